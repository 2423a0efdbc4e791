"""What the documentation tells a user to run must not open a port to everyone who can reach it."""

from __future__ import annotations

import re

from checkout_cli import REPO_ROOT

DOCUMENTS = [REPO_ROOT / "README.md", *sorted((REPO_ROOT / "docs").rglob("*.md")), *sorted((REPO_ROOT / "thrsim").rglob("*.py"))]


def test_no_document_starts_a_dask_scheduler_on_every_interface():
    exposed = re.compile(r"dask[- ]scheduler[^\n`]*--host\s+0\.0\.0\.0")
    offenders = [str(p.relative_to(REPO_ROOT)) for p in DOCUMENTS if exposed.search(p.read_text())]
    assert not offenders, offenders


def test_the_dask_docs_say_how_to_keep_the_scheduler_private():
    from thrsim.cli import dataset_cmd
    from thrsim.data import executor

    for doc in (dataset_cmd.__doc__, executor.__doc__):
        for needle in ("127.0.0.1", "private interface", "SSH tunnel", "--protocol tls", "--tls-cert", "tls://"):
            assert needle in doc, needle
