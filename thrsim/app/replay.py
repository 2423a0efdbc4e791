"""Replay a recorded session: feed its inputs, in lived order and with their times, to a fresh
trainer of the same mode and settings, and compare what it produces with what was recorded.

The trainers are deterministic given their inputs and seed, so a replay of an unchanged thrsim
reproduces the session's events and orientation trace exactly; a difference means the trainer's
behaviour changed since the session was recorded (the file keeps the versions that made it).

A reaming session names the model folder it was reamed with when that was not the shipped model.
A replay never follows that path by itself (a session file may come from elsewhere): it uses the
shipped model, or the folder the user names, and that folder passes the same checks as any model
(:func:`thrsim.learn.model_dir.load_model`).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from thrsim.app.controls import SESSION_CONTROLS
from thrsim.app.modes import MODES, Mode
from thrsim.errors import ThrsimInputError
from thrsim.learn.model_dir import SHIPPED_MODEL
from thrsim.session.file import read_session


@dataclass(frozen=True)
class ReplayOutcome:
    mode: str
    model: str | None  # the model folder the replay ran (None: no model, a navigation session)
    inputs: int
    refused_controls: int
    events: int
    events_match: bool
    trace_match: bool
    max_angle_difference_deg: float

    @property
    def reproduced(self) -> bool:
        return self.events_match and self.trace_match

    def as_dict(self) -> dict:
        return {**self.__dict__, "reproduced": self.reproduced}


def _event_keys(events: Iterable[dict]) -> list[tuple]:
    """What a replay must reproduce of each event: its kind, landmark or detail, and time (to 1 ns)."""
    return [(e["kind"], e.get("landmark") or e.get("detail"), round(e["time_s"], 9)) for e in events]


def replay_session(path: str | Path, on_state=None, model: str | Path | None = None) -> ReplayOutcome:
    """Re-live the session at ``path``; ``on_state(state)`` sees every step's state (e.g. to draw it).
    ``model``: the model folder a reaming session replays with (None: the shipped model; a session
    reamed with another folder is refused until the user names one)."""
    session = read_session(path)
    settings = session.settings
    mode = MODES.get(settings.get("mode", ""))
    if mode is None:
        raise ThrsimInputError(f"{path}: recorded in mode {settings.get('mode')!r}, which this thrsim does not have")
    settings["model"] = _model_to_use(path, settings.get("model"), model)
    trainer = mode.make_trainer(settings)
    if mode.name not in session.groups:
        raise ThrsimInputError(f"{path}: session file has no {mode.name} group")
    recorded = mode.read_record(session.groups[mode.name])
    _check_same_mesh(path, recorded, trainer)
    refused = relive(trainer, mode, session.inputs.replay(), on_state)
    replayed = trainer.record()
    same_shape = recorded.angles.shape == replayed.angles.shape
    difference = float(np.nanmax(np.abs(recorded.angles - replayed.angles), initial=0.0)) if same_shape else float("inf")
    trace_match = same_shape and bool(np.array_equal(np.isnan(recorded.angles), np.isnan(replayed.angles))) and difference <= 1e-9
    if hasattr(recorded, "removed_volume_mm3"):  # reaming: the bone removed frame by frame, too
        trace_match = (
            trace_match
            and np.array_equal(recorded.removed, replayed.removed)
            and np.allclose(recorded.removed_volume_mm3, replayed.removed_volume_mm3, rtol=0, atol=1e-9)
            and (recorded.reamer_mm is None or np.array_equal(recorded.reamer_mm, replayed.reamer_mm))  # the sequence, where recorded
            and all(  # a whole-socket model's force, frame by frame
                getattr(recorded, name) is None or np.array_equal(getattr(recorded, name), getattr(replayed, name), equal_nan=True)
                for name in ("cut_mm", "reaction_n", "motor_torque_n_m")
            )
        )
    used = trainer.settings().get("model")
    return ReplayOutcome(
        mode=mode.name,
        model=None if used is None else str(used["path"]),
        inputs=session.inputs.count,
        refused_controls=refused,
        events=len(replayed.events),
        events_match=_event_keys(recorded.events) == _event_keys(replayed.events),
        trace_match=trace_match,
        max_angle_difference_deg=difference,
    )


def relive(trainer, mode: Mode, inputs: Iterable[tuple[str, float, Any]], on_state=None) -> int:
    """Feed recorded ``(kind, time_s, payload)`` inputs, in order, to ``trainer`` as the live session fed
    them (a tick is a step; the :data:`~thrsim.app.controls.SESSION_CONTROLS` are the live session's,
    not the trainer's); the number it refused."""
    refused = 0
    for kind, time_s, payload in inputs:
        if kind == "tick":
            state = trainer.step(time_s)
            if on_state is not None:
                on_state(state)
        elif kind == "pose":
            device, matrix = payload
            try:
                trainer.apply_pose(device, np.asarray(matrix), time_s)
            except ThrsimInputError:
                refused += 1
        elif kind == "force":
            try:
                trainer.apply_force(payload, time_s)
            except ThrsimInputError:
                refused += 1
        elif payload.get("type") not in SESSION_CONTROLS:
            try:
                trainer.apply_control(mode.parse_control(payload), time_s)
            except ThrsimInputError:
                refused += 1  # refused live too: the same input, the same answer
    return refused


def _model_to_use(path, recorded: object, given: str | Path | None) -> str | None:
    """The model folder to replay with: the user's, else the shipped one, which the session must have used."""
    if given is not None:
        return str(given)
    if recorded is None or (isinstance(recorded, str) and Path(recorded).resolve() == SHIPPED_MODEL.resolve()):
        return None
    raise ThrsimInputError(
        f"{path}: reamed with the model folder {recorded!r}, not the shipped model; a replay loads only a model you name: "
        "name that folder, if you trust it (model_dir)",
        mentions=("model_dir",),
    )


def _check_same_mesh(path, recorded, trainer) -> None:
    """A reaming session replays only on the mesh it was reamed on (the model's)."""
    wanted = getattr(recorded, "mesh_digest", "")
    if not wanted:
        return
    model = trainer.settings().get("model")
    if model is None:
        raise ThrsimInputError(f"{path}: a reaming session needs its model to replay; none could be loaded ({trainer.unavailable})")
    if model["mesh_digest"] != wanted:
        raise ThrsimInputError(
            f"{path}: reamed on mesh {wanted[:12]}, but the model at {model['path']} has mesh {model['mesh_digest'][:12]}"
        )
