"""`bfields fetch` writes each downloaded result file with the mode the umask gives any new file
(issue 45: the temp file came from `mkstemp`, so fetched results were 0600 whatever the umask).
A real HTTP server (the standard library's) serves the file the client streams."""

from __future__ import annotations

import functools
import os
import stat
import threading
from collections.abc import Iterator
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import httpx
import pytest

from bayesian_fields_service.client.api import _download


class _QuietHandler(SimpleHTTPRequestHandler):
    def log_message(self, format: str, *args: object) -> None:  # noqa: A002 - the base class's name
        pass


@pytest.fixture
def served(tmp_path: Path) -> Iterator[str]:
    """A folder holding summary.json, served over HTTP on a free loopback port."""
    root = tmp_path / "served"
    root.mkdir()
    (root / "summary.json").write_text('{"tasks": []}')
    server = ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(_QuietHandler, directory=str(root)))
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}"
    finally:
        server.shutdown()
        server.server_close()


@pytest.mark.parametrize(("mask", "mode"), [(0o022, 0o644), (0o027, 0o640)])
def test_a_fetched_file_gets_the_umask_mode(mask: int, mode: int, served: str, tmp_path: Path) -> None:
    dest = tmp_path / "fetched" / "summary.json"
    dest.parent.mkdir()
    before = os.umask(mask)
    try:
        with (
            httpx.Client(timeout=5.0) as client,
            _download(client, f"{served}/summary.json", dest, None) as size,
        ):
            assert size == len('{"tasks": []}')
    finally:
        os.umask(before)
    assert dest.read_text() == '{"tasks": []}'
    assert oct(stat.S_IMODE(dest.stat().st_mode)) == oct(mode)
    assert [p.name for p in dest.parent.iterdir()] == ["summary.json"]  # no temp file left
