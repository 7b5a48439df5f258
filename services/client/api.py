"""A small typed client of the HTTP API (httpx), used by `bfields submit|status|fetch|batch`.

It packs a scene folder the way the server expects it (the .ply, the camera file(s), the images
zipped into one archive), uploads it with a progress callback, and wraps the job/batch routes.
Errors from the server become `ClientError` carrying the server's message, which already names
the file and the problem. A 429 (the tenant's waiting bound is full) or 503 (a backend is down)
is retried after the server's ``Retry-After`` (bounded: `RetryPolicy`), as is a lost connection
when the request is safe to repeat (a GET, or a POST carrying an Idempotency-Key).
"""

from __future__ import annotations

import io
import json
import os
import tempfile
import time
import zipfile
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.atomic import atomic_temp
from bayesian_fields_core.scene.trainer_transforms import SPLAT_TRANSFORM

ProgressFn = Callable[[int], None]  # called with bytes just sent/received
COLMAP_FILES = (
    "cameras.txt", "images.txt", "points3D.txt", "cameras.bin", "images.bin", "points3D.bin",
    "frames.txt", "rigs.txt", "frames.bin", "rigs.bin",
)  # fmt: skip
TERMINAL = ("succeeded", "failed", "cancelled")
RETRY_STATUSES = (429, 503)


@dataclass(frozen=True)
class RetryPolicy:
    """Bounded backoff: at most `attempts` tries; each wait is the server's Retry-After (or
    1, 2, 4, ... s without one), capped at `max_wait_s`; no wait once `budget_s` is spent."""

    attempts: int = 8
    max_wait_s: float = 60.0
    budget_s: float = 600.0

    def wait_s(self, attempt: int, retry_after: str | None) -> float:
        try:
            wanted = float(retry_after) if retry_after is not None else 2.0**attempt
        except ValueError:
            wanted = 2.0**attempt
        return min(max(wanted, 0.0), self.max_wait_s)


class ClientError(RuntimeError):
    """The server refused a request (the message is the server's) or could not be reached."""

    def __init__(self, message: str, status: int | None = None) -> None:
        self.status = status
        super().__init__(message)


class _ProgressFile(io.FileIO):
    """A file that reports every read, so httpx's multipart upload drives a progress bar."""

    def __init__(self, path: Path, on_bytes: ProgressFn | None) -> None:
        super().__init__(path, "rb")
        self._on_bytes = on_bytes

    def read(self, size: int | None = -1) -> bytes:
        data = super().read(size)
        if self._on_bytes is not None and data:
            self._on_bytes(len(data))
        return data


@dataclass(frozen=True)
class SceneUpload:
    """What `upload_scene` sends for a scene folder: the form's files and the splat's frame."""

    splat: Path
    cameras: list[Path]
    images: list[Path]
    images_root: Path  # the images are zipped relative to this folder
    splat_to_camera: list[list[float]] | None  # (4, 4) similarity; None: same frame as the cameras


def scene_files(folder: Path) -> SceneUpload:
    """The files of a scene folder, resolved with the same layout rules as `bfields run` (INRIA,
    splatfacto, gsplat, scene.yaml), so a trainer's output folder uploads as it is. The splat's
    frame, when it differs from the cameras', travels as the resolved similarity (the server
    applies it the same way whichever trainer made it)."""
    from bayesian_fields_core.scene.layout import resolve_layout

    folder = Path(folder)
    layout = resolve_layout(folder, allow_source_path=True)
    camera = layout.camera_path
    cameras = [camera] if camera.is_file() else sorted(p for p in camera.iterdir() if p.name in COLMAP_FILES)
    images_dir = layout.images_dir or folder / "images"
    if not images_dir.is_dir():
        raise InputError(f"no images folder ({images_dir.name}/) next to the cameras", source=str(folder))
    images = sorted(p for p in images_dir.rglob("*") if p.is_file() and not p.name.startswith("."))
    similarity = layout.splat_to_capture
    return SceneUpload(
        splat=layout.splat,
        cameras=cameras,
        images=images,
        images_root=images_dir,
        splat_to_camera=None if similarity is None else similarity.matrix.tolist(),
    )


