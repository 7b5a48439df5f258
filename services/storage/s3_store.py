"""`Store` on S3-compatible object storage (AWS S3, MinIO, rclone serve s3, ...) with boto3.

Besides the `Store` protocol the service needs things only object storage offers: presigned URLs
so clients upload scenes and download results straight from the bucket (the API never proxies
gigabytes), presigned *multipart* uploads for archives larger than one PUT should carry, and batch
deletes. Transient failures are retried twice over: botocore's 'standard' retry mode covers
throttling, 5xx and connection errors on the request itself, and `_retry` re-runs whole idempotent
operations (request + body read) when the connection drops mid-stream.

Self-hosted servers differ from AWS in small ways; the client is configured for the common subset:
path-style addressing by default, and checksums only when required (several servers return the
full-object checksum on ranged reads, which botocore's default validation rejects).
"""

from __future__ import annotations

import builtins
import functools
import logging
import os
import random
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from datetime import datetime
from io import BytesIO
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING, Any, Literal, TypeVar

import boto3
import botocore.exceptions as bce
from boto3.s3.transfer import TransferConfig
from botocore.config import Config

from bayesian_fields_core.errors import BayesianFieldsError, InputError
from bayesian_fields_core.job.atomic import atomic_temp
from bayesian_fields_core.job.store import ArtifactNotFound, validate_key

if TYPE_CHECKING:
    from mypy_boto3_s3.type_defs import CompletedMultipartUploadTypeDef, ObjectIdentifierTypeDef

log = logging.getLogger(__name__)
T = TypeVar("T")

MiB = 1024**2
#: S3's limits on multipart uploads: parts of at least 5 MiB (except the last), at most 10 000 parts.
MIN_PART_BYTES = 5 * MiB
MAX_PARTS = 10_000
_DELETE_BATCH = 1000  # DeleteObjects takes at most 1000 keys per request

_NOT_FOUND = {"404", "NoSuchKey", "NotFound", "NoSuchBucket"}
_AUTH = {"403", "AccessDenied", "InvalidAccessKeyId", "SignatureDoesNotMatch", "InvalidToken"}
_TRANSIENT_EXC = (
    bce.ConnectionError,  # includes EndpointConnectionError, ConnectTimeoutError, ReadTimeoutError
    bce.HTTPClientError,
    bce.IncompleteReadError,
    bce.ResponseStreamingError,
)


class StorageError(BayesianFieldsError):
    """Object storage failed in a way the caller cannot fix by changing its input."""


class StorageAuthError(StorageError):
    """The storage server rejected the configured credentials (403)."""


@dataclass(frozen=True)
class S3Credentials:
    access_key_id: str
    secret_access_key: str

    def __repr__(self) -> str:  # never print the secret
        return f"S3Credentials(access_key_id={self.access_key_id!r}, secret_access_key='***')"


@dataclass(frozen=True)
class ObjectInfo:
    """One object of a listing: key, size in bytes, ETag (quotes stripped), last-modified time."""

    key: str
    size: int
    etag: str
    last_modified: datetime


@dataclass(frozen=True)
class PendingUpload:
    """A multipart upload that was started and neither completed nor aborted."""

    key: str
    upload_id: str
    initiated: datetime


@dataclass(frozen=True)
class PartSpec:
    """One part of a planned multipart upload: bytes [start, end) of the file."""

    part_number: int
    start: int
    end: int


