"""Fixtures for the OpenIGTLink tests (helpers live in igtl_helpers.py)."""

from __future__ import annotations

import pytest
from igtl_helpers import RunningServer

from thrsim.config import IgtlConfig
from thrsim.io.server import IgtlServer


@pytest.fixture
def make_server():
    running: list[RunningServer] = []

    def make(config: IgtlConfig | None = None, **kwargs) -> RunningServer:
        config = config or IgtlConfig(port=0)
        server = RunningServer(IgtlServer(config, **kwargs))
        running.append(server)
        return server

    yield make
    for server in running:
        server.stop()


@pytest.fixture
def nav_server(make_server):
    return make_server()
