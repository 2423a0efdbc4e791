"""The trainer's web app: pages, a WebSocket per mode, the OpenIGTLink listener, the ticker.

One process serves everything. Every ``1/tick_hz`` s the ticker steps each mode's live session
on a worker thread (a reaming frame costs tens of milliseconds; the event loop keeps serving
meanwhile) and hands the state to each viewer's sender; a viewer's queue holds only the newest
state, so a slow viewer skips frames instead of slowing the others or growing memory. The
reaming mode's bone goes to each viewer as binary frames of what changed since what that viewer
last received (:mod:`thrsim.app.bone_stream`). Tracker poses reach
the live sessions through the OpenIGTLink server's session object (its public ``session=``
hook). A session ends when a viewer asks (or the server stops): it is written atomically to
``sessions_dir`` and a fresh one starts at once.

Access: on a loopback address no token is needed unless one is given; on any other address a
token is required, and every HTTP request and WebSocket handshake must carry it (``?token=``,
a ``thrsim_token`` cookie the page gets on first load, or ``Authorization: Bearer``). WebSocket
handshakes from another site's page (a foreign ``Origin``) are refused as well.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import ipaddress
import json
import logging
import re
import secrets
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

import numpy as np
from fastapi import FastAPI, HTTPException, WebSocket, WebSocketDisconnect
from fastapi.responses import FileResponse, HTMLResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles
from starlette.concurrency import run_in_threadpool

from thrsim.app.live import STATIC, THREE_DIR, LiveSession
from thrsim.app.modes import MODES, Mode
from thrsim.config import IgtlConfig
from thrsim.errors import ThrsimInputError
from thrsim.nav.session import NavigationSession

log = logging.getLogger(__name__)

TOKEN_COOKIE = "thrsim_token"
_SESSION_ID = re.compile(r"^[0-9]{8}T[0-9]{6}Z-[0-9a-f]{6}$")
_REPORT_LOCK = threading.Lock()  # matplotlib's pyplot is not safe for two reports at once


def is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


@dataclass
class ServeSettings:
    host: str = "127.0.0.1"
    port: int = 8000
    igtl_port: int = 18944
    token: str | None = None
    sessions_dir: Path = Path("sessions")
    side: str = "right"
    seed: int | None = None  # None: a fresh one per session
    tick_hz: float = 60.0
    igtl: bool = True
    model: Path | None = None  # the reaming mode's model folder (None: the shipped model)
    compile: bool = True  # run the reaming network compiled (thrsim.learn.compiled), compiled at start

    def check(self) -> None:
        if not is_loopback(self.host) and not self.token:
            raise ThrsimInputError(f"--host {self.host} is reachable from other machines: give an access token (--token or THRSIM_TOKEN)")
        if self.token is not None and len(self.token) < 8:
            raise ThrsimInputError("the access token must be at least 8 characters")
        if self.side not in ("right", "left"):
            raise ThrsimInputError(f"--side must be right or left, got {self.side!r}")
        if not self.sessions_dir.is_dir():
            raise ThrsimInputError(f"sessions folder {self.sessions_dir} does not exist")
        if self.model is not None and not self.model.is_dir():
            raise ThrsimInputError(f"--model {self.model}: no such model folder")


class _TokenGate:
    """ASGI middleware: every HTTP request and WebSocket handshake must carry the token."""

    def __init__(self, app, token: str | None):
        self.app = app
        self.token = token

    def _presented(self, scope) -> tuple[str | None, bool]:
        query = parse_qs(scope.get("query_string", b"").decode("latin-1")).get("token", [None])[0]
        if query is not None:
            return query, True
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}
        auth = headers.get("authorization", "")
        if auth.lower().startswith("bearer "):
            return auth[7:].strip(), False
        for part in headers.get("cookie", "").split(";"):
            name, _, value = part.strip().partition("=")
            if name == TOKEN_COOKIE:
                return value, False
        return None, False

    def _origin_ok(self, scope) -> bool:
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}
        origin = headers.get("origin")
        return origin is None or urlsplit(origin).netloc == headers.get("host")

    async def __call__(self, scope, receive, send):
        if scope["type"] not in ("http", "websocket"):
            return await self.app(scope, receive, send)
        if scope["type"] == "websocket" and not self._origin_ok(scope):
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


@dataclass(eq=False)  # hashed by identity: viewers live in a set
class _Viewer:
    socket: WebSocket
    queue: asyncio.Queue = field(default_factory=lambda: asyncio.Queue(maxsize=1))
    sent: int = 0
    levels_sent: np.ndarray | None = None  # the bone as this viewer last received it (reaming)
    bone_bytes: int = 0

    def offer(self, text: str) -> None:
        if self.queue.full():
            self.queue.get_nowait()  # newest state wins
        self.queue.put_nowait(text)


class TrainerHub:
    """The live sessions of every mode, their viewers, and the save on end."""

    def __init__(self, settings: ServeSettings, clock=time.monotonic):
        self.settings = settings
        self.clock = clock
        self.sessions: dict[str, LiveSession] = {name: self._start(mode) for name, mode in MODES.items()}
        self.viewers: dict[str, set[_Viewer]] = {name: set() for name in MODES}
        self.saved: list[Path] = []
        self.ticks = 0
        self.igtl_address: tuple[str, int] | None = None

    def _start(self, mode: Mode) -> LiveSession:
        seed = self.settings.seed if self.settings.seed is not None else secrets.randbits(31)
        settings = {"side": self.settings.side, "seed": seed}
        if self.settings.model is not None:
            settings["model"] = str(self.settings.model)
        if self.settings.compile and mode.name == "reaming":
            settings["compile"] = True
        return LiveSession(mode, settings, self.clock)

    def reaming_network(self) -> dict:
        """How the reaming session's network runs: compiled, eager (with why, if compiling failed) or none."""
        simulator = getattr(self.sessions["reaming"].trainer, "simulator", None)
        if simulator is None:
            return {"state": "none"}
        return {"state": "compiled" if simulator.compiled else "eager", "compile_error": simulator.compile_error}

    def on_pose(self, device: str, pose, clock_time: float) -> None:
        """A tracker pose for every mode's session (queued there: this never waits for a step)."""
        for session in self.sessions.values():
            session.pose(device, pose, clock_time)

    def on_force(self, newton: float, clock_time: float) -> None:
        for session in self.sessions.values():
            session.force(newton, clock_time)

    def tick(self, publish_early: Callable[[str, str], None] | None = None) -> dict[str, str]:
        """Step every mode's session (on the ticker's worker thread); the state texts to publish.
        ``publish_early(mode, text)`` publishes a state a slow step hands out ahead of its end."""
        self.ticks += 1
        texts = {}
        for name, session in list(self.sessions.items()):

            def early(state: dict, name: str = name) -> None:
                publish_early(name, json.dumps(state, allow_nan=False))

            try:
                state = session.tick(early if publish_early is not None and self.viewers[name] else None)
                if self.viewers[name]:
                    texts[name] = json.dumps(state, allow_nan=False)
            except Exception:  # a trainer bug must not stop the other modes or lose the session
                log.exception("%s step failed", name)
        return texts

    def publish(self, texts: dict[str, str]) -> None:
        """Hand the states to the viewers' senders (on the event loop)."""
        for name, text in texts.items():
            for viewer in self.viewers[name]:
                viewer.offer(text)

    def end(self, name: str) -> Path:
        """Save the mode's session and start a fresh one."""
        session = self.sessions[name]
        path = session.save(self.settings.sessions_dir)
        self.saved.append(path)
        self.sessions[name] = self._start(session.mode)
        return path

    def save_all(self) -> list[Path]:
        """On shutdown: keep every session that received anything."""
        return [self.end(name) for name, session in list(self.sessions.items()) if session.inputs.count > session.inputs.ticks]

    def hello(self, name: str) -> dict:
        session = self.sessions[name]
        return {"type": "hello", "mode": name, "session": session.id, "scene": session.trainer.scene(), "igtl": self.igtl_address}


