"""Fixtures of the trainer's browser tests."""

from __future__ import annotations

import pytest

from thrsim.app.drawing_bench import CHROMIUM, CHROMIUM_FLAGS


@pytest.fixture(scope="module")
def browser():
    """Debian's headless Chromium through Playwright, one per test module."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=[*CHROMIUM_FLAGS, "--no-first-run"])
        yield browser
        browser.close()
