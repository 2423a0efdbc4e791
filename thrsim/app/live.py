"""A live session: one mode's trainer, every input it received with its time, and the save.

Times given to the trainer are seconds since the session started; inputs are logged before the
trainer acts on them (a refused control is an input too), so a replay lives the same session.
The log is the session's journal on disk (:mod:`thrsim.session.journal`), so a crash loses at
most the last second; the next start closes what a crash left open (:func:`close_interrupted`).
Inputs land between two steps, never inside one: tracker poses, forces and the page's controls
queue with their arrival times and a tick applies them, in arrival order, before it steps; what
arrived during a slow tick is applied over the next ticks at twice the rate it came, never at
once (:meth:`LiveSession.tick`). :meth:`LiveSession.control` applies one at once (scripts, tests).
"""

from __future__ import annotations

import datetime as dt
import json
import logging
import math
import secrets
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from thrsim.app.modes import MODES, Mode
from thrsim.app.replay import relive
from thrsim.config import FRAME_RATE_HZ
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


#: an input never waits longer than this for its tick (s): a backlog older than that (a stall far
#: beyond a tick) is applied at once, in order, so that a tracked tool's replayed pose never goes
#: stale (navigation's ``stale_after_s``, 0.5 s) and the session never lags its trainee by more
MAX_INPUT_LAG_S = 0.25


@dataclass(frozen=True)
class _Arrival:
    """One input waiting for its tick: ``pose`` (device, 4×4), ``force`` (N) or ``control`` (a parsed
    control, whose ``reply`` gets ``(control, ack)`` or the refusal once applied), and when it came (clock time)."""

    kind: str
    clock_time: float
    payload: tuple
    reply: Future | None = None