class _ForwardingSession(NavigationSession):
    """The OpenIGTLink server's navigation session, also forwarding each reading to the trainer."""

    def __init__(self, hub: TrainerHub, **kwargs):
        super().__init__(**kwargs)
        self.hub = hub

    def update_pose(self, device: str, pose, time_s: float) -> None:
        super().update_pose(device, pose, time_s)  # validates; raises for a non-rigid pose
        self.hub.on_pose(device, self.poses[device].value, time_s)

    def update_force(self, values, time_s: float) -> None:
        super().update_force(values, time_s)
        self.hub.on_force(self.force.value, time_s)


async def _ticker(hub: TrainerHub, period: float) -> None:
    loop = asyncio.get_running_loop()
    deadline = loop.time()

    def publish_early(name: str, text: str) -> None:  # on the worker thread: hand over to the event loop
        loop.call_soon_threadsafe(hub.publish, {name: text})

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
        igtl_server = None
        if settings.igtl:
            from thrsim.io.server import NavigationServer

            first = next(iter(hub.sessions.values())).trainer
            igtl_session = _ForwardingSession(hub, side=first.side, landmarks=getattr(first, "targets", None))
            igtl_server = NavigationServer(IgtlConfig(host=settings.host, port=settings.igtl_port), session=igtl_session, clock=hub.clock)
            try:
                hub.igtl_address = await igtl_server.start()
            except OSError as error:
                app.state.startup_error = (
                    f"cannot listen for OpenIGTLink on {settings.host}:{settings.igtl_port}: {error.strerror or error}"
                )
                raise ThrsimInputError(app.state.startup_error) from None
        ticker = asyncio.create_task(_ticker(hub, 1.0 / settings.tick_hz))
        app.state.ready = True
        announce = getattr(app.state, "announce", None)
        if announce is not None:
            announce(hub.igtl_address or ("(off)", 0))
        try:
            yield
        finally:
            ticker.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await ticker
            if igtl_server is not None:
                await igtl_server.close()
            for path in hub.save_all():
                log.warning("session saved on shutdown: %s", path)

    app = FastAPI(title="thrsim trainer", lifespan=lifespan, docs_url=None, redoc_url=None, openapi_url=None)
    app.state.hub = hub
    app.add_middleware(_TokenGate, token=settings.token)
    app.mount("/static", StaticFiles(directory=STATIC, check_dir=True), name="static")
    if THREE_DIR.is_dir():
        app.mount("/vendor/three", StaticFiles(directory=THREE_DIR), name="three")

    for mode in MODES.values():
        app.add_api_route(mode.path, lambda mode=mode: _page(mode), methods=["GET"], include_in_schema=False)

    @app.get("/favicon.ico", include_in_schema=False)
    def favicon() -> Response:
        return Response(status_code=204)

    @app.get("/api/modes")
    def modes() -> dict:
        return {"modes": [{"name": m.name, "path": m.path, "title": m.title} for m in MODES.values()]}

    mesh_bytes: dict[str, bytes] = {}

    @app.get("/api/reaming/mesh")
    def reaming_mesh() -> Response:
        simulator = getattr(hub.sessions["reaming"].trainer, "simulator", None)
        if simulator is None:
            raise HTTPException(404, hub.sessions["reaming"].trainer.unavailable or "no reaming model")
        if simulator.model.graph.digest not in mesh_bytes:
            from thrsim.app.bone_stream import mesh_payload

            mesh_bytes[simulator.model.graph.digest] = mesh_payload(simulator.right_mesh)
        return Response(mesh_bytes[simulator.model.graph.digest], media_type="application/octet-stream")

    @app.get("/api/health")
    def health() -> dict:
        return {
            "ok": True, "ticks": hub.ticks, "igtl": hub.igtl_address, "viewers": {k: len(v) for k, v in hub.viewers.items()},
            "reaming_network": hub.reaming_network(),
        }  # fmt: skip

    @app.get("/api/sessions")
    def sessions() -> dict:
        files = sorted(settings.sessions_dir.glob("*.h5"))
        return {
            "sessions": [
                {"id": f.stem, "report": f"/sessions/{f.stem}/report", "file": f"/sessions/{f.stem}/file"}
                for f in files
                if _SESSION_ID.match(f.stem)
            ]
        }

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
            html = await run_in_threadpool(_locked_report, build_report, path)
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
        hub.viewers[mode_name].add(viewer)
        sender = asyncio.create_task(_send_states(viewer, hub, mode_name))
        try:
            await socket.send_text(json.dumps(hub.hello(mode_name)))
            while True:
                message = await socket.receive()
                if message["type"] == "websocket.disconnect":
                    break
                reply = _handle(hub, mode_name, message.get("text"))
                for kind, payload in reply:
                    if kind == "all":
                        for other in list(hub.viewers[mode_name]):
                            with contextlib.suppress(Exception):
                                await other.socket.send_text(json.dumps(payload))
                    else:
                        await socket.send_text(json.dumps(payload))
        except WebSocketDisconnect:
            pass
        finally:
            hub.viewers[mode_name].discard(viewer)
            sender.cancel()

    return app


