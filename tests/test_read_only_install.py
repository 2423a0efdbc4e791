"""thrsim from a read-only install, with a home it cannot write, as root and as an unprivileged user.

Numba used to cache its kernels beside the package (or in the home's cache folder) and fail at
import with "cannot cache function ...: no locator available" where neither is writable; now its
cache, and Inductor's, fall back to a private temporary folder.
"""

from __future__ import annotations

import json
import os
import shutil
import site
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import NamedTuple

import pytest
from checkout_cli import REPO_ROOT, checkout_env

pytestmark = pytest.mark.timeout(300)

NOBODY = 65534
IMPORTS = "import numpy, numba, h5py, typer"


class Python(NamedTuple):
    """An interpreter to run thrsim with, and the package folders to put on its path."""

    executable: str
    sites: tuple[str, ...] = ()


THIS_PYTHON = Python(sys.executable)
# the kernels' cache folder, and one kernel compiled and cached there
PROBE = (
    "import json, numba, thrsim, thrsim.physics.reaming_case, thrsim.portable_math as pm\n"
    "pm.exp(1.0)\n"
    "print(json.dumps({'thrsim': thrsim.__file__, 'numba_cache': numba.config.CACHE_DIR}))\n"
)


def _install(base: Path) -> tuple[Path, Path, Path]:
    """A copy of the package (install), an empty home and a temporary folder, all readable by everyone."""
    install, home, tmp = base / "install", base / "home", base / "tmp"
    shutil.copytree(REPO_ROOT / "thrsim", install / "thrsim", ignore=shutil.ignore_patterns("__pycache__", "node_modules"))
    home.mkdir()
    tmp.mkdir()
    for folder in (base, install, home):
        folder.chmod(0o755)
    tmp.chmod(0o1777)
    return install, home, tmp


def _read_only(folder: Path) -> None:
    """Read-only for everyone, root included: a read-only bind mount (root), or no write bits."""
    if os.geteuid() == 0:
        for args in (["--bind", folder, folder], ["-o", "remount,bind,ro", folder]):
            mounted = subprocess.run(["mount", *map(str, args)], capture_output=True, text=True, env=checkout_env())
            if mounted.returncode != 0:
                pytest.skip(f"cannot make a read-only bind mount here: {mounted.stderr.strip()}")
    else:
        for path in [folder, *folder.rglob("*")]:
            path.chmod(path.stat().st_mode & ~0o222)


def _unmount(*folders: Path) -> None:
    if os.geteuid() == 0:
        for folder in folders:
            subprocess.run(["umount", "-l", str(folder)], capture_output=True, env=checkout_env())


def _run(args: list[str], install: Path, home: Path, tmp: Path, user: list[str], python: Python) -> subprocess.CompletedProcess:
    path = os.pathsep.join([str(install), *python.sites])
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "PYTHONPATH": path, "HOME": str(home), "TMPDIR": str(tmp)}
    return subprocess.run([*user, python.executable, *args], cwd=home, env=env, capture_output=True, text=True, timeout=280)


def _check(install: Path, home: Path, tmp: Path, user: list[str], python: Python = THIS_PYTHON) -> None:
    mesh = _run(["-m", "thrsim", "mesh", "--element-size", "2", "--json"], install, home, tmp, user, python)
    assert mesh.returncode == 0, mesh.stderr[-3000:]
    assert json.loads(mesh.stdout)["elements"] > 0
    probe = _run(["-c", PROBE], install, home, tmp, user, python)
    assert probe.returncode == 0, probe.stderr[-3000:]
    found = json.loads(probe.stdout)
    assert Path(found["thrsim"]).is_relative_to(install)  # the read-only copy ran
    assert Path(found["numba_cache"]).is_relative_to(tmp) and any(Path(found["numba_cache"]).rglob("*.nbi"))


def test_read_only_install_and_home(tmp_path):
    install, home, tmp = _install(tmp_path)
    _read_only(install)
    _read_only(home)
    try:
        _check(install, home, tmp, user=[])
    finally:
        _unmount(install, home)


