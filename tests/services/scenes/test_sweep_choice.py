"""What the bucket sweep takes for an orphan (`scenes.bucket_sweep`), without a bucket: a scene a
row names is kept, a young prefix may still be copying, an earlier release's scene is kept for the
import, and a multipart upload goes only when old and unlisted. The sweep against a real S3
server is tests/services/api/test_orphan_sweep.py."""

from __future__ import annotations

import pytest

from bayesian_fields_service.scenes.bucket_sweep import Verdict, orphaned_upload, root_verdict
from bayesian_fields_service.scenes.layout import bucket_scene_root, scene_of

ROOT = bucket_scene_root("acme", "s_1")
HOUR = 3600.0


@pytest.mark.parametrize(
    ("has_row", "objects", "verdict"),
    [
        (True, [(ROOT + "input/a.png", 10 * HOUR)], Verdict.keep),
        (False, [], Verdict.young),
        (False, [(ROOT + "input/a.png", 10 * HOUR), (ROOT + "input/b.png", 60.0)], Verdict.young),
        (False, [(ROOT + "scene.json", 10 * HOUR), (ROOT + "input/a.png", 10 * HOUR)], Verdict.legacy),
        (False, [(ROOT + "input/scene.json", 10 * HOUR)], Verdict.orphan),  # not the record object
        (False, [(ROOT + "input/a.png", 10 * HOUR)], Verdict.orphan),
    ],
)
def test_a_scene_prefix_is_an_orphan_only_without_a_row_when_old_and_not_legacy(
    has_row: bool, objects: list[tuple[str, float]], verdict: Verdict
) -> None:
    assert root_verdict(ROOT, has_row, objects, max_age_s=HOUR) == verdict


@pytest.mark.parametrize(
    ("upload_id", "listed", "age_s", "orphan"),
    [
        ("u1", frozenset(), 2 * HOUR, True),  # no row lists it: a killed presigned start
        ("u1", frozenset({"u1"}), 2 * HOUR, False),  # its scene is still uploading
        ("u1", frozenset({"u2"}), 2 * HOUR, True),
        ("u1", frozenset(), 60.0, False),  # young: the row may be on its way
    ],
)
def test_a_multipart_upload_is_aborted_only_when_old_and_unlisted(
    upload_id: str, listed: frozenset[str], age_s: float, orphan: bool
) -> None:
    assert orphaned_upload(upload_id, listed, age_s, max_age_s=HOUR) is orphan


def test_only_keys_under_a_tenants_scene_name_a_scene() -> None:
    assert scene_of(ROOT + "staging/images/a.zip") == ("acme", "s_1")
    assert scene_of("tenants/acme/jobs/j_1/result/x") is None
    assert scene_of("tenants/acme/scenes//x") is None
    assert scene_of("elsewhere/acme/scenes/s_1/x") is None
