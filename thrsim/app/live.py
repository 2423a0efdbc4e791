"""A live session: one mode's trainer, every input it received with its time, and the save.

Times given to the trainer are seconds since the session started; inputs are logged before the
trainer acts on them (a refused control is an input too), so a replay lives the same session.
The log is the session's journal on disk (:mod:`thrsim.session.journal`), so a crash loses at
most the last second; the next start closes what a crash left open (:func:`close_interrupted`).
Every entry point holds the session's lock, so an input lands between two steps, never inside
one; tracker poses and forces do not wait for it (a reaming step holds it for tens of
milliseconds): they queue with their arrival times and are applied, in order, at the next step.
"""

from __future__ import annotations

import datetime as dt
import json
import logging
import secrets
import threading
import time
from collections import deque
from collections.abc import Callable
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from thrsim.app.modes import MODES, Mode
from thrsim.app.replay import relive
from thrsim.errors import ThrsimInputError
from thrsim.provenance import package_versions
from thrsim.session.file import write_session
from thrsim.session.journal import SUFFIX, Journal, JournalWriter, claimed

log = logging.getLogger(__name__)

STATIC = Path(__file__).parent / "static"
THREE_DIR = STATIC / "node_modules" / "three"


def versions() -> dict:
    """Versions that shape a session: thrsim, numerics, the web stack and the page's three.js."""
    found = package_versions()
    for name in ("fastapi", "starlette", "uvicorn", "websockets", "pydantic"):
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            found[name] = "absent"
    try:
        found["three.js"] = json.loads((THREE_DIR / "package.json").read_text())["version"]
    except (OSError, ValueError, KeyError):
        found["three.js"] = "absent"
    return found


def new_session_id() -> str:
    return dt.datetime.now(dt.UTC).strftime("%Y%m%dT%H%M%SZ") + "-" + secrets.token_hex(3)


class LiveSession:
    """One mode's live session in ``folder``: its journal is ``<id>.journal`` there while it lives,
    its session file ``<id>.h5`` once it ends."""

    def __init__(self, mode: Mode, settings: dict, clock: Callable[[], float], folder: Path):
        self.mode = mode
        self.settings = dict(settings)
        self.clock = clock
        self.folder = Path(folder)
        self.id = new_session_id()
        self.trainer = mode.make_trainer(self.settings)
        self.origin = clock()
        self.started_utc = dt.datetime.now(dt.UTC)
        self.attrs = {
            "mode": self.mode.name,
            "session_id": self.id,
            "started_utc": self.started_utc.isoformat(),
            "settings": json.dumps({"mode": self.mode.name, **self.settings}),  # as started: a replay starts here
            "versions": json.dumps(versions()),
        }
        self.journal = JournalWriter(self.folder / f"{self.id}{SUFFIX}", self.attrs)
        self.worst_tick_ms = 0.0  # the longest tick of this session (inputs applied, trainer stepped), wall-clock
        self.ended: tuple[dt.datetime, float] | None = None  # set by the first save: a retried save keeps it
        self.lock = threading.RLock()
        self._arrived: deque[tuple] = deque()  # poses and forces waiting for the lock (appends are atomic)

    def elapsed(self, clock_time: float | None = None) -> float:
        return (self.clock() if clock_time is None else clock_time) - self.origin

    def control(self, message: object) -> tuple[Any, str]:
        """Validate, log and apply one control; ThrsimInputError (logged first) when refused."""
        control = self.mode.parse_control(message)
        with self.lock:
            self._apply_arrived()
            now = self.elapsed()
            self.journal.control(now, control.model_dump())
            if control.type == "end_session":  # the app's to act on: it saves this session
                return control, "session ending"
            if control.type == "trainee":  # the record's, not the trainer's: the file's header says who trained
                self.attrs["trainee"] = control.id.strip()
                return control, f"trainee {self.attrs['trainee']}"
            return control, self.trainer.apply_control(control, now)

    def pose(self, device: str, pose: np.ndarray, clock_time: float) -> None:
        """Queue a tracker pose (applied when the lock is next taken; see the module docstring)."""
        self._arrived.append(("pose", device, np.array(pose, dtype=np.float64), clock_time))

    def force(self, newton: float, clock_time: float) -> None:
        """Queue a force reading, as :meth:`pose`."""
        self._arrived.append(("force", float(newton), clock_time))

    def _apply_arrived(self) -> None:
        """Log and apply the queued poses and forces in arrival order (the lock held); a refused
        one is logged as an input, as a refused control is, and the rest go on."""
        while self._arrived:
            entry = self._arrived.popleft()
            try:
                if entry[0] == "pose":
                    _, device, pose, clock_time = entry
                    now = self.elapsed(clock_time)
                    self.journal.pose(now, device, pose)
                    self.trainer.apply_pose(device, pose, now)
                else:
                    _, newton, clock_time = entry
                    now = self.elapsed(clock_time)
                    self.journal.force(now, newton)
                    self.trainer.apply_force(newton, now)
            except ThrsimInputError as error:
                log.warning("%s refused: %s", entry[0], error)

    def tick(self, early: Callable[[dict], None] | None = None) -> dict:
        """Step the trainer to now; ``early`` gets the state of the new poses ahead of a slow step's
        rest (see :class:`thrsim.app.modes.Trainer`)."""
        with self.lock:
            started = time.perf_counter()
            self._apply_arrived()
            now = self.elapsed()
            self.journal.tick(now)
            session = {"id": self.id, "elapsed_s": now}
            # an early state goes before this tick is timed: it carries the worst tick so far, not its own
            early_session = {**session, "tick_ms": None, "worst_tick_ms": self.worst_tick_ms}
            state = self.trainer.step(now, None if early is None else (lambda state: early({**state, "session": early_session})))
            tick_ms = (time.perf_counter() - started) * 1e3
            self.worst_tick_ms = max(self.worst_tick_ms, tick_ms)
            state["session"] = {**session, "tick_ms": tick_ms, "worst_tick_ms": self.worst_tick_ms}
            return state

    def save(self, folder: Path | None = None) -> Path:
        """Write the session file (into ``folder``, default the sessions folder) from the journal, then
        remove the journal; on an error the journal stays. The end time is fixed by the first try, so a
        retried save records when the session ended, not when it could be written."""
        with self.lock:
            self._apply_arrived()
            self.journal.flush()
            if self.ended is None:
                self.ended = (dt.datetime.now(dt.UTC), self.elapsed())
            ended, duration_s = self.ended
            attrs = {**self.attrs, "ended_utc": ended.isoformat(), "duration_s": duration_s, "interrupted": False}
            path = write_session(
                Path(folder or self.folder) / f"{self.id}.h5",
                attrs,
                Journal(self.journal.path).inputs(),
                {self.mode.name: self.trainer.write},
            )
            self.journal.close(remove=True)
            return path

    def discard(self) -> None:
        """End a session that is not kept (nothing but steps reached it): its journal goes."""
        with self.lock:
            self.journal.close(remove=True)


