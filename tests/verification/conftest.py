"""Slow verification checks run only when asked for: ``pytest -m slow tests/verification``
(or THRSIM_RUN_SLOW=1); the default run (CI) skips them."""

from __future__ import annotations

import os

import pytest


def pytest_collection_modifyitems(config, items):
    wanted = "slow" in (config.getoption("-m") or "") and "not slow" not in (config.getoption("-m") or "")
    if wanted or os.environ.get("THRSIM_RUN_SLOW") == "1":
        return
    skip = pytest.mark.skip(reason="slow verification check: run with -m slow or THRSIM_RUN_SLOW=1")
    for item in items:
        if "slow" in item.keywords and str(item.fspath).startswith(os.path.dirname(__file__)):
            item.add_marker(skip)
