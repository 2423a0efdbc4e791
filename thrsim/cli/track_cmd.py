"""``thrsim track``: run the OpenIGTLink navigation service headless and log its state."""

from __future__ import annotations

import asyncio
import json
import math
import signal
import time

import typer

from thrsim.cli.output import console
from thrsim.config import OPENIGTLINK_PORT, IgtlConfig
from thrsim.errors import ThrsimInputError

_DEFAULT = IgtlConfig()


def _log_line(event: str, payload: dict, json_log: bool) -> None:
    if json_log:
        # One object per line, flushed: a supervising process reads it as it comes.
        print(json.dumps({"event": event, "time": time.time(), **payload}, default=str), flush=True)
        return
    if event != "state":
        console.log(f"[bold]{event}[/bold] " + " ".join(f"{k}={v}" for k, v in payload.items()))
        return
    state, stats = payload["state"], payload["stats"]
    if state["inclination_deg"] is None:
        angles = f"angles: — ({state['note']})"
    else:
        colour = {"green": "green", "amber": "yellow", "red": "red"}[state["ray_colour"]]
        angles = (
            f"[{colour}]inclination {state['inclination_deg']:.1f}° anteversion {state['anteversion_deg']:.1f}° "
            f"(zone distance {state['distance_to_zone_deg']:.1f}°)[/{colour}]"
        )
    force = "—" if state["force_n"] is None else f"{state['force_n']:.0f} N"
    tracking = ", ".join(f"{tool} {status}" for tool, status in state["tracking"].items())
    console.log(
        f"clients {payload['clients']} | msgs {stats['messages']} (bad crc {stats['bad_crc']}, dropped {stats['protocol_errors'] + stats['oversize']}) "
        f"| {angles} | force {force} | {tracking}"
    )


async def _serve(config: IgtlConfig, duration: float | None, json_log: bool, interval: float) -> dict:
    from thrsim.io.server import IgtlServer  # asyncio server: loaded only when tracking

    server = IgtlServer(config)
    try:
        host, port = await server.start()
    except OSError as error:
        raise ThrsimInputError(f"cannot listen on {config.host}:{config.port}: {error.strerror or error}") from None
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for signum in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(signum, stop.set)
    _log_line("listening", {"host": host, "port": port}, json_log)
    deadline = None if duration is None else loop.time() + duration
    try:
        while not stop.is_set():
            wait = interval if deadline is None else min(interval, deadline - loop.time())
            if wait <= 0:
                break
            try:
                await asyncio.wait_for(stop.wait(), wait)
            except TimeoutError:
                _log_line("state", server.snapshot(), json_log)
    finally:
        for signum in (signal.SIGINT, signal.SIGTERM):
            loop.remove_signal_handler(signum)
        await server.close()
    summary = {"host": host, "port": port, "stats": dict(server.stats)}
    _log_line("stopped", summary, json_log)
    return summary


def track(
    igtl_port: int = typer.Option(OPENIGTLINK_PORT, "--igtl-port", help="OpenIGTLink port (0: any free port, printed at start)"),
    host: str = typer.Option("127.0.0.1", "--host", help="interface to listen on"),
    duration: float | None = typer.Option(
        None, "--duration", help="stop after this many seconds (default: until SIGINT/SIGTERM)", metavar="S"
    ),
    json_log: bool = typer.Option(False, "--json-log", help="log one JSON object per line on stdout instead of rich text"),
    log_interval: float = typer.Option(1.0, "--log-interval", help="seconds between state log lines", metavar="S"),
    idle_timeout: float = typer.Option(
        _DEFAULT.idle_timeout_s, "--idle-timeout", help="close a connection that sends nothing for this long", metavar="S"
    ),
    devices: list[str] | None = typer.Option(
        None,
        "--device",
        help=f"accept TRANSFORMs under this device name too (repeatable; always: {', '.join(_DEFAULT.known_devices)})",
        metavar="NAME",
    ),
) -> None:
    """Serve tracker poses (TRANSFORM) and force (SENSOR) over OpenIGTLink; reply NavigationState; log state.

    It listens on 127.0.0.1 by default. The protocol has no authentication or encryption: to
    reach it from another machine, prefer an SSH tunnel (``ssh -L 18944:127.0.0.1:18944 HOST``)
    or a private interface over ``--host 0.0.0.0``.
    """
    if duration is not None and not duration > 0:  # NaN too: a NaN deadline never comes
        raise ThrsimInputError(f"--duration must be positive, got {duration}")
    if not 0 < log_interval < math.inf:
        raise ThrsimInputError(f"--log-interval must be a positive number of seconds, got {log_interval}")
    known = tuple(dict.fromkeys((*_DEFAULT.known_devices, *(devices or ()))))
    config = IgtlConfig(host=host, port=igtl_port, idle_timeout_s=idle_timeout, known_devices=known)
    asyncio.run(_serve(config, duration, json_log, log_interval))
