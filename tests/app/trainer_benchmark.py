"""Trainer performance figures (not a test: run it by hand; it prints one JSON object).

    python3 tests/app/trainer_benchmark.py [--viewers 10] [--seconds 20] [--soak 600]

A real ``thrsim serve`` child process; N WebSocket viewers, one trainee and the others observing
its session, count the states they receive (updates per second, longest gap); a tracker streams ReamerToReference at 60 Hz over
OpenIGTLink; the server's resident memory is read from /proc at the start and the end;
``--soak S`` runs the whole load for S seconds. The page's drawing speed is ``thrsim bench
--browser``.
"""

from __future__ import annotations

import argparse
import json
import math
import socket
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path[:0] = [str(Path(__file__).parent), str(Path(__file__).resolve().parents[2])]  # this checkout first

from app_helpers import ServedTrainer, read_message, reamer_to_reference
from websockets.sync.client import connect

from thrsim.app.navigation import NavigationTrainer
from thrsim.io import igtl


def rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


class Viewer(threading.Thread):
    def __init__(self, url: str, stop: threading.Event):
        super().__init__(daemon=True)
        self.url, self.stop = url, stop
        self.states, self.max_gap_s, self.dropped, self.error = 0, 0.0, False, ""
        self.counting = False
        self.session = ""  # from its hello

    def run(self) -> None:
        try:
            with connect(self.url, open_timeout=20, max_size=2**20) as ws:
                last = time.monotonic()
                while not self.stop.is_set():
                    message = ws.recv(timeout=5)
                    now = time.monotonic()
                    if not self.session and message.startswith('{"type": "hello"'):
                        self.session = json.loads(message)["session"]
                    if '"type": "state"' in message[:40] or '"type":"state"' in message[:40]:
                        if self.counting:
                            self.states += 1
                            self.max_gap_s = max(self.max_gap_s, now - last)
                        last = now
        except Exception as error:  # a dropped connection is a result here, not a crash
            if not self.stop.is_set():
                self.dropped, self.error = True, repr(error)


class Tracker(threading.Thread):
    """ReamerToReference at 60 Hz, slowly sweeping the aim; reads every reply."""

    def __init__(self, port: int, stop: threading.Event):
        super().__init__(daemon=True)
        self.port, self.stop, self.sent, self.error = port, stop, 0, ""

    def run(self) -> None:
        targets = NavigationTrainer(side="right").targets
        try:
            with socket.create_connection(("127.0.0.1", self.port), timeout=10) as sock:
                start = time.monotonic()
                while not self.stop.is_set():
                    t = time.monotonic() - start
                    pose = reamer_to_reference(targets, 40 + 15 * math.sin(t / 3), 15 + 10 * math.cos(t / 4))
                    sock.sendall(igtl.encode_message(igtl.Message("TRANSFORM", "ReamerToReference", igtl.pack_transform(pose))))
                    read_message(sock)
                    self.sent += 1
                    time.sleep(max(0.0, start + self.sent / 60 - time.monotonic()))
        except Exception as error:
            self.error = repr(error)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--viewers", type=int, default=10)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--soak", type=float, default=0.0, help="run the load this long instead of --seconds")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        served = ServedTrainer(Path(folder), compile=True, timeout=180.0)  # the server as users run it
        try:
            results: dict = {}
            stop = threading.Event()
            url = f"ws://127.0.0.1:{served.port}/ws/navigation"
            trainee = Viewer(url, stop)
            trainee.start()
            while not trainee.session and trainee.is_alive():
                time.sleep(0.05)
            viewers = [trainee] + [Viewer(f"{url}?observe={trainee.session}", stop) for _ in range(args.viewers - 1)]
            tracker = Tracker(served.igtl_port, stop)
            for thread in viewers[1:] + [tracker]:
                thread.start()
            time.sleep(5)  # warm up: connections open, caches filled
            memory_start = rss_mb(served.process.pid)
            for viewer in viewers:
                viewer.counting = True
            start = time.monotonic()
            duration = args.soak or args.seconds
            while time.monotonic() - start < duration:
                time.sleep(1)
            elapsed = time.monotonic() - start
            rates = [v.states / elapsed for v in viewers]
            results.update(
                viewers=args.viewers,
                seconds=round(elapsed, 1),
                states_per_s_min=round(min(rates), 1),
                states_per_s_mean=round(sum(rates) / len(rates), 1),
                longest_gap_s=round(max(v.max_gap_s for v in viewers), 3),
                dropped_connections=sum(v.dropped for v in viewers),
                errors=[v.error for v in viewers if v.error] + ([tracker.error] if tracker.error else []),
                tracker_poses_per_s=round(tracker.sent / (elapsed + 5), 1),
                server_rss_mb_start=round(memory_start, 1),
                server_rss_mb_end=round(rss_mb(served.process.pid), 1),
            )
            results["server_rss_growth_percent"] = round(100 * (results["server_rss_mb_end"] / memory_start - 1), 1)
            stop.set()
            for thread in viewers + [tracker]:
                thread.join(10)
        finally:
            served.stop()
    print(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
