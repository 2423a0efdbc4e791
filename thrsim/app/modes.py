"""Trainer modes: each is a page, a trainer class, its controls, its report and its hooks into the
server. The app serves every mode registered here and names none: a mode's own routes (the reaming
mesh), binary stream (the bone), serve settings (the model, compiling) and health figures come
from its :class:`Mode`; the reaming mode (``/reaming``) joins by adding one entry.

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
from typing import TYPE_CHECKING, Any, Protocol, cast

import numpy as np

if TYPE_CHECKING:
    from thrsim.app.reaming import ReamingTrainer
    from thrsim.learn.model_dir import LoadedModel

log = logging.getLogger(__name__)


class Trainer(Protocol):
    mode: str

    @property
    def side(self) -> str: ...
    @property
    def targets(self) -> dict[str, np.ndarray]: ...  # the pelvic landmarks in the reference frame (a tracker's session checks them)

    def apply_control(self, control: Any, time_s: float) -> str: ...
    def apply_pose(self, device: str, pose: np.ndarray, time_s: float) -> None: ...
    def apply_force(self, newton: float, time_s: float) -> None: ...
    def step(self, time_s: float, early: Callable[[dict], None] | None = None) -> dict: ...
    def defaults(self) -> dict: ...
    def scene(self) -> dict: ...
    def settings(self) -> dict: ...
    def record(self) -> Any: ...
    def write(self, group: Any) -> None: ...


def _none(*_: Any) -> dict:
    return {}


def _no_routes(_: Trainer) -> list:
    return []


@dataclass(frozen=True)
class Mode:
    name: str  # also the session file's group and the WebSocket path /ws/<name>
    path: str  # where its page is served
    page: str  # HTML file in thrsim/app/static
    title: str
    make_trainer: Callable[[dict], Trainer]  # from the session settings (side, seed, and the mode's own)
    parse_control: Callable[[Any], Any]  # raises ThrsimInputError with the reason
    read_record: Callable[[dict], Any]  # the mode's group of a session file → its record (events, trace)
    #: (a session file, the competency thresholds) → the mode's part of its report (None: the file has no such group)
    report_part: Callable[[Any, Any], Any]
    #: the mode's own session settings from the server's (``thrsim serve``'s options)
    session_settings: Callable[[Any], dict] = _none
    #: (path, handler) of the mode's GET routes, given the mode's trainer every session shares data with
    routes: Callable[[Trainer], list[tuple[str, Callable[[], Any]]]] = _no_routes
    #: (trainer, what a viewer last received) → (binary message, what it then holds), None when nothing to send
    binary: Callable[[Trainer, Any], tuple[bytes, Any] | None] | None = None
    #: figures for ``/api/health``, given the mode's shared trainer
    health: Callable[[Trainer], dict] = _none


def _phantom(settings: dict) -> Any:
    """The lab's phantom a session's settings name (``thrsim serve --phantom``), or None."""
    from thrsim.nav.phantom import PhantomFile, phantom_from_file

    return None if settings.get("phantom") is None else phantom_from_file(PhantomFile(**settings["phantom"]))


def _phantom_settings(serve: Any) -> dict:
    """The phantom file every session records (a replay rebuilds the same frames from it)."""
    return {} if serve.phantom is None else {"phantom": serve.phantom.model_dump()}


def _navigation(settings: dict) -> Trainer:
    from thrsim.app.navigation import NavigationTrainer

    return NavigationTrainer(side=settings.get("side", "right"), seed=settings.get("seed", 0), phantom=_phantom(settings))


def _parse_navigation(message: Any) -> Any:
    from thrsim.app.controls import parse_control

    return parse_control(message)


def _read_navigation(group: dict) -> Any:
    from thrsim.session.navigation import read_navigation

    return read_navigation(group)


def _navigation_report(session: Any, _thresholds: Any) -> Any:
    """The navigation part (its rubric is its own: the thresholds file is the reaming report's)."""
    from thrsim.report.navigation import navigation_part

    return navigation_part(session)


#: loaded once per model folder and network kind: a new session reuses it (compiling changes a
#: model's network in place, so compiled and eager sessions never share one)
_MODELS: dict[tuple[str | None, bool], LoadedModel] = {}
#: a whole-socket model on the socket of a case (model, native size, element size): meshed once, shared by its sessions
_SOCKETS: dict[tuple[str | None, bool, float, float], LoadedModel] = {}


def _on_socket(key: tuple[str | None, bool], plan: Any, element_size_mm: float) -> LoadedModel:
    """A whole-socket model with the case's socket as its mesh (:func:`thrsim.app.reaming.socket_in_patch`)."""
    import dataclasses

    from thrsim.app.reaming import socket_in_patch
    from thrsim.learn.graph import StaticGraph

    socket_key = (*key, plan.native_socket_mm, element_size_mm)
    if socket_key not in _SOCKETS:
        mesh = socket_in_patch(plan.native_socket_mm, element_size_mm)
        _SOCKETS[socket_key] = dataclasses.replace(_MODELS[key], mesh=mesh, graph=StaticGraph(mesh))
    return _SOCKETS[socket_key]


def _reaming(settings: dict) -> Trainer:
    from thrsim.app.reaming import MAX_FRAMES_PER_TICK, ReamingTrainer
    from thrsim.errors import ThrsimInputError
    from thrsim.learn.model_dir import load_model, reads_any_mesh
    from thrsim.learn.ream import SOCKET_ELEMENT_SIZE_MM
    from thrsim.learn.simulator import ReamingSimulator
    from thrsim.session.plan import Plan

    model_dir, compile_wanted = settings.get("model"), bool(settings.get("compile"))
    plan = None if settings.get("plan") is None else Plan(**settings["plan"])  # an instructor's case (thrsim serve --plan)
    try:
        key = (model_dir, compile_wanted)
        if key not in _MODELS:
            _MODELS[key] = load_model(model_dir)
        model, case = _MODELS[key], plan or Plan()
        if reads_any_mesh(model.settings):  # a whole-socket model reams the case's socket
            model = _on_socket(key, case, float(settings.get("socket_element_size_mm", SOCKET_ELEMENT_SIZE_MM)))
        simulator = ReamingSimulator(model=model, threads=1, compile=compile_wanted, cancellous=case.cancellous)
    except ThrsimInputError as error:  # the navigation mode still serves; the page says why reaming cannot
        return ReamingTrainer(
            side=settings.get("side", "right"), seed=settings.get("seed", 0), unavailable=str(error), plan=plan, phantom=_phantom(settings)
        )
    if compile_wanted:
        if simulator.compile_error is not None:
            log.warning("the reaming network runs uncompiled (slower steps): %s", simulator.compile_error)
        # the session records what ran, so that its replay runs the same network (rounding differs)
        settings["compile"] = simulator.compiled
    return ReamingTrainer(
        side=settings.get("side", "right"),
        seed=settings.get("seed", 0),
        simulator=simulator,
        plan=plan,
        phantom=_phantom(settings),
        max_frames_per_tick=int(settings.get("max_frames_per_tick", MAX_FRAMES_PER_TICK)),
    )


def _parse_reaming(message: Any) -> Any:
    from thrsim.app.controls import parse_reaming_control

    return parse_reaming_control(message)


def _read_reaming(group: dict) -> Any:
    from thrsim.session.reaming import read_reaming

    return read_reaming(group)


def _reaming_report(session: Any, thresholds: Any) -> Any:
    from thrsim.report.reaming import reaming_part

    return reaming_part(session, thresholds)


def _as_reaming(trainer: Trainer) -> ReamingTrainer:
    """The reaming mode's hooks are only ever given the reaming mode's trainer."""
    return cast("ReamingTrainer", trainer)


def _reaming_settings(serve: Any) -> dict:
    """The model folder (None: the shipped one), whether to compile its network, an instructor's plan, and
    the element size a whole-socket model's socket is meshed at (a patch model ignores it)."""
    settings: dict = {} if serve.model is None else {"model": str(serve.model)}
    settings |= {} if serve.plan is None else {"plan": serve.plan.model_dump()}
    settings |= {} if serve.socket_element_size_mm is None else {"socket_element_size_mm": serve.socket_element_size_mm}
    settings |= _phantom_settings(serve)
    return settings | ({"compile": True} if serve.compile else {})


def _reaming_routes(trainer: Trainer) -> list[tuple[str, Callable[[], Any]]]:
    """``GET /api/reaming/mesh``: the model's mesh the page draws the bone on (404 without a model)."""
    from fastapi import HTTPException
    from fastapi.responses import Response

    from thrsim.app.bone_stream import mesh_payload

    payload: list[bytes] = []

    reaming = _as_reaming(trainer)

    def mesh() -> Any:
        simulator = reaming.simulator
        if simulator is None:
            raise HTTPException(404, reaming.unavailable or "no reaming model")
        if not payload:
            payload.append(mesh_payload(simulator.right_mesh))
        return Response(payload[0], media_type="application/octet-stream")

    return [("/api/reaming/mesh", mesh)]


def _reaming_bone(trainer: Trainer, sent: Any) -> tuple[bytes, Any] | None:
    """The bone's levels as they changed since ``sent`` (the trainer replaces its array, never mutates it)."""
    from thrsim.app.bone_stream import update

    reaming = _as_reaming(trainer)
    levels = reaming.levels
    if len(levels) == 0:
        return None
    message = update(reaming.frames_run, sent, levels)
    return None if message is None else (message, levels)


def _reaming_health(trainer: Trainer) -> dict:
    """How the reaming sessions' network runs: compiled, eager (with why, if compiling failed) or none."""
    simulator = _as_reaming(trainer).simulator
    if simulator is None:
        return {"reaming_network": {"state": "none"}}
    return {"reaming_network": {"state": "compiled" if simulator.compiled else "eager", "compile_error": simulator.compile_error}}


MODES: dict[str, Mode] = {
    "navigation": Mode(
        "navigation",
        "/",
        "navigation.html",
        "Navigation skills",
        _navigation,
        _parse_navigation,
        _read_navigation,
        _navigation_report,
        session_settings=_phantom_settings,
    ),
    "reaming": Mode(
        "reaming",
        "/reaming",
        "reaming.html",
        "Reaming",
        _reaming,
        _parse_reaming,
        _read_reaming,
        _reaming_report,
        session_settings=_reaming_settings,
        routes=_reaming_routes,
        binary=_reaming_bone,
        health=_reaming_health,
    ),  # fmt: skip
}
