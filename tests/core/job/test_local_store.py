"""LocalStore (the embedded default) honours the same contract the S3 store is tested for."""

from __future__ import annotations

from pathlib import Path

import pytest

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.store import ArtifactNotFound, LocalStore
from bayesian_fields_service.config.settings import ServiceSettings
from bayesian_fields_service.storage.stores import build_store, tenant_store


def test_roundtrip_ranges_and_list(tmp_path: Path) -> None:
    store = LocalStore(tmp_path / "root")
    store.put_bytes("s/a.bin", bytes(range(100)))
    store.put_bytes("s/sub/b.bin", b"b")
    store.put_bytes("t/c.bin", b"c")
    assert store.get_range("s/a.bin", 10, 20) == bytes(range(10, 20))
    assert store.get_range("s/a.bin", 90, 200) == bytes(range(90, 100))
    assert store.get_range("s/a.bin", 150, 200) == b""
    assert store.list("s/") == ["s/a.bin", "s/sub/b.bin"]
    assert store.list("") == ["s/a.bin", "s/sub/b.bin", "t/c.bin"]
    assert store.size("s/a.bin") == 100
    with pytest.raises(ArtifactNotFound):
        store.get_bytes("s/missing")
    assert store.delete_prefix("s/") == 2
    assert store.list("") == ["t/c.bin"]


def test_atomic_write_leaves_no_partial_file(tmp_path: Path) -> None:
    store = LocalStore(tmp_path)
    store.put_bytes("k", b"old")

    src = tmp_path / "a-directory"  # copying it fails after the temp file was created
    src.mkdir()
    with pytest.raises(IsADirectoryError):
        store.put_file("k", src)
    assert store.get_bytes("k") == b"old"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".tmp-")]


def test_temp_files_are_not_listed(tmp_path: Path) -> None:
    store = LocalStore(tmp_path)
    store.put_bytes("a/x", b"1")
    (tmp_path / "a" / ".tmp-half").write_bytes(b"partial")
    assert store.list("a/") == ["a/x"]


def test_tenant_isolation_on_local_store(tmp_path: Path) -> None:
    store = LocalStore(tmp_path)
    a, b = tenant_store(store, "alpha"), tenant_store(store, "beta")
    a.put_bytes("jobs/1/result.json", b"{}")
    assert (tmp_path / "tenants" / "alpha" / "jobs" / "1" / "result.json").is_file()
    assert b.list("") == [] and a.list("") == ["jobs/1/result.json"]
    with pytest.raises(InputError):
        b.get_bytes("../alpha/jobs/1/result.json")


def test_build_store_local(tmp_path: Path) -> None:
    store = build_store(ServiceSettings(storage_backend="local", local_storage_root=tmp_path / "data"))
    assert isinstance(store, LocalStore) and store.root == (tmp_path / "data").resolve()
