"""Every writer on a disk that fills: one line naming the file, exit 2, no temporary file left,
the previous file untouched, no native crash (h5py used to end in SIGSEGV, exit 139).

Each test runs twice: on a real tmpfs mounted small (needs root, skipped otherwise) and under a
file-size limit (RLIMIT_FSIZE with SIGXFSZ ignored, so a write past it fails with EFBIG), which
any CI machine has.
"""

from __future__ import annotations

import contextlib
import errno
import filecmp
import json
import math
import os
import resource
import shutil
import signal
import subprocess
from pathlib import Path

import numpy as np
import pytest
from checkout_cli import THRSIM, checkout_env

from thrsim.errors import ThrsimInputError, ThrsimOutputError

pytestmark = pytest.mark.timeout(300)

KINDS = ("tmpfs", "file-size-limit")
PAGE = 4096


def pages(size: int) -> int:
    return math.ceil(size / PAGE) * PAGE


class FullDisk:
    """A folder where a new file gets ``room`` bytes at most, holding a copy of ``keep`` (a file or folder)."""

    def __init__(self, kind: str, base: Path, room: int, keep: Path | None):
        self.kind, self.room = kind, room
        self.folder = base / "disk"
        self.folder.mkdir()
        self.mounted = False
        kept = 0  # tmpfs counts whole pages of file data
        if keep is not None:
            kept = sum(pages(p.stat().st_size) for p in ([keep] if keep.is_file() else keep.rglob("*")) if p.is_file())
        if kind == "tmpfs":
            if os.geteuid() != 0:
                pytest.skip("mounting a tmpfs needs root")
            size = kept + pages(room)
            mount = subprocess.run(
                ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(self.folder)],
                capture_output=True,
                text=True,
                env=checkout_env(),
            )
            if mount.returncode != 0:
                pytest.skip(f"cannot mount a tmpfs here: {mount.stderr.strip()}")
            self.mounted = True
        if keep is not None:
            copy = shutil.copy2 if keep.is_file() else shutil.copytree
            copy(keep, self.folder / keep.name)
        self.limited = False

    def _limit(self) -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (self.room, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))

    def run(self, *args: str, timeout: float = 280, **env: str) -> subprocess.CompletedProcess:
        """``thrsim ARGS`` (this checkout's) with the disk full for it."""
        preexec = self._limit if self.kind == "file-size-limit" else None
        return subprocess.run(
            [*THRSIM, *args], capture_output=True, text=True, timeout=timeout, env=checkout_env(None, **env), preexec_fn=preexec
        )

    @contextlib.contextmanager
    def full(self):
        """In this process: the disk full for the block (a file-size limit is lifted after it)."""
        if self.kind == "tmpfs":
            yield
            return
        saved = resource.getrlimit(resource.RLIMIT_FSIZE), signal.getsignal(signal.SIGXFSZ)
        self._limit()
        try:
            yield
        finally:
            resource.setrlimit(resource.RLIMIT_FSIZE, saved[0])
            signal.signal(signal.SIGXFSZ, saved[1])

    def make_room(self) -> None:
        if self.kind == "tmpfs":
            subprocess.run(["mount", "-o", "remount,size=64m", str(self.folder)], check=True, env=checkout_env())

    def fill(self) -> None:
        """After :meth:`make_room`: ``room`` bytes left again."""
        if self.kind == "tmpfs":
            size = shutil.disk_usage(self.folder).used + pages(self.room)
            subprocess.run(["mount", "-o", f"remount,size={size}", str(self.folder)], check=True, env=checkout_env())

    def unmount(self) -> None:
        if self.mounted:
            subprocess.run(["umount", "-l", str(self.folder)], check=False, env=checkout_env())


@pytest.fixture(params=KINDS)
def full_disk(request, tmp_path):
    """``full_disk(room, keep=None)`` → a :class:`FullDisk` under this test's tmp_path."""
    made = []

    def make(room: int, keep: Path | None = None) -> FullDisk:
        disk = FullDisk(request.param, tmp_path, room, keep)
        made.append(disk)
        return disk

    yield make
    for disk in made:
        disk.unmount()


def assert_clean_failure(result: subprocess.CompletedProcess, target: Path) -> None:
    """Exit 2, no traceback, the last stderr line names ``target`` and says what went wrong."""
    assert result.returncode == 2, (result.returncode, result.stderr[-2000:])
    assert "Traceback" not in result.stderr and "Segmentation" not in result.stderr, result.stderr[-2000:]
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith(f"thrsim: error: cannot write {target}: "), last
    assert "No space left on device" in last or "File too large" in last, last


