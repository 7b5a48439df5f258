"""The client verbs' errors: an unreachable artifact link is one line naming the file and the host
(it was httpx's ConnectError traceback), through `bfields fetch`'s error path; `submit` reads and
checks tasks and parameters as `bfields run` does, before it contacts the server."""

from __future__ import annotations

import socket
from pathlib import Path

import httpx
import pytest

from bayesian_fields_service.client.api import ClientError, _download
from bayesian_fields_service.client.commands import run_verb, submit


def _closed_port() -> int:
    """A local port nothing listens on (bound, then released)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _fetch_one(url: str, dest: Path) -> int:
    with httpx.Client(timeout=5.0) as client, _download(client, url, dest, None) as size:
        return size


def test_an_unreachable_link_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    url = f"http://127.0.0.1:{_closed_port()}/bucket/jobs/j_1/result/summary.json?X-Amz-Signature=abc"
    dest = tmp_path / "summary.json"
    with pytest.raises(ClientError, match=r"download of summary.json from 127.0.0.1 failed: ConnectError"):
        _fetch_one(url, dest)
    assert not dest.exists() and not list(tmp_path.iterdir())  # no partial file left behind

    assert run_verb(_fetch_one, url=url, dest=dest) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "summary.json" in err and "\n" not in err and "Traceback" not in err


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ({"param": ["top_k=0"]}, "top_k"),
        ({"param": ["no_such_param=1"]}, "no_such_param"),
        ({"task": ["  "]}, "--task"),
        ({"tasks_file": "missing-tasks.yaml"}, "missing-tasks.yaml"),
    ],
)
def test_submit_refuses_bad_tasks_and_parameters_before_the_server(
    extra: dict[str, object], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A closed port as the server: a refusal that names the input (not a ConnectError) shows
    nothing was sent."""
    (tmp_path / "tasks.yaml").write_text("- the mug\n")
    kwargs = extra if "tasks_file" in extra else {"task": ["the mug"], **extra}
    server = f"http://127.0.0.1:{_closed_port()}"
    assert run_verb(submit, scene_dir=tmp_path, server=server, **kwargs) == 2
    err = capsys.readouterr().err
    assert message in err and "ConnectError" not in err, err