def close_interrupted(folder: Path) -> list[Path]:
    """Close the sessions a crash left open in ``folder``: each journal no live session holds becomes
    a session file marked interrupted, with every input the journal kept, the mode's record rebuilt
    by reliving them through a fresh trainer (as ``thrsim replay`` does). A journal whose session
    file exists (saved, then the crash), or that holds nothing but steps, is removed; one that cannot
    be closed stays, with a warning. Returns the session files written."""
    closed = []
    for path in sorted(folder.glob(f"*{SUFFIX}")):
        target = path.with_suffix(".h5")
        try:
            with claimed(path) as ours:
                if not ours:
                    continue  # a live session's
                if not target.exists():
                    journal = Journal(path)
                    if any(kind != "tick" for kind, _, _ in journal.inputs()):
                        log.warning("closing interrupted session %s from its journal (reliving its inputs)", path.stem)
                        closed.append(_close_from_journal(journal, target))
                        log.warning("interrupted session closed: %s", target)
                path.unlink()
        except Exception as error:  # whatever it is, the journal is kept and the server starts
            log.warning("%s: interrupted session not closed, its journal is kept: %s", path, error)
    return closed


def _close_from_journal(journal: Journal, target: Path) -> Path:
    settings = json.loads(journal.attrs["settings"])
    mode = MODES.get(settings.get("mode", ""))
    if mode is None:
        raise ThrsimInputError(f"recorded in mode {settings.get('mode')!r}, which this thrsim does not have")
    trainer = mode.make_trainer(settings)
    relive(trainer, mode, journal.inputs())
    duration = max((time_s for _, time_s, _ in journal.inputs()), default=0.0)
    started = dt.datetime.fromisoformat(journal.attrs["started_utc"])
    trainees = [p["id"].strip() for kind, _, p in journal.inputs() if kind == "control" and p.get("type") == "trainee"]
    attrs = {
        **journal.attrs,
        **({"trainee": trainees[-1]} if trainees else {}),
        "ended_utc": (started + dt.timedelta(seconds=duration)).isoformat(),
        "duration_s": duration,
        "interrupted": True,
    }
    return write_session(target, attrs, journal.inputs(), {mode.name: trainer.write})