def uploadable_splat(splat: Path, tmp: Path) -> Path:
    """The file to send for a splat: itself, except a gsplat checkpoint (the service opens no
    pickle stream: it is read here with weights_only and sent as an INRIA .ply) and a SOG folder
    (zipped into the single-file .sog, which is the same members in a zip)."""
    name = splat.name.lower()
    if name.endswith(".pt"):
        from bayesian_fields_core.scene.formats import read_splat
        from bayesian_fields_core.scene.ply import DEFAULT_MAX_GAUSSIANS, write_ply

        out = tmp / (splat.stem + ".ply")
        write_ply(out, read_splat(splat, max_gaussians=DEFAULT_MAX_GAUSSIANS))
        return out
    if name == "meta.json":
        from bayesian_fields_core.scene.formats.sog import sog_members

        out = tmp / ((splat.parent.name or "splat") + ".sog")
        with zipfile.ZipFile(out, "w", zipfile.ZIP_STORED) as zf:
            for member in sog_members(splat):
                zf.write(splat.parent / member, member)
        return out
    return splat


def zip_images(images: list[Path], root: Path, dest: Path) -> Path:
    """Store (no recompression: images are compressed already) the images under their path
    relative to `root` (the images/ folder)."""
    with zipfile.ZipFile(dest, "w", zipfile.ZIP_STORED) as zf:
        for path in images:
            zf.write(path, path.relative_to(root).as_posix())
    return dest


