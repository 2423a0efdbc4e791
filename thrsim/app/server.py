"""The trainer's web app: pages, a WebSocket per page, the OpenIGTLink listener, the ticker.

One process serves everything, one live session per trainee's page (a seat), which instructors
may join read-only (``?observe=SESSION_ID``). Every ``1/tick_hz`` s the ticker steps every live
session on a worker thread and offers each viewer only the newest state, so a slow viewer skips
frames instead of slowing the others; a mode's binary stream follows each state. A page's controls
queue for the ticks as tracker poses do, and are answered once applied, in order. Routes, streams
and settings of one mode are its :class:`~thrsim.app.modes.Mode` hooks, so nothing here names a
mode. Sessions stream their inputs to a journal, are saved atomically when they end (an empty one
is not saved), are retried on a full disk, and a crash's are closed at the next start (see
:class:`TrainerHub`). Who may talk (host, token, origin, session limits, OpenIGTLink peers) is
:class:`_AccessGate`'s and :class:`ServeSettings`'s; the docs' Security page explains why.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import ipaddress
import json
import logging
import math
import re
import secrets
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlsplit

from fastapi import FastAPI, HTTPException, WebSocket, WebSocketDisconnect
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from starlette.concurrency import run_in_threadpool

from thrsim.app.live import STATIC, THREE_DIR, LiveSession, close_interrupted
from thrsim.app.modes import MODES, Mode
from thrsim.app.sessions_pages import record_routes
from thrsim.config import FRAME_RATE_HZ, HAPTIC_RATE_HZ, LOOPBACK_NETWORKS, OPENIGTLINK_PORT, IgtlConfig, LiveSessionLimit, SessionEndLimit
from thrsim.errors import ThrsimInputError
from thrsim.io import feedback
from thrsim.io.haptic import ContactForce, HapticStream, contact_of
from thrsim.nav.bone_frame import check_side
from thrsim.nav.pelvis_surface import pelvis_surface, surface_payload
from thrsim.nav.phantom import PhantomFile
from thrsim.nav.tracker_state import TrackerState
from thrsim.report.thresholds import Thresholds
from thrsim.session.file import is_interrupted
from thrsim.session.plan import Plan

log = logging.getLogger(__name__)


class SessionEndTooSoon(ThrsimInputError):
    """A viewer asked to end sessions faster than :class:`~thrsim.config.SessionEndLimit` allows: the session goes on."""


class NothingToSave(ThrsimInputError):
    """A trainee asked to end a session in which nothing assessed was done (a second click on End session): it goes on."""


TOKEN_COOKIE = "thrsim_token"
_SESSION_ID = re.compile(r"^[0-9]{8}T[0-9]{6}Z-[0-9a-f]{6}$")
_TOKEN = re.compile(r"[A-Za-z0-9._~-]+")  # URL- and cookie-safe, as secrets.token_urlsafe() makes
_REPORT_LOCK = threading.Lock()  # matplotlib's pyplot is not safe for two reports at once


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _canonical_host(name: str) -> str:
    """A host name in lower case without a final dot, or an IP address in its compressed form."""
    try:
        return ipaddress.ip_address(name).compressed
    except ValueError:
        return name.rstrip(".").lower()


def host_of(header: str) -> str:
    """The host a ``Host`` header names (``name``, ``name:port``, ``[v6]`` or ``[v6]:port``), canonical."""
    if header.startswith("["):
        return _canonical_host(header[1:].partition("]")[0])
    name, colon, port = header.rpartition(":")
    return _canonical_host(name if colon and port.isdigit() else header)


def _networks(values: tuple[str, ...]) -> tuple[ipaddress.IPv4Network | ipaddress.IPv6Network, ...]:
    networks = []
    for value in values:
        try:
            networks.append(ipaddress.ip_network(value, strict=False))
        except ValueError:
            raise ThrsimInputError(f"{value}: not an address or network (ADDR or ADDR/PREFIX)", "igtl_allow") from None
    return tuple(networks)


@dataclass
class ServeSettings:
    host: str = "127.0.0.1"
    port: int = 8000
    igtl_port: int = OPENIGTLINK_PORT
    token: str | None = None
    sessions_dir: Path = Path("sessions")
    side: str = "right"
    seed: int | None = None  # None: a fresh one per session
    tick_hz: float = FRAME_RATE_HZ  # the states' rate: a frame of reaming per tick
    igtl: bool = True
    model: Path | None = None  # the reaming mode's model folder (None: the shipped model)
    compile: bool = True  # run the reaming network compiled (thrsim.learn.compiled), compiled at start
    allowed_hosts: tuple[str, ...] = ()  # host names the page may be opened by off loopback (besides addresses)
    igtl_host: str | None = None  # the OpenIGTLink listener's address (None: loopback)
    igtl_allow: tuple[str, ...] = ()  # networks beyond loopback whose trackers are served
    igtl_feedback: bool = False  # send OpenIGTLink peers the sessions' events and simulated reamer (thrsim.io.feedback)
    session_ends: SessionEndLimit = SessionEndLimit()
    live_sessions: LiveSessionLimit = LiveSessionLimit()
    save_retry_s: float = 10.0  # how often a session that could not be saved is tried again
    plan: Plan | None = None  # an instructor's case: the reaming plan every session starts with (None: the trainee's)
    thresholds: Thresholds | None = None  # what the served reports score against (None: the shipped defaults)
    socket_element_size_mm: float | None = None  # a whole-socket model's socket is meshed at this size (mm; None: thrsim ream's)
    haptic_port: int | None = None  # the haptic stream's port on the OpenIGTLink listener's address (None: off; 0: any)
    haptic_hz: float = HAPTIC_RATE_HZ  # the haptic stream's rate (thrsim.io.haptic)
    phantom: PhantomFile | None = None  # a lab's physical pelvis the headset shows the bone on (None: the simulated one)

    def check(self) -> None:
        if not is_loopback(self.host) and not self.token:
            raise ThrsimInputError(f"{self.host} is reachable from other machines: give an access token (token)", "host", ("token",))
        if self.token is not None and len(self.token) < 8:
            raise ThrsimInputError("the access token must be at least 8 characters")
        if self.token is not None and not _TOKEN.fullmatch(self.token):
            raise ThrsimInputError("the access token may hold letters, digits and . _ ~ - only (it travels in URLs and a cookie)")
        check_side(self.side)
        check_socket_element_size(self.socket_element_size_mm)
        if not (math.isfinite(self.haptic_hz) and 100.0 <= self.haptic_hz <= 10_000.0):
            raise ThrsimInputError(f"must lie in [100, 10000] Hz, got {self.haptic_hz:g}", "haptic_hz")
        if self.haptic_port is not None and not 0 <= self.haptic_port <= 65535:
            raise ThrsimInputError(f"must lie in 0..65535, got {self.haptic_port}", "haptic_port")
        if not self.sessions_dir.is_dir():
            raise ThrsimInputError(f"sessions folder {self.sessions_dir} does not exist")
        if self.model is not None and not self.model.is_dir():
            raise ThrsimInputError(f"{self.model}: no such model folder", "model_dir")
        _networks(self.igtl_allow)
        if self.igtl_allow and is_loopback(self.igtl_config().host):
            raise ThrsimInputError(
                "admits trackers from other machines: give the address to listen on as well (igtl_host)", "igtl_allow", ("igtl_host",)
            )
        if not self.igtl_allow and not is_loopback(self.igtl_config().host):
            raise ThrsimInputError(
                f"{self.igtl_host} serves no other machine without networks to admit (igtl_allow)", "igtl_host", ("igtl_allow",)
            )

    def igtl_config(self) -> IgtlConfig:
        """The OpenIGTLink listener: on loopback (this host's, when it is loopback) unless ``igtl_host``."""
        host = self.igtl_host or (self.host if is_loopback(self.host) else "127.0.0.1")
        return IgtlConfig(
            host=host,
            port=self.igtl_port,
            allowed_peers=LOOPBACK_NETWORKS + tuple(map(str, _networks(self.igtl_allow))),
            feedback=self.igtl_feedback,
        )

    def host_allowed(self, header: str) -> bool:
        """Whether a request's ``Host`` header names this trainer (see :class:`_AccessGate`)."""
        name = host_of(header)
        if is_loopback(name):
            return True
        if is_loopback(self.host):
            return False
        served = _canonical_host(self.host)
        if name == served or name in map(_canonical_host, self.allowed_hosts):
            return True
        return served in ("0.0.0.0", "::") and _is_address(name)


#: the element sizes (mm) a whole-socket model's socket may be meshed at in a served session
SOCKET_ELEMENT_SIZE_RANGE_MM = (0.3, 5.0)


def check_socket_element_size(size: float | None) -> None:
    """A served socket's element size (None: thrsim ream's), or a one-line error naming its setting."""
    low, high = SOCKET_ELEMENT_SIZE_RANGE_MM
    if size is not None and not (math.isfinite(size) and low <= size <= high):
        raise ThrsimInputError(f"must lie in [{low:g}, {high:g}] mm, got {size:g}", "socket_element_size_mm")


def _is_address(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


class _AccessGate:
    """ASGI middleware: every HTTP request and WebSocket handshake must name this trainer as its host,
    and carry the token when there is one; WebSocket handshakes must come from this trainer's page.

    * Host: on a loopback address only requests naming a loopback host (``localhost``, 127.0.0.0/8,
      ``[::1]``; any port) are answered, so a web page cannot reach the trainer by DNS rebinding; off
      loopback, the host served, an IP address where every interface is served, and the names given
      in ``allowed_hosts``. Others get 403 (a WebSocket is closed before it opens).
    * Token: on a loopback address no token is needed unless one is given; on any other address a
      token is required, on every HTTP request and WebSocket handshake (``?token=``, a
      ``thrsim_token`` cookie the page gets on first load, or ``Authorization: Bearer``).
    * Origin: WebSocket handshakes from another site's page (a foreign ``Origin``) are refused.
    """

    def __init__(self, app, settings: ServeSettings):
        self.app = app
        self.settings = settings
        self.token = settings.token

    def _presented(self, scope) -> tuple[str | None, bool]:
        query = parse_qs(scope.get("query_string", b"").decode("latin-1")).get("token", [None])[0]
        if query is not None:
            return query, True
        headers = _headers(scope)
        auth = headers.get("authorization", "")
        if auth.lower().startswith("bearer "):
            return auth[7:].strip(), False
        for part in headers.get("cookie", "").split(";"):
            name, _, value = part.strip().partition("=")
            if name == TOKEN_COOKIE:
                return value, False
        return None, False

    async def __call__(self, scope, receive, send):
        if scope["type"] not in ("http", "websocket"):
            return await self.app(scope, receive, send)
        headers = _headers(scope)
        host = headers.get("host")
        if host is not None and not self.settings.host_allowed(host):
            if scope["type"] == "websocket":
                return await send({"type": "websocket.close", "code": 4403, "reason": "foreign host"})
            body = f"host {host} is not one this trainer answers to\n".encode("utf-8", "replace")
            await send({"type": "http.response.start", "status": 403, "headers": [(b"content-type", b"text/plain; charset=utf-8")]})
            return await send({"type": "http.response.body", "body": body})
        origin = headers.get("origin")
        if scope["type"] == "websocket" and origin is not None and urlsplit(origin).netloc != host:
            return await send({"type": "websocket.close", "code": 4403, "reason": "foreign origin"})
        if self.token is None:
            return await self.app(scope, receive, send)
        presented, from_query = self._presented(scope)
        if presented is None or not hmac.compare_digest(presented.encode(), self.token.encode()):
            reason = "missing access token" if presented is None else "wrong access token"
            if scope["type"] == "websocket":
                return await send({"type": "websocket.close", "code": 4401, "reason": reason})
            body = f"{reason}: open the trainer as /?token=YOUR_TOKEN\n".encode()
            await send({"type": "http.response.start", "status": 401, "headers": [(b"content-type", b"text/plain; charset=utf-8")]})
            return await send({"type": "http.response.body", "body": body})
        if scope["type"] == "http" and from_query:
            # The page's modules and its WebSocket then carry the token without it in every URL.
            cookie = f"{TOKEN_COOKIE}={self.token}; Path=/; HttpOnly; SameSite=Strict".encode()

            async def send_with_cookie(message):
                if message["type"] == "http.response.start":
                    message = dict(message, headers=list(message.get("headers", [])) + [(b"set-cookie", cookie)])
                await send(message)

            return await self.app(scope, receive, send_with_cookie)
        return await self.app(scope, receive, send)


def _headers(scope) -> dict[str, str]:
    return {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}


@dataclass(eq=False)  # hashed by identity: viewers live in a set
class _Viewer:
    socket: WebSocket
    queue: asyncio.Queue = field(default_factory=lambda: asyncio.Queue(maxsize=1))
    binary_held: Any = None  # what the mode's binary messages gave this viewer so far (reaming: the bone's levels)

    def offer(self, text: str) -> None:
        if self.queue.full():
            self.queue.get_nowait()  # newest state wins
        self.queue.put_nowait(text)


@dataclass(eq=False)
class Seat:
    """One trainee's place: the live session of their page (a fresh one after each end), the page
    (``owner``, None once it left) and the pages observing it."""

    session: LiveSession
    owner: _Viewer | None
    observers: set[_Viewer] = field(default_factory=set)

    @property
    def viewers(self) -> list[_Viewer]:
        return ([self.owner] if self.owner is not None else []) + list(self.observers)


class TrainerHub:
    """The seats (one per trainee's page), their live sessions and viewers, and the save on end.

    A session ends when its trainee asks (a fresh one starts at once in the same seat, its observers
    stay), leaves the page (its observers are told), or the server stops. One in which nothing
    assessed was done is not saved: an end asked for it is refused, one left or stopped is
    discarded. At most :class:`~thrsim.config.LiveSessionLimit` live at once, ends limited by
    :class:`~thrsim.config.SessionEndLimit`. A session that cannot be written (a full disk) is kept,
    journal and all, and tried again every ``save_retry_s``; at shutdown, after a few more tries,
    into the temporary folder, and only then left to its journal, with a log line that says so."""

    def __init__(self, settings: ServeSettings, clock=time.monotonic):
        self.settings = settings
        self.clock = clock
        # one trainer per mode made now, with no session: the reaming network loads (and compiles)
        # before any page opens, and these answer what every session of the mode shares (the mesh, the network)
        self.prototypes = {name: mode.make_trainer(self._settings(mode)) for name, mode in MODES.items()}
        self.seats: list[Seat] = []
        self._seating = threading.Lock()
        self.saved: list[Path] = []
        self.unsaved: list[LiveSession] = []  # ended, not yet written (a full disk): kept and retried
        self._saving = threading.Lock()
        self.ticks = 0
        self.igtl_address: tuple[str, int] | None = None
        self.haptic_address: tuple[str, int] | None = None
        #: with feedback on, hands what the peers get (thrsim.io.feedback) to the OpenIGTLink server, from any thread
        self.feedback: Callable[[list[tuple[str, str, bytes]]], None] | None = None
        self._ended_events: deque[dict] = deque()  # sessions ended since the last tick (feedback on); appends are atomic
        #: with a haptic stream, the fast contact model it evaluates (thrsim.io.haptic), following every tick
        self.contact_force: ContactForce | None = None if settings.haptic_port is None else ContactForce()
        self.ends_left = float(settings.session_ends.burst)  # the token bucket of viewer-asked ends
        self._counting_ends = threading.Lock()
        self.ends_counted_at = clock()

    def _settings(self, mode: Mode) -> dict:
        seed = self.settings.seed if self.settings.seed is not None else secrets.randbits(31)
        return {"side": self.settings.side, "seed": seed, **mode.session_settings(self.settings)}

    def _start(self, mode: Mode) -> LiveSession:
        return LiveSession(mode, self._settings(mode), self.clock, self.settings.sessions_dir, tick_s=1.0 / self.settings.tick_hz)

    def open_seat(self, mode_name: str, owner: _Viewer | None) -> Seat:
        """A seat with a fresh session of the mode for a trainee's page; ThrsimInputError when
        :class:`~thrsim.config.LiveSessionLimit` sessions are live already."""
        with self._seating:
            limit = self.settings.live_sessions.sessions
            if len(self.seats) >= limit:
                raise ThrsimInputError(
                    f"{len(self.seats)} sessions are live, the most this trainer runs at once ({limit}): "
                    "end one, or observe one (?observe=SESSION_ID)"
                )
            seat = Seat(self._start(MODES[mode_name]), owner)
            self.seats.append(seat)
            return seat

    def observe(self, mode_name: str, session_id: str, viewer: _Viewer) -> Seat:
        """Join the live session ``session_id`` of the mode as an observer; ThrsimInputError when there is none."""
        for seat in list(self.seats):
            if seat.session.id == session_id and seat.session.mode.name == mode_name:
                seat.observers.add(viewer)
                return seat
        raise ThrsimInputError(f"no live {mode_name} session {session_id!r} to observe")

    def leave(self, seat: Seat, viewer: _Viewer) -> Path | None:
        """A viewer's page left. An observer just goes; the trainee's leaving closes the seat and ends
        its session: saved (the path) when something assessed was done in it, else discarded (None)."""
        if viewer is not seat.owner:
            seat.observers.discard(viewer)
            return None
        seat.owner = None
        with self._seating:
            self.seats.remove(seat)
        session = seat.session
        if not session.assessable():
            session.discard()
            self._ended(session, None)
            return None
        try:
            path = session.save(self.settings.sessions_dir)
        except (ThrsimInputError, OSError) as error:
            self.unsaved.append(session)
            log.error("session %s kept, not saved yet: %s", session.id, error)
            self._ended(session, None)
            return None
        self.saved.append(path)
        self._ended(session, path)
        return path

    def on_pose(self, device: str, pose, clock_time: float) -> None:
        """A tracker pose for every live session (queued there: this never waits for a step)."""
        for seat in list(self.seats):
            seat.session.pose(device, pose, clock_time)

    def on_force(self, newton: float, clock_time: float) -> None:
        if self.contact_force is not None:
            self.contact_force.push(newton)  # felt at once, before the next frame reads it
        for seat in list(self.seats):
            seat.session.force(newton, clock_time)

    def tick(self, publish_early: Callable[[Seat, str], None] | None = None) -> dict[Seat, str]:
        """Step every live session (on the ticker's worker thread); the state texts to publish.
        ``publish_early(seat, text)`` publishes a state a slow step hands out ahead of its end."""
        self.ticks += 1
        texts = {}

        def early_for(seat: Seat, heard: list[dict]) -> Callable[[dict], None] | None:
            publish = None if publish_early is None or not seat.viewers else publish_early

            def early(state: dict) -> None:
                heard.append(state)  # its events are the peers' too
                if publish is not None:
                    publish(seat, json.dumps(state, allow_nan=False))

            return None if publish is None and self.feedback is None else early

        stepped: list[tuple[LiveSession, list[dict]]] = []
        for seat in list(self.seats):
            heard: list[dict] = []
            try:
                state = seat.session.tick(early_for(seat, heard))
                if seat.viewers:
                    texts[seat] = json.dumps(state, allow_nan=False)
            except Exception:  # a trainer bug must not stop the other sessions or lose this one
                log.exception("%s step failed", seat.session.mode.name)
                continue
            stepped.append((seat.session, [*heard, state]))
        if self.contact_force is not None:
            self.contact_force.follow(contact_of([states[-1] for _, states in stepped]))
        self._feed(stepped)
        return texts

    def _feed(self, stepped: list[tuple[LiveSession, list[dict]]]) -> None:
        """Hand the OpenIGTLink peers this tick's feedback: the sessions ended since the last tick and
        every event of this one in one message, then each simulated reamer (thrsim.io.feedback)."""
        if self.feedback is None:
            return
        try:
            events = [self._ended_events.popleft() for _ in range(len(self._ended_events))]
            reamers, forces = [], []
            for session, states in stepped:
                events += feedback.step_events(session.id, states)
                reamers.append(feedback.simulated_reamer(states[-1], session.trainer.scene))
                forces += feedback.frame_forces(states)
            outgoing = [feedback.events_message(events)] if events else []
            self.feedback(outgoing + [reamer for reamer in reamers if reamer is not None] + forces)
        except Exception:  # a bug of ours in the feedback must not stop the sessions
            log.exception("OpenIGTLink feedback failed")

    def _ended(self, session: LiveSession, path: Path | None) -> None:
        """With feedback on, the end of ``session`` goes to the OpenIGTLink peers at the next tick, with
        its file's name (None: not saved)."""
        if self.feedback is not None:
            self._ended_events.append(
                feedback.session_ended(session.id, session.mode.name, session.elapsed(), None if path is None else path.name)
            )

    def publish(self, texts: dict[Seat, str]) -> None:
        """Hand the states to the viewers' senders (on the event loop)."""
        for seat, text in texts.items():
            for viewer in seat.viewers:
                viewer.offer(text)

    def end_asked(self, seat: Seat) -> Path:
        """The trainee's end of the seat's session: NothingToSave, the session going on, when nothing
        assessed was done in it; within :class:`~thrsim.config.SessionEndLimit`, ThrsimInputError,
        the session going on, when ends come faster."""
        session = seat.session
        if not session.assessable():
            raise NothingToSave(f"nothing to save: nothing assessed was done in session {session.id} yet; it goes on")
        limit = self.settings.session_ends
        with self._counting_ends:  # pages' ends are answered on worker threads
            now = self.clock()
            self.ends_left = min(limit.burst, self.ends_left + (now - self.ends_counted_at) / limit.refill_s)
            self.ends_counted_at = now
            if self.ends_left < 1:
                wait_s = (1 - self.ends_left) * limit.refill_s
                raise SessionEndTooSoon(
                    f"sessions ended too often ({limit.burst} at once, then one every {limit.refill_s:g} s): "
                    f"this one goes on; end it again in {math.ceil(wait_s)} s"
                )
            self.ends_left -= 1
        return self.end(seat)

    def end(self, seat: Seat) -> Path:
        """Start a fresh session in the seat and save the one that ended.

        A save that fails (ThrsimOutputError, or ThrsimInputError for a sessions folder gone) is
        raised after the session is put in :attr:`unsaved` (its journal kept), which
        :meth:`retry_unsaved` writes later.
        """
        session = seat.session
        seat.session = self._start(session.mode)  # where no fresh session can start (no journal), this one goes on
        try:
            path = session.save(self.settings.sessions_dir)
        except (ThrsimInputError, OSError):
            self.unsaved.append(session)
            self._ended(session, None)
            raise
        self.saved.append(path)
        self._ended(session, path)
        return path

    def retry_unsaved(self, folder: Path | None = None) -> list[Path]:
        """Write the sessions that ended unsaved (to ``folder``, default the sessions folder); those that fail stay."""
        written = []
        with self._saving:  # the retry task and the shutdown may both be here
            for session in list(self.unsaved):
                try:
                    path = session.save(folder or self.settings.sessions_dir)
                except (ThrsimInputError, OSError) as error:
                    log.error("session %s kept, not saved: %s", session.id, error)
                    continue
                self.unsaved.remove(session)
                self.saved.append(path)
                written.append(path)
                log.warning("session %s saved: %s", session.id, path)
        return written

    def save_all(self, tries: int = 3, pause_s: float = 1.0) -> list[Path]:
        """On shutdown: save every live session in which something assessed was done (no fresh ones
        start), trying ``tries`` times, then the temporary folder; discard the others. A session that
        cannot be written anywhere keeps its journal, which the next start closes."""
        written = []
        for session in [seat.session for seat in self.seats]:
            if not session.assessable():
                session.discard()
                continue
            try:
                path = session.save(self.settings.sessions_dir)
            except (ThrsimInputError, OSError):
                self.unsaved.append(session)
                continue
            self.saved.append(path)
            written.append(path)
        for attempt in range(tries):
            if not self.unsaved:
                break
            if attempt:
                time.sleep(pause_s)
            written += self.retry_unsaved()
        fallback = Path(tempfile.gettempdir()) / "thrsim-sessions"
        if self.unsaved:
            with contextlib.suppress(OSError):
                fallback.mkdir(exist_ok=True)
                written += self.retry_unsaved(fallback)
        for session in self.unsaved:
            log.error(
                "session %s lost for now: not saved to %s nor %s; its journal is kept, and the next start closes it",
                session.id,
                self.settings.sessions_dir,
                fallback,
            )
        return written

    def hello(self, seat: Seat, viewer: _Viewer) -> dict:
        """What a viewer gets first and after each end: the session, its role, the observers' link and the scene."""
        session = seat.session
        return {
            "type": "hello",
            "mode": session.mode.name,
            "session": session.id,
            "role": "trainee" if viewer is seat.owner else "observer",
            "observe": f"{session.mode.path}?observe={session.id}",
            "scene": session.trainer.scene(),
            "defaults": session.trainer.defaults(),
            "tick_hz": self.settings.tick_hz,
            "igtl": self.igtl_address,
        }


class _ForwardingTracker(TrackerState):
    """The OpenIGTLink server's tracker state, also forwarding each reading to the trainer's live sessions."""

    def __init__(self, hub: TrainerHub, **kwargs):
        super().__init__(**kwargs)
        self.hub = hub

    def update_pose(self, device: str, pose, time_s: float) -> None:
        super().update_pose(device, pose, time_s)  # validates; raises for a non-rigid pose
        self.hub.on_pose(device, self.poses[device].value, time_s)

    def update_force(self, values, time_s: float) -> float:
        newton = super().update_force(values, time_s)
        self.hub.on_force(newton, time_s)
        return newton


async def _retry_saves(hub: TrainerHub, period: float) -> None:
    """Write the sessions a full disk kept in memory, every ``period`` s (on a worker thread)."""
    while True:
        await asyncio.sleep(period)
        if hub.unsaved:
            await asyncio.to_thread(hub.retry_unsaved)


async def _ticker(hub: TrainerHub, period: float) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time()

    def publish_early(seat: Seat, text: str) -> None:  # on the worker thread: hand over to the event loop
        loop.call_soon_threadsafe(hub.publish, {seat: text})

    while True:
        hub.publish(await asyncio.to_thread(hub.tick, publish_early))
        deadline += period
        delay = deadline - loop.time()
        if delay < -period:
            deadline = loop.time()  # fell behind (a busy machine): skip, do not burst
        await asyncio.sleep(max(0.0, delay))


def _page(mode: Mode) -> HTMLResponse:
    html = (STATIC / mode.page).read_text()
    if not (THREE_DIR / "build" / "three.module.js").is_file():
        html = html.replace(
            "<body>", '<body><p class="fatal">three.js is not installed: run ./install.sh (or npm ci in thrsim/app/static).</p>', 1
        )
    return HTMLResponse(html, headers={"cache-control": "no-store"})


def create_app(settings: ServeSettings) -> FastAPI:
    """The trainer app; its lifespan runs the OpenIGTLink listener and the ticker."""
    settings.check()
    hub = TrainerHub(settings)

    @contextlib.asynccontextmanager
    async def lifespan(app: FastAPI):
        await asyncio.to_thread(close_interrupted, settings.sessions_dir)  # before the tracker and the ticker compete with it
        igtl_server = None
        if settings.igtl:
            from thrsim.io.server import IgtlServer

            first = next(iter(hub.prototypes.values()))  # every mode's pelvis is the same synthetic one
            igtl_tracker = _ForwardingTracker(hub, side=first.side, landmarks=first.targets)
            igtl_config = settings.igtl_config()
            igtl_server = IgtlServer(igtl_config, tracker=igtl_tracker, clock=hub.clock)
            if igtl_config.feedback:
                loop, listener = asyncio.get_running_loop(), igtl_server

                def hand_over(messages: list[tuple[str, str, bytes]]) -> None:  # from the ticker's worker thread or the loop
                    loop.call_soon_threadsafe(listener.broadcast, messages)

                hub.feedback = hand_over
            try:
                hub.igtl_address = await igtl_server.start()
            except OSError as error:
                app.state.startup_error = (
                    f"cannot listen for OpenIGTLink on {igtl_config.host}:{settings.igtl_port}: {error.strerror or error}"
                )
                raise ThrsimInputError(app.state.startup_error) from None
        haptic = None
        if settings.haptic_port is not None and hub.contact_force is not None:
            listen = settings.igtl_config()
            haptic = HapticStream(
                listen.host, settings.haptic_port, settings.haptic_hz, tuple(map(str, listen.allowed_peers)), hub.contact_force
            )
            try:
                hub.haptic_address = await asyncio.to_thread(haptic.start)
            except OSError as error:
                app.state.startup_error = (
                    f"cannot listen for the haptic stream on {listen.host}:{settings.haptic_port}: {error.strerror or error}"
                )
                raise ThrsimInputError(app.state.startup_error) from None
        ticker = asyncio.create_task(_ticker(hub, 1.0 / settings.tick_hz))
        saver = asyncio.create_task(_retry_saves(hub, settings.save_retry_s))
        app.state.ready = True
        announce = getattr(app.state, "announce", None)
        if announce is not None:
            announce(hub.igtl_address or ("(off)", 0))
        try:
            yield
        finally:
            for task in (ticker, saver):
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await task
            if igtl_server is not None:
                await igtl_server.close()
            if haptic is not None:
                await asyncio.to_thread(haptic.close)
            for path in hub.save_all():
                log.warning("session saved on shutdown: %s", path)

    app = FastAPI(title="thrsim trainer", lifespan=lifespan, docs_url=None, redoc_url=None, openapi_url=None)
    app.state.hub = hub
    app.add_middleware(_AccessGate, settings=settings)
    app.mount("/static", StaticFiles(directory=STATIC, check_dir=True), name="static")
    if THREE_DIR.is_dir():
        app.mount("/vendor/three", StaticFiles(directory=THREE_DIR), name="three")

    for mode in MODES.values():
        app.add_api_route(mode.path, lambda mode=mode: _page(mode), methods=["GET"], include_in_schema=False)

    @app.get("/favicon.ico", include_in_schema=False)
    def favicon() -> Response:
        return Response(status_code=204)

    @app.get("/api/pelvis", include_in_schema=False)
    def pelvis() -> Response:
        """The pelvis's bone surface both pages draw (:mod:`thrsim.nav.pelvis_surface`, built on first use)."""
        return Response(surface_payload(pelvis_surface()), media_type="application/octet-stream")

    @app.get("/api/modes")
    def modes() -> dict:
        return {"modes": [{"name": m.name, "path": m.path, "title": m.title} for m in MODES.values()]}

    for mode in MODES.values():
        for path, handler in mode.routes(hub.prototypes[mode.name]):
            app.add_api_route(path, handler, methods=["GET"], include_in_schema=False)

    @app.get("/api/health")
    def health() -> dict:
        figures = {
            "ok": True, "ticks": hub.ticks, "igtl": hub.igtl_address, "sessions": {name: sum(seat.session.mode.name == name for seat in hub.seats) for name in MODES},
            "viewers": {name: sum(len(seat.viewers) for seat in hub.seats if seat.session.mode.name == name) for name in MODES},
        }  # fmt: skip
        for mode in MODES.values():
            figures.update(mode.health(hub.prototypes[mode.name]))
        return figures

    @app.get("/api/sessions")
    def sessions() -> dict:
        files = sorted(settings.sessions_dir.glob("*.h5"))
        return {
            "sessions": [
                {"id": f.stem, "report": f"/sessions/{f.stem}/report", "file": f"/sessions/{f.stem}/file", "interrupted": is_interrupted(f)}
                for f in files
                if _SESSION_ID.match(f.stem)
            ]
        }

    for path, handler, methods in record_routes(settings.sessions_dir, settings.thresholds):  # /sessions, /trainee/<id>, the exports
        app.add_api_route(path, handler, methods=methods, include_in_schema=False)

    def _session_file(session_id: str) -> Path:
        path = settings.sessions_dir / f"{session_id}.h5"
        if not _SESSION_ID.match(session_id) or not path.is_file():
            raise HTTPException(404, f"no saved session {session_id!r}")
        return path

    @app.get("/sessions/{session_id}/file")
    def session_file(session_id: str) -> FileResponse:
        return FileResponse(_session_file(session_id), media_type="application/x-hdf5", filename=f"{session_id}.h5")

    @app.get("/sessions/{session_id}/report")
    async def session_report(session_id: str) -> Response:
        from thrsim.report import build_report

        path = _session_file(session_id)
        try:
            html = await run_in_threadpool(_locked_report, build_report, path, settings.thresholds)
        except ThrsimInputError as error:
            return JSONResponse({"error": str(error)}, status_code=422)
        return HTMLResponse(html)

    @app.websocket("/ws/{mode_name}")
    async def stream(socket: WebSocket, mode_name: str) -> None:
        if mode_name not in MODES:
            await socket.close(code=4404, reason=f"unknown mode {mode_name!r}")
            return
        await socket.accept()
        viewer = _Viewer(socket)
        observe = socket.query_params.get("observe")
        try:
            seat = hub.observe(mode_name, observe, viewer) if observe else await asyncio.to_thread(hub.open_seat, mode_name, viewer)
        except ThrsimInputError as error:  # nothing to observe (4404), or the trainer is full (4429)
            await socket.send_text(json.dumps({"type": "refused", "message": str(error)}))
            await socket.close(code=4404 if observe else 4429, reason="refused")
            return
        sender = asyncio.create_task(_send_states(viewer, seat))
        answers: asyncio.Queue = asyncio.Queue()  # each control's answer, in the order the controls came
        answerer = asyncio.create_task(_answer_controls(hub, seat, viewer, answers))
        try:
            await socket.send_text(json.dumps(hub.hello(seat, viewer)))
            while True:  # never waits for a tick: a control arriving during a slow one queues with its arrival time
                message = await socket.receive()
                if message["type"] == "websocket.disconnect":
                    break
                answers.put_nowait(_submit(seat, viewer, message.get("text")))
        except WebSocketDisconnect:
            pass
        finally:
            sender.cancel()
            answerer.cancel()
            observers = list(seat.observers) if viewer is seat.owner else []
            path = await asyncio.to_thread(hub.leave, seat, viewer)
            over = {"type": "session_over", "message": f"the trainee left session {seat.session.id}" + (" (saved)" if path else "")}
            for other in observers:  # the seat is gone: so is what they observed
                with contextlib.suppress(Exception):
                    await other.socket.send_text(json.dumps(over))
                    await other.socket.close(code=4410, reason="session over")

    return app


def _locked_report(build, path: Path, thresholds: Thresholds | None) -> str:
    with _REPORT_LOCK:
        return build(path, thresholds)


def _submit(seat: Seat, viewer: _Viewer, text: str | None) -> Future | list[tuple[str, dict | str]]:
    """One viewer message: a control queued in the seat's session for its tick (the future of its
    acknowledgement), or the replies refusing it at once (an observer's, not JSON, not a control)."""
    if viewer is not seat.owner:
        return [("one", {"type": "error", "message": f"this page observes session {seat.session.id}: its controls are the trainee's"})]
    if text is None:
        return [("one", {"type": "error", "message": "controls are JSON text messages, not binary"})]
    try:
        return seat.session.submit(text)
    except ThrsimInputError as error:
        log.warning("%s control refused: %s", seat.session.mode.name, error)  # one line per bad message, never a traceback
        return [("one", {"type": "error", "message": str(error)})]


async def _answer_controls(hub: TrainerHub, seat: Seat, viewer: _Viewer, answers: asyncio.Queue) -> None:
    """Answer each of a viewer's controls, in order, once its tick applied it (:func:`_answer`)."""
    while True:
        submitted = await answers.get()
        if not isinstance(submitted, list):
            with contextlib.suppress(Exception):  # a refusal: _answer says it
                await asyncio.wrap_future(submitted)
        # an end saves the session: off the event loop, which must not wait for a tick or the disk
        replies = submitted if isinstance(submitted, list) else await asyncio.to_thread(_answer, hub, seat, submitted)
        for kind, payload in replies:
            for other in seat.viewers if kind == "all" else [viewer]:
                with contextlib.suppress(Exception):
                    await other.socket.send_text(json.dumps(hub.hello(seat, other) if payload == "hello" else payload))


def _answer(hub: TrainerHub, seat: Seat, applied: Future) -> list[tuple[str, dict | str]]:
    """An applied control → replies: ("one", payload) to the sender, ("all", payload) to every viewer
    of the seat ("hello": each viewer's own)."""
    session = seat.session
    try:
        control, ack = applied.result()
    except ThrsimInputError as error:
        log.warning("%s control refused: %s", session.mode.name, error)  # one line per bad message, never a traceback
        return [("one", {"type": "error", "message": str(error)})]
    except Exception as error:  # a trainer bug: refuse this control, keep the session and the server
        log.error("control failed", exc_info=error)
        return [("one", {"type": "error", "message": f"control failed: {error}"})]
    if control.type == "end_session":
        try:
            path = hub.end_asked(seat)
        except (SessionEndTooSoon, NothingToSave) as error:
            return [("one", {"type": "error", "message": f"session not saved: {error}"})]
        except (ThrsimInputError, OSError) as error:  # the session ended; the hub keeps it and retries
            kept = {
                "type": "error",
                "message": f"session kept, not saved yet ({error}); saving it again every {hub.settings.save_retry_s:g} s",
            }
            return [("all", kept), ("all", "hello")]
        saved = {"type": "session_saved", "session": path.stem, "file": str(path), "report": f"/sessions/{path.stem}/report"}
        return [("all", saved), ("all", "hello")]
    if control.type == "side":
        return [("one", {"type": "ack", "message": ack}), ("all", {"type": "scene", "scene": session.trainer.scene()})]
    return [("one", {"type": "ack", "message": ack})]


async def _send_states(viewer: _Viewer, seat: Seat) -> None:
    """Each state the viewer's queue offers, then the mode's binary message for it, if any (the reaming bone)."""
    with contextlib.suppress(Exception):  # the receive loop notices the disconnect and cleans up
        while True:
            await viewer.socket.send_text(await viewer.queue.get())
            binary = seat.session.mode.binary
            found = None if binary is None else binary(seat.session.trainer, viewer.binary_held)
            if found is not None:
                message, viewer.binary_held = found
                await viewer.socket.send_bytes(message)