def plan_parts(total_bytes: int, part_bytes: int) -> list[PartSpec]:
    """Split `total_bytes` into S3 parts of `part_bytes` (the last one shorter).

    Raises InputError when the plan would break S3's limits, so a client learns before uploading.
    """
    if total_bytes <= 0:
        raise InputError(f"multipart upload: size must be positive, got {total_bytes}")
    if part_bytes < MIN_PART_BYTES:
        raise InputError(f"multipart upload: part size {part_bytes} is below S3's minimum {MIN_PART_BYTES}")
    n = -(-total_bytes // part_bytes)
    if n > MAX_PARTS:
        raise InputError(
            f"multipart upload: {total_bytes} bytes in parts of {part_bytes} needs {n} parts (max {MAX_PARTS})"
        )
    return [PartSpec(i + 1, i * part_bytes, min(total_bytes, (i + 1) * part_bytes)) for i in range(n)]


def _file_name(key: str) -> str:
    """What a client-facing message may say about an object: its file name, never the bucket key
    (``tenants/<tenant>/scenes/<id>/staging/...`` names the layout and other tenants' prefix)."""
    return PurePosixPath(key).name or "object"


def _key(key: str) -> str:
    """`validate_key`, plus what only matters on S3: 'a//b' and 'a/' would be keys distinct from
    'a/b' and 'a' there, while a folder-backed store maps them to the same file."""
    validate_key(key)
    if "//" in key or key.endswith("/"):
        raise InputError(f"invalid artifact key {key!r}")
    return key


def _validate_prefix(prefix: str) -> str:
    """A list/delete prefix: '' or a key-like string, optionally ending in '/'."""
    if prefix:
        _key(prefix[:-1] if prefix.endswith("/") else prefix)
    return prefix


def _code(exc: bce.ClientError) -> str:
    return str(exc.response.get("Error", {}).get("Code", ""))


def _status(exc: bce.ClientError) -> int:
    return int(exc.response.get("ResponseMetadata", {}).get("HTTPStatusCode", 0) or 0)


class S3Store:
    """A `Store` on one bucket. Thread-safe (boto3 clients are); create one per process."""

    def __init__(
        self,
        bucket: str,
        *,
        endpoint_url: str | None = None,
        public_endpoint_url: str | None = None,
        region: str = "us-east-1",
        credentials: S3Credentials | None = None,
        addressing_style: Literal["auto", "path", "virtual"] = "path",
        multipart_threshold: int = 64 * MiB,
        multipart_chunksize: int = 16 * MiB,
        max_concurrency: int = 4,
        max_attempts: int = 5,
        connect_timeout_s: float = 5.0,
        read_timeout_s: float = 60.0,
        retry_base_delay_s: float = 0.2,
        retry_max_delay_s: float = 5.0,
    ) -> None:
        self.bucket = bucket
        self.endpoint_url = endpoint_url
        self.region = region
        self.max_attempts = max_attempts
        self.retry_base_delay_s = retry_base_delay_s
        self.retry_max_delay_s = retry_max_delay_s
        config = Config(
            region_name=region,
            signature_version="s3v4",
            s3={"addressing_style": addressing_style},
            retries={"mode": "standard", "max_attempts": max_attempts},
            connect_timeout=connect_timeout_s,
            read_timeout=read_timeout_s,
            request_checksum_calculation="when_required",
            response_checksum_validation="when_required",
            max_pool_connections=max(10, max_concurrency * 2),
        )
        kwargs: dict[str, Any] = {"endpoint_url": endpoint_url, "config": config}
        if credentials is not None:
            kwargs["aws_access_key_id"] = credentials.access_key_id
            kwargs["aws_secret_access_key"] = credentials.secret_access_key
        self.client = boto3.session.Session().client("s3", **kwargs)
        # Presigned links are for clients, which may reach the store at another address than this
        # process (a host outside the compose network); a SigV4 signature covers the host, so the
        # links are signed by a client of that address. Signing sends no request.
        self.presign_client = (
            boto3.session.Session().client("s3", **{**kwargs, "endpoint_url": public_endpoint_url})
            if public_endpoint_url
            else self.client
        )
        self.transfer_config = TransferConfig(
            multipart_threshold=multipart_threshold,
            multipart_chunksize=multipart_chunksize,
            max_concurrency=max_concurrency,
            use_threads=max_concurrency > 1,
        )

    @classmethod
    def from_settings(cls, settings: Any, **tuning: Any) -> S3Store:
        """Build from `bayesian_fields_service.config.settings.ServiceSettings` (`tuning` overrides the retry and
        timeout parameters, e.g. the API's short request-path budget)."""
        creds = None
        if settings.s3_access_key_id and settings.s3_secret_access_key is not None:
            creds = S3Credentials(settings.s3_access_key_id, settings.s3_secret_access_key.get_secret_value())
        return cls(
            settings.s3_bucket,
            endpoint_url=settings.s3_endpoint_url,
            public_endpoint_url=settings.s3_public_endpoint_url,
            region=settings.s3_region,
            credentials=creds,
            addressing_style=settings.s3_addressing_style,
            multipart_threshold=settings.s3_multipart_threshold_bytes,
            multipart_chunksize=settings.s3_multipart_chunk_bytes,
            **{"max_attempts": settings.s3_max_attempts, **tuning},
        )

    def __repr__(self) -> str:
        return f"S3Store(bucket={self.bucket!r}, endpoint_url={self.endpoint_url!r})"

    # ---- error handling --------------------------------------------------------------------

    def _translate(self, exc: bce.ClientError, key: str | None) -> Exception:
        code = _code(exc)
        if code in _NOT_FOUND or _status(exc) == 404:
            if code == "NoSuchBucket":
                return StorageError(f"bucket {self.bucket!r} does not exist at {self.endpoint_url or 'AWS'}")
            return ArtifactNotFound(key)
        if code in _AUTH or _status(exc) == 403:
            return StorageAuthError(
                f"object storage at {self.endpoint_url or 'AWS'} refused access to bucket {self.bucket!r} "
                f"({code or 'HTTP 403'}): check BFIELDS_S3_ACCESS_KEY_ID / BFIELDS_S3_SECRET_ACCESS_KEY "
                "and the bucket policy"
            )
        return StorageError(f"object storage error on {key or self.bucket!r}: {code}: {exc}")

    def _retry(self, fn: Callable[[], T], key: str | None) -> T:
        """Run an idempotent operation, retrying dropped connections with exponential backoff and
        full jitter; translate S3 error codes into the store's exceptions."""
        attempt = 0
        while True:
            try:
                return fn()
            except bce.ClientError as exc:
                raise self._translate(exc, key) from exc
            except _TRANSIENT_EXC as exc:
                attempt += 1
                if attempt >= self.max_attempts:
                    raise StorageError(
                        f"object storage at {self.endpoint_url or 'AWS'} unreachable after {attempt} attempts "
                        f"({type(exc).__name__}: {exc})"
                    ) from exc
                delay = random.uniform(0, min(self.retry_max_delay_s, self.retry_base_delay_s * 2**attempt))
                log.warning("S3 %s: %s; retry %d in %.2fs", key, type(exc).__name__, attempt, delay)
                time.sleep(delay)

    # ---- Store protocol --------------------------------------------------------------------

    def put_bytes(self, key: str, data: bytes) -> None:
        _key(key)
        if len(data) >= self.transfer_config.multipart_threshold:
            self._retry(
                lambda: self.client.upload_fileobj(
                    BytesIO(data), self.bucket, key, Config=self.transfer_config
                ),
                key,
            )
        else:
            self._retry(lambda: self.client.put_object(Bucket=self.bucket, Key=key, Body=data), key)

    def get_bytes(self, key: str) -> bytes:
        _key(key)
        return self._retry(lambda: self.client.get_object(Bucket=self.bucket, Key=key)["Body"].read(), key)

    def get_range(self, key: str, start: int, end: int) -> bytes:
        """Bytes [start, end) (end exclusive, like Python slices; S3's Range header is inclusive).
        A range past the end of the object yields b'' (as with a file), not an error."""
        _key(key)
        if start < 0 or end < 0:
            raise InputError(f"ranged read: negative offsets {start}, {end}", source=_file_name(key))
        if end <= start:
            return b""

        def read() -> bytes:
            try:
                resp = self.client.get_object(Bucket=self.bucket, Key=key, Range=f"bytes={start}-{end - 1}")
            except bce.ClientError as exc:
                if _code(exc) == "InvalidRange" or _status(exc) == 416:
                    self.size(key)  # raises ArtifactNotFound if the object is missing
                    return b""
                raise
            return resp["Body"].read()

        return self._retry(read, key)

    def put_file(self, key: str, path: Path) -> None:
        """Upload a file; multipart (parallel parts) above the configured threshold."""
        _key(key)
        if not Path(path).is_file():
            raise InputError("not a file", source=str(path))
        self._retry(
            lambda: self.client.upload_file(str(path), self.bucket, key, Config=self.transfer_config), key
        )

    def get_file(self, key: str, path: Path) -> None:
        """Download to `path` atomically (temp file in the same folder, then rename)."""
        _key(key)
        dest = Path(path)
        dest.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = atomic_temp(dest.parent)
        os.close(fd)
        try:
            self._retry(
                lambda: self.client.download_file(self.bucket, key, str(tmp), Config=self.transfer_config),
                key,
            )
            os.replace(tmp, dest)
        finally:
            Path(tmp).unlink(missing_ok=True)

    def exists(self, key: str) -> bool:
        try:
            self.size(key)
        except ArtifactNotFound:
            return False
        return True

    def size(self, key: str) -> int:
        _key(key)
        head = self._retry(lambda: self.client.head_object(Bucket=self.bucket, Key=key), key)
        return int(head["ContentLength"])

    def iter_keys(self, prefix: str, *, page_size: int = 1000) -> Iterator[str]:
        """Keys starting with `prefix`, page by page (ListObjectsV2 continuation tokens)."""
        _validate_prefix(prefix)
        paginator = self.client.get_paginator("list_objects_v2")
        pages = paginator.paginate(
            Bucket=self.bucket, Prefix=prefix, PaginationConfig={"PageSize": page_size}
        )
        try:
            for page in pages:
                for obj in page.get("Contents", []):
                    yield obj["Key"]
        except bce.ClientError as exc:
            raise self._translate(exc, prefix) from exc

    def list_objects(self, prefix: str) -> list[ObjectInfo]:
        """Objects under `prefix` with size, ETag and last-modified time, in key order (the same
        LIST calls as `list`: sizes come free, no HEAD per key)."""
        _validate_prefix(prefix)

        def collect() -> list[ObjectInfo]:
            out = []
            for page in self.client.get_paginator("list_objects_v2").paginate(
                Bucket=self.bucket, Prefix=prefix
            ):
                for obj in page.get("Contents", []):
                    out.append(
                        ObjectInfo(
                            obj["Key"],
                            int(obj["Size"]),
                            str(obj.get("ETag", "")).strip('"'),
                            obj["LastModified"],
                        )
                    )
            return sorted(out, key=lambda o: o.key)

        return self._retry(collect, prefix)

    def list_prefixes(self, prefix: str) -> list[str]:
        """The 'folders' right below `prefix` (which should end in '/'): ListObjectsV2 with a '/'
        delimiter, so a tenant's scenes are listed without walking their files."""
        _validate_prefix(prefix)

        def collect() -> list[str]:
            pages = self.client.get_paginator("list_objects_v2").paginate(
                Bucket=self.bucket, Prefix=prefix, Delimiter="/"
            )
            return sorted(p["Prefix"] for page in pages for p in page.get("CommonPrefixes", []))

        return self._retry(collect, prefix)

    def list(self, prefix: str, *, page_size: int = 1000) -> list[str]:
        return sorted(self._retry(lambda: list(self.iter_keys(prefix, page_size=page_size)), prefix))

    def delete(self, key: str) -> None:
        _key(key)
        self._retry(lambda: self.client.delete_object(Bucket=self.bucket, Key=key), key)

    def delete_prefix(self, prefix: str) -> int:
        """Delete every key under `prefix` with batched DeleteObjects; returns how many."""
        keys = self.list(prefix)
        for i in range(0, len(keys), _DELETE_BATCH):
            batch: list[ObjectIdentifierTypeDef] = [{"Key": k} for k in keys[i : i + _DELETE_BATCH]]
            resp = self._retry(
                functools.partial(
                    self.client.delete_objects, Bucket=self.bucket, Delete={"Objects": batch, "Quiet": True}
                ),
                prefix,
            )
            if resp.get("Errors"):
                first = resp["Errors"][0]
                raise StorageError(
                    f"delete of {len(resp['Errors'])} keys under {prefix!r} failed, e.g. "
                    f"{first.get('Key')}: {first.get('Code')} {first.get('Message')}"
                )
        return len(keys)

    # ---- bucket ----------------------------------------------------------------------------

    def ensure_bucket(self) -> None:
        """Create the bucket if it does not exist (idempotent; for start-up and tests)."""
        try:
            self._retry(lambda: self.client.head_bucket(Bucket=self.bucket), None)
            return
        except ArtifactNotFound:
            pass
        except StorageError as exc:
            if "does not exist" not in str(exc):
                raise
        kwargs: dict[str, Any] = {"Bucket": self.bucket}
        if self.region != "us-east-1":
            kwargs["CreateBucketConfiguration"] = {"LocationConstraint": self.region}
        try:
            self.client.create_bucket(**kwargs)
        except bce.ClientError as exc:
            if _code(exc) not in {"BucketAlreadyOwnedByYou", "BucketAlreadyExists"}:
                raise self._translate(exc, None) from exc

    # ---- presigned URLs --------------------------------------------------------------------

    def presigned_get(self, key: str, expires_s: int = 3600, *, filename: str | None = None) -> str:
        """A URL anyone holding it can GET for `expires_s` seconds. `filename` sets the download
        name (Content-Disposition)."""
        params: dict[str, Any] = {"Bucket": self.bucket, "Key": _key(key)}
        if filename:
            safe = PurePosixPath(filename).name.replace('"', "")
            params["ResponseContentDisposition"] = f'attachment; filename="{safe}"'
        return self.presign_client.generate_presigned_url("get_object", Params=params, ExpiresIn=expires_s)

    def presigned_put(self, key: str, expires_s: int = 3600, *, content_type: str | None = None) -> str:
        """A URL to PUT one object (up to 5 GiB) for `expires_s` seconds. When `content_type` is
        given the uploader must send the same Content-Type header (it is signed)."""
        params: dict[str, Any] = {"Bucket": self.bucket, "Key": _key(key)}
        if content_type:
            params["ContentType"] = content_type
        return self.presign_client.generate_presigned_url("put_object", Params=params, ExpiresIn=expires_s)

    # ---- presigned multipart upload (large scene archives) ----------------------------------

    def create_multipart_upload(self, key: str, *, content_type: str | None = None) -> str:
        """Start a multipart upload; returns its upload id. Not retried: a retry would leak an
        orphan upload (abort it, or let a bucket lifecycle rule expire it)."""
        params: dict[str, Any] = {"Bucket": self.bucket, "Key": _key(key)}
        if content_type:
            params["ContentType"] = content_type
        try:
            return str(self.client.create_multipart_upload(**params)["UploadId"])
        except bce.ClientError as exc:
            raise self._translate(exc, key) from exc

    def presigned_upload_part(self, key: str, upload_id: str, part_number: int, expires_s: int = 3600) -> str:
        """A URL to PUT part `part_number` (1..10000) of an upload; the response's ETag header
        identifies the part (S3 also remembers it, see `list_parts`)."""
        if not 1 <= part_number <= MAX_PARTS:
            raise InputError(f"part number {part_number} out of range 1..{MAX_PARTS}")
        params = {
            "Bucket": self.bucket,
            "Key": _key(key),
            "UploadId": upload_id,
            "PartNumber": part_number,
        }
        return self.presign_client.generate_presigned_url("upload_part", Params=params, ExpiresIn=expires_s)

    def list_parts(self, key: str, upload_id: str) -> builtins.list[dict[str, Any]]:
        """Parts uploaded so far: [{'PartNumber', 'ETag', 'Size'}], in part order."""
        _key(key)
        parts: list[dict[str, Any]] = []
        paginator = self.client.get_paginator("list_parts")

        def collect() -> list[dict[str, Any]]:
            parts.clear()
            for page in paginator.paginate(Bucket=self.bucket, Key=key, UploadId=upload_id):
                parts.extend(
                    {"PartNumber": p["PartNumber"], "ETag": p["ETag"], "Size": p["Size"]}
                    for p in page.get("Parts", [])
                )
            return sorted(parts, key=lambda p: p["PartNumber"])

        return self._retry(collect, key)

    def complete_multipart_upload(
        self, key: str, upload_id: str, parts: builtins.list[dict[str, Any]] | None = None
    ) -> None:
        """Assemble the parts into the object. `parts` = [{'PartNumber', 'ETag'}] as reported by
        the uploader; None takes the server's own list (`list_parts`)."""
        _key(key)
        if parts is None:
            parts = self.list_parts(key, upload_id)
        if not parts:
            raise InputError("no parts were uploaded", source=_file_name(key))
        body: CompletedMultipartUploadTypeDef = {
            "Parts": sorted(
                ({"PartNumber": int(p["PartNumber"]), "ETag": str(p["ETag"])} for p in parts),
                key=lambda p: p["PartNumber"],
            )
        }
        try:
            self.client.complete_multipart_upload(
                Bucket=self.bucket, Key=key, UploadId=upload_id, MultipartUpload=body
            )
        except bce.ClientError as exc:
            if _code(exc) in {"InvalidPart", "InvalidPartOrder", "EntityTooSmall", "NoSuchUpload"}:
                raise InputError(
                    f"the upload cannot be completed: {_code(exc)} (the part numbers and ETags must be "
                    "those the part uploads answered)",
                    source=_file_name(key),
                ) from exc
            raise self._translate(exc, key) from exc

    def list_multipart_uploads(self, prefix: str) -> builtins.list[PendingUpload]:
        """Multipart uploads under `prefix` that were started and never completed or aborted
        (their parts use storage but no listing of objects shows them)."""
        _validate_prefix(prefix)

        def collect() -> list[PendingUpload]:
            out = []
            try:
                for page in self.client.get_paginator("list_multipart_uploads").paginate(
                    Bucket=self.bucket, Prefix=prefix
                ):
                    for up in page.get("Uploads", []):
                        out.append(PendingUpload(up["Key"], up["UploadId"], up["Initiated"]))
            except bce.ClientError as exc:
                if _code(exc) != "NoSuchUpload":  # rclone's (gofakes3's) answer when there are none
                    raise
            return out

        return self._retry(collect, prefix)

    def abort_multipart_upload(self, key: str, upload_id: str) -> None:
        """Discard an upload and its parts (idempotent: an unknown upload id is ignored)."""
        _key(key)
        try:
            self._retry(
                lambda: self.client.abort_multipart_upload(Bucket=self.bucket, Key=key, UploadId=upload_id),
                key,
            )
        except ArtifactNotFound:
            pass