def test_unprivileged_user():
    if os.geteuid() != 0:
        pytest.skip("runs as an unprivileged user through setpriv, which needs root (test_read_only_install_and_home covers this user)")
    if shutil.which("setpriv") is None:
        pytest.skip("setpriv (util-linux) is not installed")
    user = ["setpriv", f"--reuid={NOBODY}", f"--regid={NOBODY}", "--clear-groups"]
    base = Path(tempfile.mkdtemp(prefix="thrsim-ro-"))  # pytest's own tmp_path is root's alone (0700)
    mounted: list[Path] = []
    try:
        install, home, tmp = _install(base)
        for path in [install, *install.rglob("*")]:  # root-owned and not writable by others: read-only to nobody
            path.chmod(0o755 if path.is_dir() else 0o644)
        python = THIS_PYTHON
        usable = subprocess.run([*user, sys.executable, "-c", IMPORTS], capture_output=True, text=True, cwd="/", env=checkout_env())
        if usable.returncode != 0:  # the interpreter lives where nobody may look (root's home): show it read-only elsewhere
            python = _interpreter_view(base / "python", mounted)
            usable = subprocess.run(
                [*user, python.executable, "-c", IMPORTS],
                capture_output=True,
                text=True,
                cwd="/",
                env={"PYTHONPATH": os.pathsep.join(python.sites)},
            )
        assert usable.returncode == 0, usable.stderr[-2000:]
        _check(install, home, tmp, user, python)
    finally:
        _unmount(*mounted)
        shutil.rmtree(base, ignore_errors=True)


def _interpreter_view(view: Path, mounted: list[Path]) -> Python:
    """This interpreter's installation bind-mounted read-only at ``view``, which everyone may reach."""
    view.mkdir()
    view.chmod(0o755)
    prefix = Path(sys.prefix)
    for args in (["--bind", prefix, view], ["-o", "remount,bind,ro", view]):
        done = subprocess.run(["mount", *map(str, args)], capture_output=True, text=True, env=checkout_env())
        if done.returncode != 0:
            pytest.skip(f"this interpreter is not readable by an unprivileged user, and cannot be bind-mounted: {done.stderr.strip()}")
        if view not in mounted:
            mounted.append(view)
    sites = [str(view / Path(p).relative_to(prefix)) for p in site.getsitepackages() if Path(p).is_relative_to(prefix)]
    return Python(str(view / Path(sys.executable).relative_to(prefix)), tuple(sites))


def test_cache_dir_falls_back_to_a_private_temporary_folder(tmp_path, monkeypatch):
    from thrsim.cache import cache_dir

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    assert cache_dir("numba") == tmp_path / "cache" / "thrsim" / "numba" and (tmp_path / "cache" / "thrsim" / "numba").is_dir()

    (tmp_path / "file").write_text("")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "file"))  # cannot be a folder
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    private = tmp_path / "tmp" / f"thrsim-{os.getuid()}"
    assert cache_dir("numba") == private / "numba" and private.stat().st_mode & 0o777 == 0o700

    private.chmod(0o777)  # opened to others (or made by another user first): not trusted
    fresh = cache_dir("numba")
    assert fresh.parent == tmp_path / "tmp" and fresh.name.startswith("thrsim-numba-") and fresh.stat().st_mode & 0o777 == 0o700


def test_inductor_cache_is_in_the_users_cache_folder(tmp_path, monkeypatch):
    """Not Inductor's default /tmp/torchinductor_<user>, a name another user can take first."""
    from types import SimpleNamespace

    import torch

    from thrsim.learn.compiled import compile_network

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.setenv("TORCHINDUCTOR_CACHE_DIR", "")  # unset for compile_network, and whatever it sets undone after
    seen = {}

    def fake_compile(network, dynamic):  # records where Inductor would cache what it compiles
        seen["cache"] = os.environ.get("TORCHINDUCTOR_CACHE_DIR")
        return network

    monkeypatch.setattr(torch, "compile", fake_compile)
    one_graph = (torch.zeros((3, 2)), torch.zeros((2, 2)), torch.zeros((1, 2)), torch.tensor([0, 1]), torch.tensor([1, 0]))
    batch = (*one_graph, torch.zeros(3, dtype=torch.int64), torch.zeros(2, dtype=torch.int64))
    model = SimpleNamespace(network=lambda *inputs: torch.zeros((len(inputs[0]), 1)), normalised_inputs=lambda example: batch)
    assert compile_network(model, example=None) is None
    assert seen["cache"] == str(tmp_path / "thrsim" / "inductor")