def _locked_report(build, path: Path) -> str:
    with _REPORT_LOCK:
        return build(path)


def _handle(hub: TrainerHub, mode_name: str, text: str | None) -> list[tuple[str, dict]]:
    """One viewer message → replies: ("one", payload) to the sender, ("all", payload) to every viewer."""
    if text is None:
        return [("one", {"type": "error", "message": "controls are JSON text messages, not binary"})]
    session = hub.sessions[mode_name]
    try:
        control, ack = session.control(text)
    except ThrsimInputError as error:
        log.warning("%s control refused: %s", mode_name, error)  # one line per bad message, never a traceback
        return [("one", {"type": "error", "message": str(error)})]
    except Exception as error:  # a trainer bug: refuse this control, keep the session and the server
        log.exception("control failed")
        return [("one", {"type": "error", "message": f"control failed: {error}"})]
    if control.type == "end_session":
        try:
            path = hub.end(mode_name)
        except (ThrsimInputError, OSError) as error:
            return [("one", {"type": "error", "message": f"session not saved: {error}"})]
        saved = {"type": "session_saved", "session": path.stem, "file": str(path), "report": f"/sessions/{path.stem}/report"}
        return [("all", saved), ("all", hub.hello(mode_name))]
    if control.type == "side":
        return [("one", {"type": "ack", "message": ack}), ("all", {"type": "scene", "scene": session.trainer.scene()})]
    return [("one", {"type": "ack", "message": ack})]


async def _send_states(viewer: _Viewer, hub: TrainerHub, mode_name: str) -> None:
    from thrsim.app.bone_stream import update

    with contextlib.suppress(Exception):  # the receive loop notices the disconnect and cleans up
        while True:
            await viewer.socket.send_text(await viewer.queue.get())
            viewer.sent += 1
            trainer = hub.sessions[mode_name].trainer
            levels = getattr(trainer, "levels", None)
            if levels is None or len(levels) == 0:
                continue
            message = update(trainer.frames_run, viewer.levels_sent, levels)
            if message is not None:
                await viewer.socket.send_bytes(message)
                viewer.levels_sent = levels  # the trainer replaces its array, never mutates it
                viewer.bone_bytes += len(message)
