"""Where thrsim keeps compiled code (Numba kernels, TorchInductor), and what a cache of it depends on.

Caches live in the user's cache folder (``$XDG_CACHE_HOME``, default ``~/.cache``), never in the
package (a read-only install) nor in a shared-name folder in /tmp (another user could own it or
put code in it); where that cannot be written, a private temporary folder: slower, never a crash.

Numba keys a kernel's cache on its own file only, but a kernel inlines the kernels it calls from
other files (portable_math.py's among them) and compiles in constants of modules it imports:
after an edit there, stale machine code, which can crash. So every kernel module calls
:func:`use_numba_cache` before defining a kernel, and the cache folder is named after a hash of
:data:`KERNEL_MODULES` and every thrsim module they import, transitively (an explicit
NUMBA_CACHE_DIR still wins).
"""

from __future__ import annotations

import ast
import hashlib
import os
import stat
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent
#: every module that defines Numba kernels with ``cache=True`` (globs in the package)
KERNEL_MODULES = ("physics/*.py", "portable_math.py", "learn/features.py", "learn/graph.py")
_numba_cache_set = False


def cache_dir(name: str) -> Path:
    """The folder for the ``name`` cache, created: ``$XDG_CACHE_HOME/thrsim/<name>``, else a private temporary one."""
    home = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    folder = home / "thrsim" / name
    try:
        folder.mkdir(parents=True, exist_ok=True)
        if os.access(folder, os.W_OK | os.X_OK):
            return folder
    except OSError:
        pass
    return _private_temporary(name)


def _private_temporary(name: str) -> Path:
    """``<tmp>/thrsim-<uid>/<name>`` when that folder is this user's alone (mode 0700, not a link),
    else a fresh folder of this process's (mkdtemp: nobody else can have made it)."""
    base = Path(tempfile.gettempdir()) / f"thrsim-{os.getuid()}"
    try:
        base.mkdir(mode=0o700, exist_ok=True)
        info = os.lstat(base)
        if stat.S_ISDIR(info.st_mode) and info.st_uid == os.getuid() and not info.st_mode & 0o077:
            folder = base / name
            folder.mkdir(exist_ok=True)
            return folder
    except OSError:
        pass
    return Path(tempfile.mkdtemp(prefix=f"thrsim-{name}-"))


def kernel_sources() -> list[Path]:
    """The files the Numba cache is keyed on: :data:`KERNEL_MODULES` and all they import."""
    return imported_sources(path for pattern in KERNEL_MODULES for path in sorted(PACKAGE.glob(pattern)))


def use_numba_cache() -> None:
    """Point Numba's cache at ``cache_dir("numba")/<hash of kernel_sources()>`` and start Numba's
    threading layer; a kernel module calls it before its first kernel (Numba reads the folder when
    a kernel is defined).

    The threading layer: a cached serial kernel that calls parallel ones (``advance_reaming``,
    ``solid_step``) carries their code, but when it was compiled in a process that had loaded them
    from the cache, not Numba's note to start the threading layer on loading it (Numba issues
    8578, 10184). Loaded first in a fresh process, it crashed (SIGSEGV) in its first parallel
    loop. Started here, before any kernel can run, every load is safe."""
    global _numba_cache_set
    if _numba_cache_set:
        return
    import numba

    numba.get_num_threads()  # starts the threading layer
    if not os.environ.get("NUMBA_CACHE_DIR"):
        digest = hashlib.sha256(b"".join(path.read_bytes() for path in kernel_sources())).hexdigest()[:16]
        numba.config.CACHE_DIR = str(cache_dir("numba") / digest)
    _numba_cache_set = True


def imported_sources(modules: Iterable[Path]) -> list[Path]:
    """``modules`` and every thrsim module they import, transitively (the imports run at import
    time, read with ``ast``, and the packages' ``__init__.py`` on the way), sorted.

    A compiled kernel inlines what it calls and the constants it reads from other modules, so a
    cache of it is only valid while all of these files are unchanged.
    """
    found: set[Path] = set()
    todo = [Path(m).resolve() for m in modules]
    while todo:
        path = todo.pop()
        if path in found:
            continue
        found.add(path)
        for name in _thrsim_imports(path):
            todo += _module_files(name)
    return sorted(found)


def _thrsim_imports(path: Path) -> set[str]:
    """Dotted names of the thrsim modules (or of names in them) that ``path`` imports."""
    package = ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    if path.name != "__init__.py":
        package = package.rpartition(".")[0]
    names: set[str] = set()
    for node in _import_time_nodes(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parent = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join([*parent, *([base] if base else [])])
            names.add(base)
            names.update(f"{base}.{alias.name}" for alias in node.names)  # `from thrsim import portable_math`
    return {name for name in names if name == "thrsim" or name.startswith("thrsim.")}


def _import_time_nodes(tree: ast.AST) -> Iterator[ast.AST]:
    """The nodes run when the module is imported: all but function bodies (an import in a function
    runs in plain Python; a kernel sees only what its module imported)."""
    todo = [tree]
    while todo:
        node = todo.pop()
        yield node
        todo += [
            child for child in ast.iter_child_nodes(node) if not isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
        ]


def _module_files(name: str) -> list[Path]:
    """The files that importing ``name`` runs: each package's ``__init__.py`` on the way and the
    module itself (none for a name that is not a module, e.g. a class imported from one)."""
    files = []
    folder = PACKAGE.parent
    for part in name.split("."):
        folder = folder / part
        if (folder / "__init__.py").is_file():
            files.append(folder / "__init__.py")
        elif folder.with_suffix(".py").is_file():
            files.append(folder.with_suffix(".py"))
            break
        else:
            break
    return files
