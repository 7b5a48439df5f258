"""Fast checks of the pieces under the service with no server: record merging rules, progress
arithmetic, archive member checks that are awkward to craft over HTTP (tar links, devices)."""

from __future__ import annotations

import io
import tarfile
from pathlib import Path

import pytest

from bayesian_fields_core.errors import InputError
from bayesian_fields_service.jobs.model import JobRecord, JobState, merge, overall_progress
from bayesian_fields_service.scenes.archives import ArchiveLimits, extract_archive

LIMITS = ArchiveLimits(max_members=10, max_bytes=1000)


def _record(**kw: object) -> JobRecord:
    return JobRecord(id="j_" + "0" * 22, tenant="t", scene_id="s_" + "0" * 22, tasks=["a"], **kw)  # type: ignore[arg-type]


def test_terminal_state_and_cancel_request_survive_a_late_writer() -> None:
    stored = _record(
        state=JobState.cancelled, cancel_requested=True, stages_done=["perceive"], error="cancelled"
    )
    late = _record(state=JobState.running, stages_done=["fuse"], timings={"fuse": 2.0})
    merged = merge(stored, late)
    assert merged.state == JobState.cancelled and merged.cancel_requested and merged.error == "cancelled"
    assert merged.stages_done == ["perceive", "fuse"] and merged.timings == {"fuse": 2.0}
    assert merge(_record(state=JobState.queued), _record(state=JobState.running)).state == JobState.running


def test_overall_progress_weights_stages() -> None:
    assert overall_progress([], None, 0.0) == 0.0
    assert overall_progress([], "perceive", 0.5) == 30.0
    assert overall_progress(["perceive"], "fuse", 1.0) == 85.0
    assert overall_progress(["perceive", "fuse", "cluster"], None, 0.0) == 100.0


def _tar(tmp_path: Path, add) -> Path:  # noqa: ANN001
    path = tmp_path / "a.tar"
    with tarfile.open(path, "w") as tf:
        add(tf)
    return path


def _file(tf: tarfile.TarFile, name: str, data: bytes = b"abc") -> None:
    info = tarfile.TarInfo(name)
    info.size = len(data)
    tf.addfile(info, io.BytesIO(data))


@pytest.mark.parametrize(
    ("kind", "message"),
    [
        (tarfile.SYMTYPE, "symbolic link"),
        (tarfile.LNKTYPE, "hard link"),
        (tarfile.CHRTYPE, "not a regular file"),
    ],
)
def test_tar_links_and_devices_are_refused(tmp_path: Path, kind: bytes, message: str) -> None:
    def add(tf: tarfile.TarFile) -> None:
        _file(tf, "ok.png")
        info = tarfile.TarInfo("bad.png")
        info.type = kind
        info.linkname = "ok.png"
        tf.addfile(info)

    with pytest.raises(InputError, match=message):
        extract_archive(_tar(tmp_path, add), tmp_path / "out", LIMITS, source="a.tar")
    assert not (tmp_path / "out").exists()  # checks run before anything is written


def test_tar_extracts_and_strips_a_common_folder(tmp_path: Path) -> None:
    path = _tar(tmp_path, lambda tf: (_file(tf, "images/a.png"), _file(tf, "images/sub/b.png")))
    written = extract_archive(path, tmp_path / "out", LIMITS, source="a.tar")
    assert sorted(map(str, written)) == ["a.png", "sub/b.png"]
    assert (tmp_path / "out" / "sub" / "b.png").read_bytes() == b"abc"


def test_garbage_is_not_an_archive(tmp_path: Path) -> None:
    path = tmp_path / "x.zip"
    path.write_bytes(b"not an archive at all")
    with pytest.raises(InputError, match="x.zip"):
        extract_archive(path, tmp_path / "out", LIMITS, source="x.zip")


@pytest.mark.parametrize(
    ("message", "expected"),
    [
        (
            "/tmp/up-1/scene/splat.gltf: glTF buffers[0].uri path '/etc/passwd' is absolute",
            "splat.gltf: glTF buffers[0].uri path '/etc/passwd' is absolute",
        ),
        ('images path "/etc/it\'s" is absolute', 'images path "/etc/it\'s" is absolute'),
        ("No such file or directory: '/srv/store/tenants/acme/x.png'", "No such file or directory: 'x.png'"),
        ("path '/a/b' then /var/lib/worker/tmp/frame.png", "path '/a/b' then frame.png"),
    ],
)
def test_redaction_keeps_the_paths_a_user_sent_and_drops_the_servers(message: str, expected: str) -> None:
    from bayesian_fields_service.sanitize.text import redact_locations

    assert redact_locations(message) == expected