class BFieldsClient:
    """Calls the API of one server with one API key."""

    def __init__(self, server: str, api_key: str | None, *, timeout_s: float = 60.0,
                 retry: RetryPolicy | None = None, sleep: Callable[[float], None] = time.sleep) -> None:  # fmt: skip
        self.retry = retry or RetryPolicy()
        self.sleep = sleep
        self.retries_done = 0  # how many 429/503/connection retries this client made (for tests, logs)
        if not api_key:
            raise ClientError("no API key: pass --api-key or set BFIELDS_API_KEY")
        self.server = server.rstrip("/")
        self.http = httpx.Client(
            base_url=self.server,
            headers={"X-API-Key": api_key},
            timeout=httpx.Timeout(timeout_s, connect=10.0),
        )

    def close(self) -> None:
        self.http.close()

    def __enter__(self) -> BFieldsClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- plumbing ------------------------------------------------------------------------------
    def _call(self, method: str, path: str, *, retry: bool = True, **kwargs: Any) -> Any:
        """One API call; `retry=False` for a request whose body cannot be sent twice (a stream)."""
        headers = kwargs.get("headers") or {}
        repeatable = retry and (method == "GET" or "Idempotency-Key" in headers)
        started = time.monotonic()
        attempt = 0
        while True:
            attempt += 1
            last = attempt >= self.retry.attempts or time.monotonic() - started > self.retry.budget_s
            try:
                resp = self.http.request(method, path, **kwargs)
            except httpx.TransportError as exc:
                if not repeatable or last:
                    raise ClientError(f"{self.server}: {type(exc).__name__}: {exc}") from None
                self._backoff(attempt, None)
                continue
            except httpx.HTTPError as exc:
                raise ClientError(f"{self.server}: {type(exc).__name__}: {exc}") from None
            if retry and resp.status_code in RETRY_STATUSES and not last:
                self._backoff(attempt, resp.headers.get("Retry-After"))
                continue
            break
        if resp.status_code >= 400:
            try:
                detail = resp.json().get("detail", resp.text)
            except ValueError:
                detail = resp.text
            raise ClientError(f"{method} {path}: HTTP {resp.status_code}: {detail}", resp.status_code)
        return (
            resp.json()
            if resp.content and resp.headers.get("content-type", "").startswith("application/json")
            else None
        )

    def _backoff(self, attempt: int, retry_after: str | None) -> None:
        self.retries_done += 1
        self.sleep(self.retry.wait_s(attempt - 1, retry_after))

    # ---- scenes --------------------------------------------------------------------------------
    def upload_scene(self, folder: Path, *, name: str | None = None, on_bytes: ProgressFn | None = None,
                     on_total: Callable[[int], None] | None = None) -> dict[str, Any]:  # fmt: skip
        """Zip the images, upload splat + cameras + zip in one multipart request."""
        files = scene_files(Path(folder))
        with tempfile.TemporaryDirectory(prefix="bfields-submit-") as tmp, ExitStack() as stack:
            archive = zip_images(files.images, files.images_root, Path(tmp) / "images.zip")
            splat = uploadable_splat(files.splat, Path(tmp))
            parts = [("splat", splat), *(("cameras", p) for p in files.cameras), ("images", archive)]
            if files.splat_to_camera is not None:
                transform = Path(tmp) / SPLAT_TRANSFORM
                transform.write_text(json.dumps({"splat_to_camera": files.splat_to_camera}))
                parts.append(("transform", transform))
            if on_total is not None:
                on_total(sum(p.stat().st_size for _, p in parts))
            form = [(field, (p.name, stack.enter_context(_ProgressFile(p, on_bytes)))) for field, p in parts]
            return self._call("POST", "/v1/scenes", files=form, data={"name": name or Path(folder).name},
                              timeout=httpx.Timeout(None, connect=10.0), retry=False)  # fmt: skip

    def scene(self, scene_id: str) -> dict[str, Any]:
        return self._call("GET", f"/v1/scenes/{scene_id}")

    # ---- jobs ----------------------------------------------------------------------------------
    def submit_job(self, scene_id: str, tasks: list[str], *, parameters: dict[str, Any] | None = None,
                   model_profile: str = "default", idempotency_key: str | None = None,
                   priority: str = "interactive") -> dict[str, Any]:  # fmt: skip
        headers = {"Idempotency-Key": idempotency_key} if idempotency_key else None
        body = {
            "scene_id": scene_id,
            "tasks": tasks,
            "parameters": parameters or {},
            "model_profile": model_profile,
            "priority": priority,
        }
        return self._call("POST", "/v1/jobs", json=body, headers=headers)

    def job(self, job_id: str) -> dict[str, Any]:
        return self._call("GET", f"/v1/jobs/{job_id}")

    def cancel(self, job_id: str) -> dict[str, Any]:
        return self._call("DELETE", f"/v1/jobs/{job_id}")

    def result(self, job_id: str) -> dict[str, Any]:
        return self._call("GET", f"/v1/jobs/{job_id}/result")

    def wait(self, job_id: str, *, poll_s: float = 1.0, timeout_s: float | None = None,
             on_update: Callable[[dict[str, Any]], None] | None = None) -> dict[str, Any]:  # fmt: skip
        """Poll until the job ends; returns its final record."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            job = self.job(job_id)
            if on_update is not None:
                on_update(job)
            if job["state"] in TERMINAL:
                return job
            if deadline is not None and time.monotonic() > deadline:
                raise ClientError(f"job {job_id} still {job['state']} after {timeout_s} s")
            time.sleep(poll_s)

    def download_artifacts(
        self, job_id: str, out_dir: Path, *, on_bytes: ProgressFn | None = None
    ) -> list[Path]:
        """Download every artifact of a finished job (presigned URLs) into `out_dir`."""
        result = self.result(job_id)
        out_dir = Path(out_dir)
        written = []
        for art in result["artifacts"]:
            dest = (out_dir / art["path"]).resolve()
            if not dest.is_relative_to(out_dir.resolve()):
                raise ClientError(f"refusing artifact path {art['path']!r} outside {out_dir}")
            dest.parent.mkdir(parents=True, exist_ok=True)
            url = art["url"]
            client = self.http if url.startswith("/") else httpx.Client(timeout=self.http.timeout)
            with _download(client, url, dest, on_bytes) as size:
                if size != art["size"]:
                    raise ClientError(f"{art['path']}: downloaded {size} bytes, expected {art['size']}")
            if client is not self.http:
                client.close()
            written.append(dest)
        (out_dir / "result.json").write_text(_json(result))
        return written

    # ---- batches -------------------------------------------------------------------------------
    def submit_batch(self, body: dict[str, Any], *, idempotency_key: str | None = None) -> dict[str, Any]:
        headers = {"Idempotency-Key": idempotency_key} if idempotency_key else None
        return self._call("POST", "/v1/batches", json=body, headers=headers)

    def batch(self, batch_id: str, *, jobs: bool = False) -> dict[str, Any]:
        """A batch's counts and progress; `jobs=True` lists its jobs too, which the server answers
        for a batch of at most its `BFIELDS_BATCH_JOBS_INLINE_MAX` jobs only (422 past it): read
        any batch's jobs with `batch_jobs`."""
        params = {"jobs": "true"} if jobs else None
        return self._call("GET", f"/v1/batches/{batch_id}", params=params)

    def batch_jobs(self, batch_id: str, *, page: int = 500) -> Iterator[dict[str, Any]]:
        """Every job record of a batch, a page at a time."""
        cursor: str | None = None
        while True:
            params: dict[str, Any] = {"limit": page, **({"cursor": cursor} if cursor else {})}
            got = self._call("GET", f"/v1/batches/{batch_id}/jobs", params=params)
            yield from got["items"]
            cursor = got.get("next_cursor")
            if not cursor:
                return

    def answers(
        self,
        batch_id: str | None = None,
        *,
        task: str | None = None,
        min_probability: float | None = None,
        max_rank: int | None = None,
        found: bool | None = None,
        scene: str | None = None,
        all_ranks: bool = False,
        page: int = 500,
    ) -> Iterator[dict[str, Any]]:
        """Answers as rows, a page at a time: a batch's (`batch_id`; every task, or `task`), or
        with no batch one task's across your fleet (`task` required: each scene's latest
        succeeded job that asked it, best first; `all_ranks` for every ranked object)."""
        params: dict[str, Any] = {"limit": page, "task": task, "min_probability": min_probability}
        if batch_id is not None:
            path = f"/v1/batches/{batch_id}/answers"
            params |= {"max_rank": max_rank, "scene": scene,
                       "found": None if found is None else str(found).lower()}  # fmt: skip
        else:
            path, params["all_ranks"] = "/v1/answers", str(all_ranks).lower()
        params = {k: v for k, v in params.items() if v is not None}
        cursor: str | None = None
        while True:
            got = self._call("GET", path, params={**params, **({"cursor": cursor} if cursor else {})})
            yield from got["items"]
            cursor = got.get("next_cursor")
            if not cursor:
                return

    def fleet_answers(self, task: str, *, min_probability: float | None = None) -> dict[str, Any]:
        """The first page of one task's fleet search with its counts (`asked`, `found`, `not_found`)."""
        params = {
            "task": task,
            **({"min_probability": min_probability} if min_probability is not None else {}),
        }
        return self._call("GET", "/v1/answers", params=params)

    def cancel_batch(self, batch_id: str) -> dict[str, Any]:
        return self._call("POST", f"/v1/batches/{batch_id}/cancel")

    def retry_batch(self, batch_id: str) -> dict[str, Any]:
        return self._call("POST", f"/v1/batches/{batch_id}/retry")


