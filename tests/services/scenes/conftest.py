"""The scenes domain over its in-memory records fake and a real folder store (no server)."""

from __future__ import annotations

import itertools
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path

import pytest

from bayesian_fields_core.job.store import LocalStore
from bayesian_fields_service.config.settings import ServiceSettings
from bayesian_fields_service.scenes.lifecycle import Scenes
from bayesian_fields_service.scenes.store import SceneStore
from tests.services.scenes.fakes import FolderMultipart, InMemorySceneRecords

SAMPLE = Path(__file__).resolve().parents[3] / "samples" / "tabletop"
T0 = datetime(2026, 1, 2, 3, 4, 5, tzinfo=UTC)


def ids() -> Callable[[], str]:
    """Time-ordered scene ids, as `common.jobs.new_id` makes them (``s_`` + 22 hex digits)."""
    counter = itertools.count(1)
    return lambda: f"s_{next(counter):022x}"


@pytest.fixture
def records() -> InMemorySceneRecords:
    return InMemorySceneRecords()


@pytest.fixture
def bucket(tmp_path: Path) -> LocalStore:
    return LocalStore(tmp_path / "bucket")


@pytest.fixture
def multipart(bucket: LocalStore) -> FolderMultipart:
    return FolderMultipart(bucket)


@pytest.fixture
def settings() -> ServiceSettings:
    return ServiceSettings(max_upload_bytes=50 * 1024 * 1024)


@pytest.fixture
def scenes(settings: ServiceSettings, bucket: LocalStore, records: InMemorySceneRecords) -> Scenes:
    """The domain on a folder bucket without direct transfers (as a local deployment runs)."""
    return Scenes(settings, bucket, SceneStore(records), ids(), clock=lambda: T0)


@pytest.fixture
def presigned(
    settings: ServiceSettings, bucket: LocalStore, records: InMemorySceneRecords, multipart: FolderMultipart
) -> Scenes:
    """The domain with the bucket's multipart uploads (as an S3 deployment runs)."""
    return Scenes(settings, bucket, SceneStore(records), ids(), transfers=multipart, clock=lambda: T0)
