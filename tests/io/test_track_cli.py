"""The real commands as subprocesses: ``thrsim track`` serving a pyigtl client end to end and
stopping cleanly on SIGTERM or --duration; ``thrsim nav angles`` for scripting."""

from __future__ import annotations

import json
import signal
import subprocess

import pyigtl
import pytest
from checkout_cli import THRSIM, checkout_env
from igtl_helpers import reamer_pose_mm, wait_until

pytestmark = pytest.mark.timeout(60)


def test_track_serves_pyigtl_and_stops_on_sigterm():
    process = subprocess.Popen(
        [*THRSIM, "track", "--igtl-port", "0", "--json-log", "--log-interval", "0.5"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=checkout_env(),
    )
    client = None
    try:
        listening = json.loads(process.stdout.readline())
        assert listening["event"] == "listening" and listening["host"] == "127.0.0.1"
        client = pyigtl.OpenIGTLinkClient("127.0.0.1", listening["port"])
        assert wait_until(client.is_connected, 10)
        replies = []
        for _ in range(10):
            client.send_message(pyigtl.TransformMessage(reamer_pose_mm(40.0, 15.0), device_name="ReamerToReference"), wait=False)
            reply = client.wait_for_message("NavigationState", timeout=3)
            assert reply is not None, "thrsim track did not answer"
            replies.append(json.loads(reply.string))
        assert (replies[-1]["inclination_deg"], replies[-1]["anteversion_deg"]) == pytest.approx((40.0, 15.0), abs=1e-3)
        assert replies[-1]["in_safe_zone"] is True
        logged = json.loads(process.stdout.readline())  # the periodic state log, within 0.5 s
        assert logged["event"] == "state" and logged["stats"]["replies"] >= 1
    finally:
        if client is not None:
            client.stop()
        process.send_signal(signal.SIGTERM)
        stdout, stderr = process.communicate(timeout=15)
    assert process.returncode == 0, stderr
    lines = [json.loads(line) for line in stdout.splitlines()]
    assert lines[-1]["event"] == "stopped" and lines[-1]["stats"]["replies"] >= 10


def test_track_stops_after_duration_and_refuses_bad_flags():
    finished = subprocess.run(
        [*THRSIM, "track", "--igtl-port", "0", "--duration", "0.5", "--json-log"],
        capture_output=True,
        text=True,
        timeout=30,
        env=checkout_env(),
    )
    assert finished.returncode == 0
    assert json.loads(finished.stdout.splitlines()[-1])["event"] == "stopped"
    bad = subprocess.run([*THRSIM, "track", "--duration", "-1"], capture_output=True, text=True, timeout=30, env=checkout_env())
    assert bad.returncode == 2 and bad.stderr.strip() == "thrsim: error: --duration must be positive, got -1.0"


def test_nav_angles_json_and_errors():
    landmarks = ["--asis-right", "115,0,0", "--asis-left=-115,0,0", "--pubic-right", "22,0,-88", "--pubic-left=-22,0,-88"]
    ok = subprocess.run(
        [*THRSIM, "nav", "angles", "--axis", "0.620885,0.258819,-0.739942", *landmarks, "--json"],
        capture_output=True,
        text=True,
        timeout=30,
        env=checkout_env(),
    )
    assert ok.returncode == 0, ok.stderr
    result = json.loads(ok.stdout)
    assert (result["inclination_deg"], result["anteversion_deg"]) == pytest.approx((40.0, 15.0), abs=1e-3)
    assert result["operative"]["inclination_deg"] == pytest.approx(38.38, abs=0.01)
    assert result["safe_zone"]["colour"] == "green"
    bad = subprocess.run(
        [*THRSIM, "nav", "angles", "--axis", "0,0,0", *landmarks], capture_output=True, text=True, timeout=30, env=checkout_env()
    )
    assert bad.returncode == 2 and bad.stderr.strip() == "thrsim: error: axis is the zero vector"
