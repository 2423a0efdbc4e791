"""Trainer modes: each is a page, a trainer class and its controls. The app serves every mode
registered here; the reaming mode (``/reaming``) joins by adding one entry.

A trainer (see :class:`Trainer`) is pure logic: it takes validated controls, tracker poses and
force readings, steps at the server's tick, returns the JSON state viewers receive, and writes
its own group of the session file. A step with a slow part (reaming's simulator frames) hands
``early`` the state of the new poses before it, so viewers see the tools move without waiting;
the step computes the same either way, so a replay (which passes no ``early``) lives it alike. Everything web-facing (sockets, tokens, recording) is the
app's, shared by all modes.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

log = logging.getLogger(__name__)


class Trainer(Protocol):
    mode: str

    def apply_control(self, control: Any, time_s: float) -> str: ...
    def apply_pose(self, device: str, pose: np.ndarray, time_s: float) -> None: ...
    def apply_force(self, newton: float, time_s: float) -> None: ...
    def step(self, time_s: float, early: Callable[[dict], None] | None = None) -> dict: ...
    def scene(self) -> dict: ...
    def settings(self) -> dict: ...
    def record(self) -> Any: ...
    def write(self, group: Any) -> None: ...


@dataclass(frozen=True)
class Mode:
    name: str  # also the session file's group and the WebSocket path /ws/<name>
    path: str  # where its page is served
    page: str  # HTML file in thrsim/app/static
    title: str
    make_trainer: Callable[[dict], Trainer]  # from the session settings (side, seed)
    parse_control: Callable[[Any], Any]  # raises ThrsimInputError with the reason
    read_record: Callable[[dict], Any]  # the mode's group of a session file → its record (events, trace)


def _navigation(settings: dict) -> Trainer:
    from thrsim.app.navigation import NavigationTrainer

    return NavigationTrainer(side=settings.get("side", "right"), seed=settings.get("seed", 0))


def _parse_navigation(message: Any) -> Any:
    from thrsim.app.controls import parse_control

    return parse_control(message)


def _read_navigation(group: dict) -> Any:
    from thrsim.session.navigation import read_navigation

    return read_navigation(group)


#: loaded once per model folder and network kind: a new session reuses it (compiling changes a
#: model's network in place, so compiled and eager sessions never share one)
_MODELS: dict[tuple[str | None, bool], object] = {}


def _reaming(settings: dict) -> Trainer:
    from thrsim.app.reaming import ReamingTrainer
    from thrsim.errors import ThrsimInputError
    from thrsim.learn.model_dir import load_model
    from thrsim.learn.simulator import ReamingSimulator

    model_dir, compile_wanted = settings.get("model"), bool(settings.get("compile"))
    try:
        if (model_dir, compile_wanted) not in _MODELS:
            _MODELS[model_dir, compile_wanted] = load_model(model_dir)
        simulator = ReamingSimulator(model=_MODELS[model_dir, compile_wanted], threads=1, compile=compile_wanted)
    except ThrsimInputError as error:  # the navigation mode still serves; the page says why reaming cannot
        return ReamingTrainer(side=settings.get("side", "right"), seed=settings.get("seed", 0), unavailable=str(error))
    if compile_wanted:
        if simulator.compile_error is not None:
            log.warning("the reaming network runs uncompiled (slower steps): %s", simulator.compile_error)
        # the session records what ran, so that its replay runs the same network (rounding differs)
        settings["compile"] = simulator.compiled
    return ReamingTrainer(side=settings.get("side", "right"), seed=settings.get("seed", 0), simulator=simulator)


def _parse_reaming(message: Any) -> Any:
    from thrsim.app.controls import parse_reaming_control

    return parse_reaming_control(message)


def _read_reaming(group: dict) -> Any:
    from thrsim.session.reaming import read_reaming

    return read_reaming(group)


MODES: dict[str, Mode] = {
    "navigation": Mode("navigation", "/", "navigation.html", "Navigation skills", _navigation, _parse_navigation, _read_navigation),
    "reaming": Mode("reaming", "/reaming", "reaming.html", "Reaming", _reaming, _parse_reaming, _read_reaming),
}