def leftovers(folder: Path) -> list[str]:
    """Temporary files (atomic writes, dataset parts) anywhere under ``folder``."""
    return sorted(
        str(p.relative_to(folder)) for p in folder.rglob("*") if p.name.startswith(".") and p.name != ".lock" or ".part" in p.name
    )


def same_tree(a: Path, b: Path) -> bool:
    if a.is_file():
        return filecmp.cmp(a, b, shallow=False)
    names = sorted(p.relative_to(a) for p in a.rglob("*"))
    return names == sorted(p.relative_to(b) for p in b.rglob("*")) and all(
        filecmp.cmp(a / n, b / n, shallow=False) for n in names if (a / n).is_file()
    )


# ---------------------------------------------------------------- command-line writers


@pytest.fixture(scope="module")
def previous_case(tmp_path_factory) -> Path:
    """A small real case (2 mm elements, one frame): the file a failed rewrite must leave as it was."""
    out = tmp_path_factory.mktemp("previous") / "case.h5"
    args = ["fem", "--inclination", "15", "--anteversion", "0", "--frames", "1", "--element-size", "2", "--threads", "1"]
    result = subprocess.run([*THRSIM, *args, "--out", str(out)], capture_output=True, text=True, timeout=280, env=checkout_env())
    assert result.returncode == 0, result.stderr
    return out


