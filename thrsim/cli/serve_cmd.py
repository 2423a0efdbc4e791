"""``thrsim serve``: the browser trainer (pages, WebSocket state stream, OpenIGTLink listener)."""

from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import socket
import sys
from dataclasses import replace
from pathlib import Path

import typer

from thrsim.config import HAPTIC_RATE_HZ, OPENIGTLINK_PORT
from thrsim.errors import ThrsimInputError


def _uvicorn_server(config):
    import uvicorn

    class _Server(uvicorn.Server):
        @contextlib.contextmanager
        def capture_signals(self):
            # Ctrl-C or SIGTERM: shut down (saving live sessions) and exit 0, not re-raise the signal.
            previous = {signum: signal.signal(signum, self.handle_exit) for signum in (signal.SIGINT, signal.SIGTERM)}
            try:
                yield
            finally:
                for signum, handler in previous.items():
                    signal.signal(signum, handler)

    return _Server(config)


def _access_token(token: str | None, token_file: Path | None) -> str | None:
    """The access token: from --token-file, else --token (with a warning: a command line is public),
    else the THRSIM_TOKEN environment variable; None when there is none."""
    if token is not None and token_file is not None:
        raise ThrsimInputError("give the access token once: --token-file PATH or THRSIM_TOKEN, not --token as well")
    if token_file is not None:
        try:
            return token_file.read_text().strip()
        except (OSError, UnicodeDecodeError) as error:
            raise ThrsimInputError(f"cannot read the access token from {token_file}: {getattr(error, 'strerror', None) or error}") from None
    if token is not None:
        print(
            "thrsim serve: warning: --token shows the token to every user of this machine (ps); use --token-file or THRSIM_TOKEN",
            file=sys.stderr,
        )
        return token
    return os.environ.get("THRSIM_TOKEN") or None


