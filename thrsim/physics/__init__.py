"""Material law, tet kinematics, contact, the explicit solver and the reaming case.

Numba caches compiled kernels on disk, but it keys a kernel's cache on its own file only:
a kernel that calls a kernel from another file (the reaming loop calls contact, solid and
material kernels) would keep stale machine code after that other file changes, which can
crash. So the cache lives in a folder named after a hash of every source file here and of
thrsim/config.py (kernels compile its constants in, e.g. the friction cap), set before any
kernel is defined; an explicit NUMBA_CACHE_DIR still wins.
"""

import hashlib
import os
from pathlib import Path

import numba

_SOURCES = [*sorted(Path(__file__).parent.glob("*.py")), Path(__file__).parent.parent / "config.py"]
_DIGEST = hashlib.sha256(b"".join(path.read_bytes() for path in _SOURCES)).hexdigest()[:16]

if not os.environ.get("NUMBA_CACHE_DIR"):
    _cache_home = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    numba.config.CACHE_DIR = str(_cache_home / "thrsim" / "numba" / _DIGEST)
