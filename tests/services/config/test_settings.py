"""ServiceSettings from BFIELDS_* variables, and API key lookup (inline, hashed, secret file)."""

from __future__ import annotations

import ast
import json
import os
import time
from pathlib import Path

import pytest
from pydantic import ValidationError

from bayesian_fields_core.errors import InputError
from bayesian_fields_service.config.settings import ServiceSettings, get_settings
from bayesian_fields_service.security.api_keys import ApiKeyRing, hash_api_key


@pytest.fixture
def clean_env(monkeypatch: pytest.MonkeyPatch) -> pytest.MonkeyPatch:
    for name in list(os.environ):
        if name.startswith("BFIELDS_"):
            monkeypatch.delenv(name)
    return monkeypatch


def test_env_variables_are_read(clean_env: pytest.MonkeyPatch) -> None:
    clean_env.setenv("BFIELDS_REDIS_URL", "redis://r:6379/3")
    clean_env.setenv("BFIELDS_STORAGE_BACKEND", "s3")
    clean_env.setenv("BFIELDS_S3_ENDPOINT_URL", "http://minio:9000")
    clean_env.setenv("BFIELDS_S3_ACCESS_KEY_ID", "minioadmin")
    clean_env.setenv("BFIELDS_S3_SECRET_ACCESS_KEY", "topsecret")
    clean_env.setenv("BFIELDS_API_KEYS", json.dumps({"k1": "tenant-a", hash_api_key("k2"): "tenant-b"}))
    clean_env.setenv("BFIELDS_MAX_UPLOAD_BYTES", "1000")
    s = ServiceSettings()
    assert s.redis_url == "redis://r:6379/3" and s.storage_backend == "s3"
    assert s.s3_endpoint_url == "http://minio:9000" and s.max_upload_bytes == 1000
    assert s.s3_secret_access_key is not None and s.s3_secret_access_key.get_secret_value() == "topsecret"
    assert "topsecret" not in repr(s)  # secrets never show up in a repr or log line
    get_settings.cache_clear()
    assert get_settings().redis_url == "redis://r:6379/3"
    get_settings.cache_clear()


def test_every_field_is_documented() -> None:
    undocumented = [n for n, f in ServiceSettings.model_fields.items() if not f.description]
    assert undocumented == []


def test_env_example_lists_every_setting() -> None:
    example = (Path(__file__).resolve().parents[3] / ".env.example").read_text()
    missing = [n for n in ServiceSettings.model_fields if f"BFIELDS_{n.upper()}" not in example]
    assert missing == []


@pytest.mark.parametrize(
    ("env", "message"),
    [
        ({"BFIELDS_REDIS_URL": "http://x"}, "redis://"),
        ({"BFIELDS_STORAGE_BACKEND": "ftp"}, "storage_backend"),
        ({"BFIELDS_S3_ACCESS_KEY_ID": "only-the-id"}, "or neither"),
        ({"BFIELDS_API_KEYS": '{"k": "../evil"}'}, "invalid tenant"),
        ({"BFIELDS_JOB_TIME_LIMIT_S": "10", "BFIELDS_JOB_SOFT_TIME_LIMIT_S": "20"}, "SOFT_TIME_LIMIT"),
        ({"BFIELDS_CELERY_VISIBILITY_TIMEOUT_S": "100"}, "VISIBILITY_TIMEOUT"),
        ({"BFIELDS_S3_MULTIPART_CHUNK_BYTES": "1024"}, "s3_multipart_chunk_bytes"),
        ({"BFIELDS_TRACING": "jaeger"}, "BFIELDS_TRACING takes"),
        ({"BFIELDS_TRACING": "file:"}, "BFIELDS_TRACING takes"),
        ({"BFIELDS_LOG_FORMAT": "xml"}, "log_format"),
    ],
)
def test_bad_settings_fail_clearly(clean_env: pytest.MonkeyPatch, env: dict[str, str], message: str) -> None:
    for k, v in env.items():
        clean_env.setenv(k, v)
    with pytest.raises(ValidationError, match=message):
        ServiceSettings()