def serve(
    port: int = typer.Option(8000, "--port", help="HTTP port of the trainer page (0: any free port, printed at start)"),
    igtl_port: int = typer.Option(OPENIGTLINK_PORT, "--igtl-port", help="OpenIGTLink port for a tracker (0: any free port)"),
    host: str = typer.Option("127.0.0.1", "--host", help="interface to listen on; beyond loopback a token is required"),
    token_file: Path | None = typer.Option(
        None, "--token-file", help="file holding the access token every request must carry (or env THRSIM_TOKEN)", metavar="PATH"
    ),
    token: str | None = typer.Option(
        None, "--token", help="the access token itself: every user of this machine sees it in ps; prefer --token-file or THRSIM_TOKEN"
    ),
    allow_host: list[str] = typer.Option(
        [], "--allow-host", help="off loopback: a host name the trainer may be opened by (addresses need none; repeatable)", metavar="NAME"
    ),
    igtl_host: str | None = typer.Option(
        None, "--igtl-host", help="interface the OpenIGTLink listener listens on (default: loopback, whatever --host)"
    ),
    igtl_allow: list[str] = typer.Option(
        [],
        "--igtl-allow",
        help="a network or address whose trackers the OpenIGTLink listener serves, beyond loopback (repeatable)",
        metavar="ADDR/NET",
    ),
    igtl_feedback: bool = typer.Option(
        False,
        "--igtl-feedback",
        help="send every OpenIGTLink peer the sessions' events (STRING thrsimEvent) and the simulated reamer (TRANSFORM SimReamerToBone)",
    ),
    haptic_port: int | None = typer.Option(
        None,
        "--haptic-port",
        help="also stream the force a haptic device renders (SENSOR ReamerReaction, ReamerTorque) on this port of the OpenIGTLink "
        "listener's address, far faster than the frames (0: any free port; default: off)",
        metavar="PORT",
    ),
    haptic_hz: float = typer.Option(HAPTIC_RATE_HZ, "--haptic-hz", help="the haptic stream's rate, 100 to 10000", metavar="HZ"),
    socket_element_size: float | None = typer.Option(
        None,
        "--socket-element-size",
        help="a whole-socket --model reams the case's socket meshed at this element size, 0.3 to 5 mm [default: 1.5]",
        metavar="MM",
    ),
    sessions: Path = typer.Option(
        Path("sessions"), "--sessions", help="folder where ended sessions are saved (created if absent)", metavar="DIR"
    ),
    side: str = typer.Option("right", "--side", help="operated hip at start: right or left"),
    seed: int | None = typer.Option(None, "--seed", help="random seed of the simulated hand (default: a new one per session)"),
    model: Path | None = typer.Option(
        None, "--model", help="the reaming mode's learned-simulator model (default: the shipped model)", metavar="MODEL_DIR"
    ),
    compile: bool = typer.Option(
        True,
        "--compile/--no-compile",
        help="compile the reaming network in the background (torch.compile; about 10 s, a minute on a first run; faster steps once done)",
    ),
    plan_file: Path | None = typer.Option(
        None, "--plan", help="an instructor's case file: the reaming plan every session starts with, fixed (JSON or YAML)", metavar="FILE"
    ),
    thresholds_file: Path | None = typer.Option(
        None,
        "--thresholds",
        help="competency thresholds the served reports score against (JSON or YAML; default: the shipped ones)",
        metavar="FILE",
    ),
    phantom_file: Path | None = typer.Option(
        None,
        "--phantom",
        help="a lab's 3-D printed pelvis: its landmarks and headset calibration target in its marker array's frame (JSON; see the docs' Headset page)",
        metavar="FILE",
    ),
    as_json: bool = typer.Option(
        False,
        "--json",
        help="announce the trainer as one JSON object on one line of stdout (url, ports, sessions folder) instead of a line of text",
    ),
) -> None:
    """Serve the trainer: open the printed address in a browser; end a session there to get its report."""
    import uvicorn

    from thrsim.app.server import ServeSettings, create_app
    from thrsim.nav.phantom import read_phantom_file
    from thrsim.report.thresholds import load_thresholds
    from thrsim.session.plan import load_plan

    if not 0 <= port <= 65535 or not 0 <= igtl_port <= 65535:
        raise ThrsimInputError("ports must lie in 0..65535")
    if seed is not None and seed < 0:
        raise ThrsimInputError(f"--seed must be a non-negative integer, got {seed}")
    if not sessions.exists() and not sessions.parent.is_dir():
        raise ThrsimInputError(f"cannot create sessions folder {sessions}: {sessions.parent} does not exist")
    plan = None if plan_file is None else load_plan(plan_file)
    thresholds = load_thresholds(thresholds_file)
    phantom = None if phantom_file is None else read_phantom_file(phantom_file)
    settings = ServeSettings(
        host=host, port=port, igtl_port=igtl_port, token=_access_token(token, token_file), sessions_dir=sessions, side=side, seed=seed,
        model=model, compile=compile, allowed_hosts=tuple(allow_host), igtl_host=igtl_host, igtl_allow=tuple(igtl_allow), igtl_feedback=igtl_feedback,
        plan=plan, thresholds=thresholds, haptic_port=haptic_port, haptic_hz=haptic_hz,
        socket_element_size_mm=socket_element_size, phantom=phantom,
    )  # fmt: skip
    # refusals are one line, before the ports are taken, the network compiled or the sessions folder made
    # (checked as the folder it will be made in, so that a refused start leaves nothing behind)
    replace(settings, sessions_dir=sessions if sessions.exists() else sessions.parent).check()
    try:
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        listener = socket.socket(family, socket.SOCK_STREAM)
        listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        listener.bind((host, port))
        listener.listen(128)  # connections wait in the backlog until the app has started
    except OSError as error:
        raise ThrsimInputError(f"cannot listen on {host}:{port}: {error.strerror or error}") from None
    # Refuse a taken OpenIGTLink or haptic port here, as one line, before the app starts.
    igtl_listen = settings.igtl_config().host
    for what, wanted in (("OpenIGTLink", igtl_port), ("the haptic stream", haptic_port)):
        if not wanted:  # off, or any free port
            continue
        try:
            with socket.socket(socket.AF_INET6 if ":" in igtl_listen else socket.AF_INET, socket.SOCK_STREAM) as probe:
                probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                probe.bind((igtl_listen, wanted))
        except OSError as error:
            listener.close()
            raise ThrsimInputError(f"cannot listen for {what} on {igtl_listen}:{wanted}: {error.strerror or error}") from None
    if compile:
        print(
            "thrsim serve: compiling the reaming network (about 10 s; 30 s or more the first time on a machine; --no-compile skips it)",
            file=sys.stderr,
            flush=True,
        )
    sessions.mkdir(exist_ok=True)
    app = create_app(settings)  # checks the settings: a refusal is one line, exit 2
    bound_port = listener.getsockname()[1]
    shown_host = f"[{host}]" if ":" in host else host
    url = f"http://{shown_host}:{bound_port}/"

    def announce(igtl: tuple[str, int]) -> None:
        haptic = app.state.hub.haptic_address
        if as_json:
            off = igtl[1] == 0
            where = {"igtl_host": None if off else igtl[0], "igtl_port": None if off else igtl[1]}
            where |= {"haptic_port": None if haptic is None else haptic[1]}
            print(json.dumps({"url": url, "host": host, "port": bound_port, **where, "sessions": str(sessions)}))
        else:
            print(
                f"thrsim trainer: {url}{'?token=…' if token else ''} · OpenIGTLink on {igtl[0]}:{igtl[1]} · sessions saved in {sessions}/"
                + ("" if haptic is None else f" · haptic stream on {haptic[0]}:{haptic[1]}")
            )
        sys.stdout.flush()

    app.state.announce = announce
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    config = uvicorn.Config(app, log_level="warning", ws_max_size=64 * 1024, ws_ping_interval=20, ws_ping_timeout=20, lifespan="on")
    _uvicorn_server(config).run(sockets=[listener])
    if not getattr(app.state, "ready", False):
        raise ThrsimInputError(getattr(app.state, "startup_error", "the trainer did not start"))
