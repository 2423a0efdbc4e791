"""The Numba cache: keyed on every thrsim module a kernel can compile in, kept out of the package,
and safe to load whatever process wrote it.

Numba keys a kernel's cache on its own file; thrsim keys the whole cache folder on a hash of the
kernel modules and everything they import (thrsim.cache). A module they import that the key
misses (as thrsim/portable_math.py once was) leaves stale machine code after an edit: a crash.
"""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
from pathlib import Path

from checkout_cli import checkout_env

from thrsim.cache import KERNEL_MODULES, PACKAGE, imported_sources, kernel_sources


def _defines_cached_kernels(path: Path) -> bool:
    return any(
        isinstance(node, ast.keyword) and node.arg == "cache" and isinstance(node.value, ast.Constant) and node.value.value is True
        for node in ast.walk(ast.parse(path.read_text()))
    )


def test_every_module_with_cached_kernels_is_a_kernel_module():
    listed = {path for pattern in KERNEL_MODULES for path in PACKAGE.glob(pattern)}
    with_kernels = {path for path in PACKAGE.rglob("*.py") if _defines_cached_kernels(path)}
    assert with_kernels and with_kernels <= listed, sorted(str(p.relative_to(PACKAGE)) for p in with_kernels - listed)


def test_the_key_covers_every_thrsim_module_the_kernel_modules_load():
    """Import every kernel module in a fresh interpreter (thrsim.config first, as the commands do):
    each thrsim file it loads is in the key, and every cached kernel's cache is in the keyed folder."""
    modules = [
        ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts) for pattern in KERNEL_MODULES for path in PACKAGE.glob(pattern)
    ]
    script = (
        "import importlib, json, sys, numba\n"
        "import thrsim.config\n"
        f"loaded = [importlib.import_module(name) for name in {modules!r}]\n"
        "caches = [f._cache._cache_path for m in loaded for f in vars(m).values() if getattr(getattr(f, '_cache', None), '_cache_path', None)]\n"
        "files = sorted(m.__file__ for n, m in sys.modules.items() if n.split('.')[0] == 'thrsim' and getattr(m, '__file__', None))\n"
        "print(json.dumps({'files': files, 'caches': caches, 'folder': numba.config.CACHE_DIR}))\n"
    )
    env = checkout_env()
    env.pop("NUMBA_CACHE_DIR", None)
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=120)
    assert run.returncode == 0, run.stderr
    found = json.loads(run.stdout)
    files = {Path(f).resolve() for f in found["files"]}
    key = set(kernel_sources())
    assert PACKAGE / "portable_math.py" in files  # the kernels inline it
    assert files <= key, f"not in the Numba cache key: {sorted(str(f.relative_to(PACKAGE)) for f in files - key)}"
    assert len(found["caches"]) > 20
    assert all(cache.startswith(found["folder"]) and not cache.startswith(str(PACKAGE)) for cache in found["caches"]), found


def test_imported_sources_follows_every_form_of_import(tmp_path, monkeypatch):
    """Absolute, `from thrsim import module`, relative and package imports are followed; imports
    inside functions (plain Python, never compiled into a kernel) are not."""
    package = tmp_path / "thrsim"
    (package / "physics").mkdir(parents=True)
    for name in ("__init__.py", "physics/__init__.py", "config.py", "portable_math.py", "errors.py", "report.py", "physics/solid.py"):
        (package / name).write_text("")
    (package / "physics" / "kernel.py").write_text(
        "from thrsim import portable_math as pm\nfrom .solid import step\nimport thrsim.config\ndef later():\n    from thrsim import report\n"
    )
    (package / "config.py").write_text("from thrsim.errors import ThrsimInputError\n")
    monkeypatch.setattr("thrsim.cache.PACKAGE", package)
    found = {str(p.relative_to(package)) for p in imported_sources([package / "physics" / "kernel.py"])}
    assert found == {
        "__init__.py",
        "physics/__init__.py",
        "physics/kernel.py",
        "physics/solid.py",
        "portable_math.py",
        "config.py",
        "errors.py",
    }


# A serial kernel calling a parallel one, defined as thrsim's kernel modules define theirs.
_NESTED_KERNELS = """
import numpy as np
from numba import njit, prange
from thrsim.cache import use_numba_cache
use_numba_cache()

@njit(parallel=True, cache=True)
def inner(a):
    out = np.zeros(a.size)
    for i in prange(a.size):
        out[i] = 2.0 * a[i]
    return out

@njit(cache=True)
def outer(a):
    return inner(a).sum()
"""


def test_a_cached_kernel_that_calls_parallel_ones_loads_in_a_fresh_process(tmp_path):
    """The parallel kernel cached by one process; loaded by the next, which then compiles and caches
    the serial one (Numba leaves out its note to start the threading layer: issues 8578, 10184); a
    third process loads the serial one first. Without thrsim.cache starting the threading layer
    that third process died (SIGSEGV), as `thrsim fem` did after a test run had written the cache."""
    (tmp_path / "nested.py").write_text(_NESTED_KERNELS)
    env = checkout_env(NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    env["PYTHONPATH"] = os.pathsep.join([str(tmp_path), env["PYTHONPATH"]])
    for calls in ("print(nested.inner(a).sum())", "nested.inner(a)\nprint(nested.outer(a))", "print(nested.outer(a))"):
        script = f"import numpy as np, nested\na = np.arange(1000.0)\n{calls}"
        run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300)
        assert run.returncode == 0 and run.stdout.split()[-1] == "999000.0", (calls, run.returncode, run.stderr[-500:])
    assert len(list((tmp_path / "cache").rglob("nested.outer-*.nbc"))) == 1  # the last process loaded it, compiled nothing