@contextmanager
def _download(client: httpx.Client, url: str, dest: Path, on_bytes: ProgressFn | None) -> Iterator[int]:
    """Stream `url` into `dest` atomically; yields the byte count."""
    fd, tmp = atomic_temp(dest.parent, prefix=".part-")
    size = 0
    try:
        with os.fdopen(fd, "wb") as fh, _streamed(client, url, dest) as resp:
            if resp.status_code != 200:
                raise ClientError(
                    f"download of {dest.name} failed: HTTP {resp.status_code}", resp.status_code
                )
            for chunk in resp.iter_bytes(1 << 20):
                fh.write(chunk)
                size += len(chunk)
                if on_bytes is not None:
                    on_bytes(len(chunk))
        os.replace(tmp, dest)
        yield size
    finally:
        Path(tmp).unlink(missing_ok=True)


@contextmanager
def _streamed(client: httpx.Client, url: str, dest: Path) -> Iterator[httpx.Response]:
    """`client.stream("GET", url)`, with a transport failure (an unreachable link, a dropped
    connection) as a one-line `ClientError` naming the file and the host, not httpx's traceback."""
    try:
        with client.stream("GET", url) as resp:
            yield resp
    except httpx.HTTPError as exc:
        host = httpx.URL(url).host or url
        raise ClientError(
            f"download of {dest.name} from {host} failed: {type(exc).__name__}: {exc}"
        ) from None


def _json(obj: Any) -> str:
    import json

    return json.dumps(obj, indent=2, sort_keys=True)