def test_fem_on_a_full_disk(full_disk, previous_case):
    disk = full_disk(room=previous_case.stat().st_size // 3, keep=previous_case)
    target = disk.folder / previous_case.name
    args = ["fem", "--inclination", "15", "--anteversion", "0", "--frames", "1", "--element-size", "2", "--threads", "1"]
    result = disk.run(*args, "--out", str(target), "--json")
    assert_clean_failure(result, target)
    assert same_tree(previous_case, target) and leftovers(disk.folder) == []


SWEEP = ["--solver", "synthetic", "--inclinations", "15", "--anteversions", "0,45", "--frames", "6", "--element-sizes", "1.0"]
SWEEP += ["--extra-forces", "none", "--workers", "1"]


def test_dataset_on_a_full_disk(full_disk):
    disk = full_disk(room=32_000)  # the manifest fits, a case file does not
    out = disk.folder / "data"
    result = disk.run("dataset", *SWEEP, "--out", str(out), "--json")
    first = sorted(json.loads((out / "manifest.json").read_text())["cases"])[0]
    assert_clean_failure(result, out / "cases" / f"{first}.h5")
    assert "worker" not in result.stderr  # the sweep stopped at the first case, no worker died
    manifest = json.loads((out / "manifest.json").read_text())
    assert {entry["status"] for entry in manifest["cases"].values()} == {"pending"}  # redone by the next run, not failed
    assert "No space left" in manifest["runs"][-1]["stop_reason"] or "too large" in manifest["runs"][-1]["stop_reason"]
    assert leftovers(out) == []


@pytest.fixture(scope="module")
def small_dataset(tmp_path_factory) -> tuple[Path, Path]:
    """A synthetic dataset of two cases and its learning pack."""
    folder = tmp_path_factory.mktemp("packed")
    for args in (
        ["dataset", *SWEEP, "--out", str(folder / "data")],
        ["dataset", "pack", str(folder / "data"), "--out", str(folder / "pack.h5")],
    ):
        result = subprocess.run([*THRSIM, *args], capture_output=True, text=True, timeout=120, env=checkout_env())
        assert result.returncode == 0, result.stderr
    return folder / "data", folder / "pack.h5"


def test_pack_on_a_full_disk(full_disk, small_dataset):
    data, previous = small_dataset
    disk = full_disk(room=previous.stat().st_size // 3, keep=previous)
    target = disk.folder / previous.name
    assert_clean_failure(disk.run("dataset", "pack", str(data), "--out", str(target)), target)
    assert same_tree(previous, target) and leftovers(disk.folder) == []


def navigation_session(folder: Path):
    """A short live navigation session with a landmark acquired (a session worth saving)."""
    from thrsim.app.live import LiveSession
    from thrsim.app.modes import MODES

    clock = iter(np.arange(100.0, 200.0, 1 / 60))
    session = LiveSession(MODES["navigation"], {"side": "right", "seed": 3}, lambda: next(clock), folder)
    session.control({"type": "probe", "action": "touch"})
    for _ in range(45):
        session.tick()
    assert session.trainer.registration.acquired
    return session


def test_report_on_a_full_disk(full_disk, tmp_path):
    session_file = navigation_session(tmp_path).save(tmp_path)
    previous = tmp_path / "report.html"
    previous.write_text("<p>an earlier report</p>" * 40)
    disk = full_disk(room=512, keep=previous)
    target = disk.folder / previous.name
    assert_clean_failure(disk.run("report", str(session_file), "--out", str(target)), target)
    assert same_tree(previous, target) and leftovers(disk.folder) == []


def test_ream_on_a_full_disk(full_disk, tiny_model, tmp_path):
    previous = tmp_path / "run"
    args = ["ream", "--inclination", "20", "--anteversion", "10", "--frames", "2", "--model", str(tiny_model)]
    done = subprocess.run([*THRSIM, *args, "--out", str(previous)], capture_output=True, text=True, timeout=280, env=checkout_env())
    assert done.returncode == 0, done.stderr
    disk = full_disk(room=2_000, keep=previous)
    target = disk.folder / previous.name
    assert_clean_failure(disk.run(*args, "--out", str(target)), target)
    assert same_tree(previous, target) and leftovers(disk.folder) == []


# ---------------------------------------------------------------- library writers, in this process


def test_model_on_a_full_disk(full_disk, tiny_model):
    from thrsim.learn.model_dir import load_model, save_model

    model = load_model(tiny_model)
    disk = full_disk(room=1_000, keep=tiny_model)
    target = disk.folder / tiny_model.name
    with disk.full(), pytest.raises(ThrsimOutputError) as raised:
        save_model(target, model.card, model.gn, model.mlp, model.advance, model.mesh)
    assert raised.value.errno in (errno.ENOSPC, errno.EFBIG)
    assert str(raised.value).startswith(f"cannot write {target / 'network.safetensors'}: ")
    assert same_tree(tiny_model, target) and leftovers(disk.folder) == []


def test_png_on_a_full_disk(full_disk, tmp_path):
    from thrsim.render import save_png

    rng = np.random.default_rng(0)
    previous = save_png(rng.integers(0, 255, (64, 64, 3), dtype=np.uint8), tmp_path / "bone.png")
    disk = full_disk(room=2_000, keep=previous)
    target = disk.folder / previous.name
    with disk.full(), pytest.raises(ThrsimOutputError, match=f"cannot write {target}: "):
        save_png(rng.integers(0, 255, (256, 256, 3), dtype=np.uint8), target)
    assert same_tree(previous, target) and leftovers(disk.folder) == []


def test_server_keeps_a_session_it_cannot_save_and_retries(full_disk, tmp_path, monkeypatch, caplog):
    from thrsim.app.server import ServeSettings, TrainerHub
    from thrsim.session import read_session

    disk = full_disk(room=2_000)
    disk.make_room()  # the server starts (its sessions' journals open), then the disk fills
    hub = TrainerHub(ServeSettings(sessions_dir=disk.folder, igtl=False, compile=False))
    seat = hub.open_seat("navigation", None)  # a trainee's page opened
    disk.fill()
    session = navigation_session(tmp_path)
    seat.session.discard()
    seat.session = session
    with disk.full():
        with pytest.raises((ThrsimOutputError, ThrsimInputError)):
            hub.end(seat)
        if seat.session is session:
            # no fresh session could start (its journal could not be created): this one goes on, nothing lost
            assert hub.unsaved == []
        else:  # ended, kept (journal and all) and retried
            assert hub.unsaved == [session]
            assert hub.retry_unsaved() == [] and hub.unsaved == [session]
    disk.make_room()
    if hub.unsaved:
        assert hub.retry_unsaved() == [disk.folder / f"{session.id}.h5"] and hub.unsaved == []
    else:
        assert hub.end(seat) == disk.folder / f"{session.id}.h5"
    assert read_session(disk.folder / f"{session.id}.h5").attrs["session_id"] == session.id

    # at shutdown, a disk still full: the session goes to the temporary folder (on another disk)
    # instead; under a file-size limit, which every folder shares, it is logged as lost
    monkeypatch.setattr("tempfile.gettempdir", lambda: str(tmp_path))
    seat.session.discard()
    seat.session = second = navigation_session(tmp_path)
    disk.fill()
    with disk.full():
        saved = hub.save_all(tries=2, pause_s=0.0)
    if disk.kind == "tmpfs":
        assert saved == [tmp_path / "thrsim-sessions" / f"{second.id}.h5"] and hub.unsaved == []
        assert read_session(saved[0]).attrs["session_id"] == second.id
    else:
        assert saved == [] and hub.unsaved == [second]
        assert f"session {second.id} lost" in caplog.text
    assert leftovers(disk.folder) == [] and leftovers(tmp_path / "thrsim-sessions") == []
