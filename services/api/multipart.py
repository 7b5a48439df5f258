"""Streaming multipart/form-data receiver with a hard size limit.

Starlette's `request.form()` spools a whole request before the handler sees it and has no total
size cap, so a client could fill the API's disk with one request. Here the raw body is fed
chunk by chunk to python-multipart's push parser and every file part is written straight to a
temp folder; the byte count is checked on every chunk and the request is refused with 413 (naming
the limit) the moment it passes `max_bytes`. The handler then works on plain files.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING

from fastapi import HTTPException, Request, status
from python_multipart import MultipartParser
from python_multipart.multipart import parse_options_header

from bayesian_fields_core.errors import InputError
from bayesian_fields_service.scenes.intake import clean_filename

if TYPE_CHECKING:
    from python_multipart.multipart import MultipartCallbacks

MAX_FIELD_BYTES = 64 * 1024
MAX_PARTS = 20_000


@dataclass
class ReceivedFile:
    """One uploaded file part, already on disk."""

    field: str
    filename: str
    path: Path
    size: int = 0


@dataclass
class ReceivedForm:
    fields: dict[str, str] = field(default_factory=dict)
    files: list[ReceivedFile] = field(default_factory=list)

    def files_of(self, name: str) -> list[ReceivedFile]:
        return [f for f in self.files if f.field == name]


def too_large(limit: int) -> HTTPException:
    return HTTPException(
        status_code=status.HTTP_413_REQUEST_ENTITY_TOO_LARGE,
        detail=f"upload exceeds the limit of {limit} bytes (BFIELDS_MAX_UPLOAD_BYTES)",
    )


class _Receiver:
    """python-multipart callbacks that route each part to a file or a small text buffer."""

    def __init__(self, tmp_dir: Path) -> None:
        self.tmp_dir = tmp_dir
        self.form = ReceivedForm()
        self._headers: dict[bytes, bytes] = {}
        self._hname = b""
        self._hvalue = b""
        self._name = ""
        self._text: bytearray | None = None
        self._file: ReceivedFile | None = None
        self._fh: IO[bytes] | None = None

    def callbacks(self) -> MultipartCallbacks:
        return {
            "on_part_begin": self._part_begin,
            "on_header_field": lambda d, s, e: self._append("_hname", d[s:e]),
            "on_header_value": lambda d, s, e: self._append("_hvalue", d[s:e]),
            "on_header_end": self._header_end,
            "on_headers_finished": self._headers_finished,
            "on_part_data": self._part_data,
            "on_part_end": self._part_end,
        }

    def _append(self, attr: str, data: bytes) -> None:
        setattr(self, attr, getattr(self, attr) + data)

    def _part_begin(self) -> None:
        self._headers = {}
        self._hname = self._hvalue = b""

    def _header_end(self) -> None:
        self._headers[self._hname.lower()] = self._hvalue
        self._hname = self._hvalue = b""

    def _headers_finished(self) -> None:
        _, opts = parse_options_header(self._headers.get(b"content-disposition", b""))
        self._name = opts.get(b"name", b"").decode("utf-8", "replace")
        filename = opts.get(b"filename")
        if len(self.form.files) + len(self.form.fields) >= MAX_PARTS:
            raise InputError(f"more than {MAX_PARTS} form parts", source="multipart")
        if filename is None:
            self._text = bytearray()
            return
        name = clean_filename(filename.decode("utf-8", "replace"), field_name=self._name or "file")
        path = self.tmp_dir / f"part-{len(self.form.files):05d}"
        self._file = ReceivedFile(self._name, name, path)
        self._fh = path.open("wb")

    def _part_data(self, data: bytes, start: int, end: int) -> None:
        if self._fh is not None and self._file is not None:
            self._fh.write(data[start:end])
            self._file.size += end - start
        elif self._text is not None:
            self._text += data[start:end]
            if len(self._text) > MAX_FIELD_BYTES:
                raise InputError(f"form field longer than {MAX_FIELD_BYTES} bytes", source=self._name)

    def _part_end(self) -> None:
        if self._fh is not None and self._file is not None:
            self._fh.close()
            self.form.files.append(self._file)
        elif self._text is not None:
            self.form.fields[self._name] = self._text.decode("utf-8", "replace")
        self._fh, self._file, self._text = None, None, None

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()


async def receive_multipart(request: Request, tmp_dir: Path, *, max_bytes: int) -> ReceivedForm:
    """Parse the request body into `tmp_dir`; 413 past `max_bytes`, 400/415 when malformed."""
    ctype, opts = parse_options_header(request.headers.get("content-type", ""))
    if ctype != b"multipart/form-data" or b"boundary" not in opts:
        raise HTTPException(
            status.HTTP_415_UNSUPPORTED_MEDIA_TYPE, "expected multipart/form-data with a boundary"
        )
    declared = request.headers.get("content-length")
    if declared is not None and declared.isdigit() and int(declared) > max_bytes:
        raise too_large(max_bytes)
    tmp_dir.mkdir(parents=True, exist_ok=True)
    receiver = _Receiver(tmp_dir)
    parser = MultipartParser(opts[b"boundary"], receiver.callbacks())
    received = 0
    try:
        async for chunk in request.stream():
            received += len(chunk)
            if received > max_bytes:
                raise too_large(max_bytes)
            parser.write(chunk)
        parser.finalize()
    except InputError:
        raise
    except HTTPException:
        raise
    except Exception as exc:  # python-multipart raises its own error types for malformed bodies
        raise HTTPException(status.HTTP_400_BAD_REQUEST, f"malformed multipart body: {exc}") from None
    finally:
        receiver.close()
    return receiver.form
