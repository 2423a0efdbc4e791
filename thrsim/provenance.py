"""Versions and configuration hashes recorded in every output file."""

from __future__ import annotations

import hashlib
import json
import platform
from importlib import metadata
from typing import Any

from thrsim import __version__

_PACKAGES = ("numpy", "scipy", "numba", "gmsh", "meshio", "h5py", "torch")


def package_versions() -> dict[str, str]:
    """thrsim, Python and the numerical libraries whose versions can change results."""
    versions = {"thrsim": __version__, "python": platform.python_version()}
    for name in _PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "absent"
    return versions


def config_hash(config: dict) -> str:
    """Stable short hash of a JSON-serialisable configuration (key order does not matter)."""
    text = json.dumps(config, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def json_default(value: Any) -> Any:
    """``json.dumps`` fallback for NumPy arrays and scalars."""
    if hasattr(value, "tolist"):
        return value.tolist()
    if hasattr(value, "item"):
        return value.item()
    raise TypeError(f"not JSON-serialisable: {type(value).__name__}")
