"""Trainer modes: each is a page, a trainer class and its controls. The app serves every mode
registered here; the reaming mode (``/reaming``) joins by adding one entry.

A trainer (see :class:`Trainer`) is pure logic: it takes validated controls, tracker poses and
force readings, steps at the server's tick, returns the JSON state viewers receive, and writes
its own group of the session file. Everything web-facing (sockets, tokens, recording) is the
app's, shared by all modes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np


class Trainer(Protocol):
    mode: str

    def apply_control(self, control: Any, time_s: float) -> str: ...
    def apply_pose(self, device: str, pose: np.ndarray, time_s: float) -> None: ...
    def apply_force(self, newton: float, time_s: float) -> None: ...
    def step(self, time_s: float) -> dict: ...
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


_MODELS: dict[str | None, object] = {}  # loaded once per model folder: a new session reuses it


def _reaming(settings: dict) -> Trainer:
    from thrsim.app.reaming import ReamingTrainer
    from thrsim.errors import ThrsimInputError
    from thrsim.learn.model_dir import load_model
    from thrsim.learn.simulator import ReamingSimulator

    model_dir = settings.get("model")
    try:
        if model_dir not in _MODELS:
            _MODELS[model_dir] = load_model(model_dir)
        simulator = ReamingSimulator(model=_MODELS[model_dir], threads=1)
    except ThrsimInputError as error:  # the navigation mode still serves; the page says why reaming cannot
        return ReamingTrainer(side=settings.get("side", "right"), seed=settings.get("seed", 0), unavailable=str(error))
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
