"""`thrsim dataset --scheduler ADDR` against a real, separately started Dask cluster.

A scheduler and a worker (two worker processes via ``--nworkers 2``) run as their own
subprocesses on 127.0.0.1, as a user would start them; the CLI runs as a subprocess too, once
against the scheduler and once with the local pool, and both datasets must hold the same data.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from checkout_cli import THRSIM, checkout_env

from thrsim.data.case_file import data_digest, validate_case
from thrsim.data.generate import read_manifest

distributed = pytest.importorskip("distributed")

pytestmark = pytest.mark.timeout(180)

SWEEP = ["--inclinations", "0,15,30", "--anteversions", "0,90", "--frames", "3", "--extra-forces", "none", "--solver", "synthetic"]
CASES = 5  # γ = 0 at θ 0 and 90 is one physical case
CLI_TIMEOUT_S = 90


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _dask(*args: str) -> list[str]:
    """`dask scheduler ...` / `dask worker ...` through this interpreter (the `dask` console script's entry point)."""
    return [sys.executable, "-m", "dask", *args]


def _stop(proc: subprocess.Popen, timeout: float = 15.0) -> None:
    """SIGTERM the process group started for ``proc`` (a nanny's worker processes included), then SIGKILL."""
    if proc.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGTERM)
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=timeout)
    with contextlib.suppress(ProcessLookupError):  # leftovers in the group (or a process ignoring SIGTERM)
        os.killpg(proc.pid, signal.SIGKILL)
    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(timeout=5)


@pytest.fixture
def dask_cluster(tmp_path):
    """tcp://127.0.0.1:PORT of a scheduler with one `dask worker --nworkers 2 --nthreads 1`, torn down after the test."""
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    logs = tmp_path / "dask-logs"
    logs.mkdir()
    procs: list[tuple[subprocess.Popen, object]] = []
    files = contextlib.ExitStack()

    def start(name: str, cmd: list[str]) -> subprocess.Popen:
        log = files.enter_context(open(logs / f"{name}.log", "wb"))  # noqa: SIM115 - closed by the ExitStack
        # own session: the whole group (nanny + worker processes) can be signalled together
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=tmp_path, start_new_session=True, env=checkout_env())
        procs.append((proc, log))
        return proc

    try:
        start("scheduler", _dask("scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard", "--idle-timeout", "600"))
        start(
            "worker",
            _dask(
                "worker",
                address,
                "--nworkers",
                "2",
                "--nthreads",
                "1",
                "--no-dashboard",
                "--host",
                "127.0.0.1",
                "--local-directory",
                str(tmp_path / "dask-worker-space"),
                "--death-timeout",
                "60",
            ),
        )
        yield address, procs, logs
    finally:
        for proc, _ in reversed(procs):  # workers first, then the scheduler
            _stop(proc)
        files.close()


def _logs(logs: Path) -> str:
    return "\n".join(f"--- {p.name}\n{p.read_text(errors='replace')[-3000:]}" for p in sorted(logs.glob("*.log")))


def _run_cli(out: Path, *extra: str) -> dict:
    cmd = [*THRSIM, "dataset", "--out", str(out), *SWEEP, "--json", *extra]
    done = subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=CLI_TIMEOUT_S, cwd=out.parent, env=checkout_env())
    assert done.returncode == 0, f"{' '.join(cmd)} exited {done.returncode}\nstdout: {done.stdout}\nstderr: {done.stderr}"
    return json.loads(done.stdout)


def test_cli_on_external_dask_cluster_matches_local_pool(tmp_path, dask_cluster):
    address, procs, logs = dask_cluster

    # the local run goes first: the cluster comes up meanwhile
    local = _run_cli(tmp_path / "local", "--workers", "2")

    with distributed.Client(address, timeout="60s", set_as_default=False) as client:
        try:
            client.wait_for_workers(2, timeout=60)
        except TimeoutError:
            pytest.fail(f"the Dask workers did not register within 60 s\n{_logs(logs)}")
        worker_pids = set(client.run(os.getpid).values())
    assert len(worker_pids) == 2
    assert all(proc.poll() is None for proc, _ in procs), _logs(logs)

    remote = _run_cli(tmp_path / "dask", "--scheduler", address, "--connect-timeout", "10")

    for summary in (local, remote):
        assert (summary["cases"], summary["generated"], summary["failed"], summary["skipped"]) == (CASES, CASES, 0, 0), summary
        assert summary["frames_generated"] == 3 * CASES
    assert "local process pool" in local["executor"]
    assert remote["executor"] == f"Dask scheduler {address}, 2 worker(s)"

    a, b = read_manifest(tmp_path / "local")["cases"], read_manifest(tmp_path / "dask")["cases"]
    assert sorted(a) == sorted(b) and len(a) == CASES
    for case_id in a:
        ea, eb = a[case_id], b[case_id]
        assert ea["status"] == eb["status"] == "complete"
        assert ea["split"] == eb["split"] and ea["params"] == eb["params"]
        pa, pb = tmp_path / "local" / ea["file"], tmp_path / "dask" / eb["file"]
        da, db = data_digest(pa), data_digest(pb)
        assert da == ea["data_digest"] and db == eb["data_digest"]  # the manifests describe the files on disk
        assert da == db, f"{case_id}: local and Dask data differ"
        sa, sb = validate_case(pa), validate_case(pb)
        assert sa["frames"] == sb["frames"] == 3 and sa["elements"] == sb["elements"] > 0
        assert sa["removed"] == sb["removed"] == ea["removed"] == eb["removed"]
        # the Dask cases ran in the external worker processes, not in the CLI process
        host, _, pid = eb["worker"].rpartition(":")
        assert host == socket.gethostname() and int(pid) in worker_pids, (eb["worker"], worker_pids)
    for root in (tmp_path / "local", tmp_path / "dask"):
        assert sorted(p.name for p in (root / "cases").iterdir()) == sorted(f"{c}.h5" for c in a)  # no .part left over

    # a rerun against the same cluster skips everything
    again = _run_cli(tmp_path / "dask", "--scheduler", address, "--connect-timeout", "10")
    assert (again["skipped"], again["generated"]) == (CASES, 0)