def test_tracing_is_off_unless_named_or_an_otlp_endpoint_is_set(clean_env: pytest.MonkeyPatch) -> None:
    for name in ("OTEL_EXPORTER_OTLP_ENDPOINT", "OTEL_EXPORTER_OTLP_TRACES_ENDPOINT"):
        clean_env.delenv(name, raising=False)
    assert ServiceSettings().tracing_mode == "off"
    clean_env.setenv("OTEL_EXPORTER_OTLP_ENDPOINT", "http://collector:4318")
    assert ServiceSettings().tracing_mode == "otlp"
    clean_env.setenv("BFIELDS_TRACING", "off")  # the switch wins over the endpoint
    assert ServiceSettings().tracing_mode == "off"
    clean_env.setenv("BFIELDS_TRACING", "file:/var/log/spans.jsonl")
    assert ServiceSettings().tracing_mode == "file:/var/log/spans.jsonl"


def test_key_ring_inline_and_hashed() -> None:
    ring = ApiKeyRing({"clear-key": "tenant-a", hash_api_key("hashed-key"): "tenant-b"})
    assert ring.tenant_for("clear-key") == "tenant-a"
    assert ring.tenant_for("hashed-key") == "tenant-b"
    assert ring.tenant_for(hash_api_key("hashed-key")) is None  # the stored hash is not a key
    assert ring.tenant_for("wrong") is None and ring.tenant_for("") is None and ring.tenant_for(None) is None


def test_key_ring_file_formats_and_rotation(tmp_path: Path) -> None:
    keys = tmp_path / "keys"
    keys.write_text(f"# operator keys\nfile-key tenant-c\n{hash_api_key('h')}  tenant-d  # hashed\n")
    ring = ApiKeyRing({}, keys)
    assert ring.tenant_for("file-key") == "tenant-c" and ring.tenant_for("h") == "tenant-d"
    time.sleep(0.01)
    keys.write_text(json.dumps({"rotated": "tenant-c"}))
    os.utime(keys, (time.time() + 5, time.time() + 5))  # make the change visible to the mtime check
    assert ring.tenant_for("rotated") == "tenant-c"
    assert ring.tenant_for("file-key") is None  # the old key is gone without a restart
    keys.unlink()
    assert ring.tenant_for("rotated") is None and not ring


def test_key_ring_file_errors_name_the_file(tmp_path: Path) -> None:
    bad = tmp_path / "keys"
    bad.write_text("only-one-field\n")
    with pytest.raises(InputError, match="keys: line 1"):
        ApiKeyRing({}, bad).tenant_for("x")
    bad.write_text('{"k": "bad tenant"}')
    with pytest.raises(InputError, match="invalid tenant"):
        ApiKeyRing({}, bad).tenant_for("x")


def test_no_service_module_reads_the_environment_itself() -> None:
    """Service knobs come from `ServiceSettings` alone (documented, validated, in .env.example):
    no module of the API or the workers reads `os.environ` / `os.getenv` on its own. The client
    (`services/client`) runs on a user's machine and is not configured by the service's settings."""
    root = Path(__file__).resolve().parents[3] / "services"
    readers = []
    for path in sorted(root.rglob("*.py")):
        if path.name == "settings.py" or "client" in path.relative_to(root).parts:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Attribute) and node.attr in {"environ", "getenv"}:
                if isinstance(node.value, ast.Name) and node.value.id == "os":
                    readers.append(f"{path.relative_to(root.parent)}:{node.lineno}")
    assert readers == []


def test_stages_are_defined_once() -> None:
    from bayesian_fields_core.job.stage_table import STAGES
    from bayesian_fields_service.jobs import model as jobs

    assert jobs.STAGES is STAGES
    assert list(jobs.STAGE_WEIGHTS) == list(STAGES)