class LiveSession:
    """One mode's live session in ``folder``: its journal is ``<id>.journal`` there while it lives,
    its session file ``<id>.h5`` once it ends."""

    def __init__(self, mode: Mode, settings: dict, clock: Callable[[], float], folder: Path, tick_s: float = 1.0 / FRAME_RATE_HZ):
        self.mode = mode
        self.tick_s = tick_s  # the time between ticks, which a tick's own time counts as at most (_take_to)
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
        # the most CPU one tick's own thread used: far under the worst wall-clock tick, that tick waited
        # (for the cores or the interpreter's lock held by the server's other threads), not worked
        self.worst_tick_cpu_ms = 0.0
        self.ended: tuple[dt.datetime, float] | None = None  # set by the first save: a retried save keeps it
        self.lock = threading.RLock()
        self._arrived: deque[_Arrival] = deque()  # inputs waiting for their tick, in arrival order (appends are atomic)
        self._taken_to = self.origin  # clock time: the ticks applied the inputs that arrived up to it (_take_to)
        self._last_tick = (self.origin, self.origin)  # clock times: when the last tick began and ended

    def elapsed(self, clock_time: float | None = None) -> float:
        return (self.clock() if clock_time is None else clock_time) - self.origin

    def submit(self, message: object) -> Future:
        """Validate a page's control (ThrsimInputError at once when it is not one) and queue it for the
        next tick; the future gets ``(control, ack)`` when it is applied, or the trainer's refusal."""
        control = self.mode.parse_control(message)
        reply: Future = Future()
        self._arrived.append(_Arrival("control", self.clock(), (control,), reply))
        return reply

    def control(self, message: object) -> tuple[Any, str]:
        """Validate, log and apply one control now, after every input queued before it;
        ThrsimInputError (logged first) when refused."""
        reply = self.submit(message)
        with self.lock:
            self._apply_arrived()
        return reply.result()

    def pose(self, device: str, pose: np.ndarray, clock_time: float) -> None:
        """Queue a tracker pose for the next tick (see the module docstring)."""
        self._arrived.append(_Arrival("pose", clock_time, (device, np.array(pose, dtype=np.float64))))

    def force(self, newton: float, clock_time: float) -> None:
        """Queue a force reading, as :meth:`pose`."""
        self._arrived.append(_Arrival("force", clock_time, (float(newton),)))

    def _apply_arrived(self, until: float = math.inf) -> None:
        """Log and apply the queued inputs that arrived by ``until`` (clock time), in arrival order (the
        lock held); a refused one is logged as an input, and the rest go on."""
        while self._arrived and self._arrived[0].clock_time <= until:
            entry = self._arrived.popleft()
            now = self.elapsed(entry.clock_time)
            try:
                if entry.kind == "pose":
                    device, pose = entry.payload
                    self.journal.pose(now, device, pose)
                    self.trainer.apply_pose(device, pose, now)
                elif entry.kind == "force":
                    self.journal.force(now, entry.payload[0])
                    self.trainer.apply_force(entry.payload[0], now)
                else:
                    self._apply_control(entry, now)
            except ThrsimInputError as error:
                log.warning("%s refused: %s", entry.kind, error)

    def _apply_control(self, entry: _Arrival, now: float) -> None:
        """Log and apply a queued control; its reply gets the acknowledgement or the refusal."""
        assert entry.reply is not None
        control = entry.payload[0]
        try:
            self.journal.control(now, control.model_dump())
            if control.type == "end_session":  # the app's to act on: it saves this session
                ack = "session ending"
            elif control.type == "trainee":  # the record's, not the trainer's: the file's header says who trained
                self.attrs["trainee"] = control.id.strip()
                ack = f"trainee {self.attrs['trainee']}"
            else:
                ack = self.trainer.apply_control(control, now)
        except Exception as error:  # a refusal, or a trainer bug: the control's sender is told, the session goes on
            entry.reply.set_exception(error)
            return
        entry.reply.set_result((control, ack))

    def _take_to(self, clock_time: float) -> float:
        """Up to when (clock time) the tick at ``clock_time`` applies the inputs. At a tick's pace, all
        that arrived by then. A slow tick's own time counts as one tick: what arrived during it is
        applied over the next ticks in slices twice as long as the time between them (replayed at twice
        the rate it came, so caught up in about the stall's length, never at once), but all that waited
        :data:`MAX_INPUT_LAG_S` or more at once."""
        began, ended = self._last_tick
        since = clock_time - max(began, ended - self.tick_s)
        self._taken_to = min(clock_time, max(self._taken_to + 2.0 * max(0.0, since), clock_time - MAX_INPUT_LAG_S))
        return self._taken_to

    def tick(self, early: Callable[[dict], None] | None = None) -> dict:
        """Apply the inputs due (:meth:`_take_to`) and step the trainer to now; ``early`` gets the state
        of the new poses ahead of a slow step's rest (see :class:`thrsim.app.modes.Trainer`)."""
        with self.lock:
            started, cpu_started = time.perf_counter(), time.thread_time()
            clock_time = self.clock()
            self._apply_arrived(self._take_to(clock_time))
            now = self.elapsed(clock_time)
            self.journal.tick(now)
            session = {"id": self.id, "elapsed_s": now}
            # an early state goes before this tick is timed: it carries the worst tick so far, not its own
            worst = {"worst_tick_ms": self.worst_tick_ms, "worst_tick_cpu_ms": self.worst_tick_cpu_ms}
            early_session = {**session, "tick_ms": None, **worst}
            state = self.trainer.step(now, None if early is None else (lambda state: early({**state, "session": early_session})))
            tick_ms = (time.perf_counter() - started) * 1e3
            self.worst_tick_ms = max(self.worst_tick_ms, tick_ms)
            self.worst_tick_cpu_ms = max(self.worst_tick_cpu_ms, (time.thread_time() - cpu_started) * 1e3)
            worst = {"worst_tick_ms": self.worst_tick_ms, "worst_tick_cpu_ms": self.worst_tick_cpu_ms}
            state["session"] = {**session, "tick_ms": tick_ms, **worst}
            self._last_tick = (clock_time, self.clock())
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

    def assessable(self) -> bool:
        """Whether something assessed was done in this session. Read between ticks: a record read during
        a step would pin the arrays the step appends to (a BufferError there, a trace row lost)."""
        with self.lock:
            return self.trainer.record().assessable

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
