"""One splat file through what the upload check does with it, minus the catch-all boundary,
with its peak memory measured: the property the reader corpus and the reader fuzz targets test.

Why without the boundary: `formats.READER_FAILURES` turns *any* exception of a reader into an
InputError at the upload, so a 500 can no longer happen there; but a TypeError or IndexError
turned into a 422 still means a reader followed a field it had not checked, and its message is
an exception's text rather than the field and what was expected. Called directly, a reader must
refuse a bad file itself, with an InputError naming the file.
"""

from __future__ import annotations

import tracemalloc
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

from bayesian_fields_core.checks.alignment import GEOMETRY_MAX_GAUSSIANS
from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.formats import open_source, read_splat, splat_format
from bayesian_fields_core.scene.formats.scan import scan_source
from bayesian_fields_core.scene.ply import DEFAULT_MAX_GAUSSIANS, read_ply, read_ply_elements

LIMIT = DEFAULT_MAX_GAUSSIANS
"""The readers run at the service's default limit, so a declared count up to 20 M is tried."""
MAX_PEAK_MIB = 150
"""Issue 30's bound on the memory checking any upload may take, whatever the file declares."""


@dataclass
class Peak:
    """Peak memory of a block: Python + numpy allocations (tracemalloc; numpy reports its
    buffers there) and resident-set growth (which also sees Pillow's and zstd's native buffers)."""

    traced_mib: float = 0.0
    rss_mib: float = 0.0
    measured: list[str] = field(default_factory=list)

    @property
    def mib(self) -> float:
        return max(self.traced_mib, self.rss_mib)


def _status_kib(key: str) -> int | None:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(key + ":"):
                return int(line.split()[1])
    except OSError:
        return None
    return None


def _reset_rss_peak() -> bool:
    """Reset the process's VmHWM to its current RSS (Linux `clear_refs` 5); False if refused."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
    except OSError:
        return False
    return _status_kib("VmHWM") is not None


@contextmanager
def peak_memory(*, traced: bool = True) -> Iterator[Peak]:
    """Measure the block's peak memory into the yielded `Peak` (tracemalloc only if `traced`)."""
    peak = Peak()
    rss = _reset_rss_peak()
    base = _status_kib("VmRSS") if rss else None
    if traced:
        tracemalloc.start()
    try:
        yield peak
    finally:
        if traced:
            peak.traced_mib = tracemalloc.get_traced_memory()[1] / 2**20
            tracemalloc.stop()
            peak.measured.append("tracemalloc")
        hwm = _status_kib("VmHWM") if rss else None
        if base is not None and hwm is not None:
            peak.rss_mib = (hwm - base) / 1024
            peak.measured.append("rss")


def read_strictly(path: Path, spill_dir: Path) -> None:
    """What `checks.upload` does with the splat (format from the name and header, then a
    bounded scan of every row, payloads spilled to `spill_dir`) with no catch-all boundary."""
    if path.name.lower().endswith(".ply"):
        read_ply_elements(path)  # the header parse `splat_format` runs under the boundary
    kind = splat_format(path)
    if kind == "ply":  # an INRIA PLY (a mutant lost the other layouts' properties)
        read_ply(path, max_gaussians=LIMIT)
        return
    with open_source(path, kind, max_gaussians=LIMIT, spill_dir=spill_dir) as source:
        scan_source(source, sample_size=GEOMETRY_MAX_GAUSSIANS)


@dataclass
class Outcome:
    loaded: bool
    message: str
    peak: Peak


def check_splat_file(path: Path, spill_dir: Path, *, traced: bool = True, whole: bool = True) -> Outcome:
    """Read `path` strictly; the outcome, or AssertionError when the property fails: a refusal
    is an InputError whose message starts with the file's path and says more, memory stays under
    `MAX_PEAK_MIB`, and (`whole`) a file the scan accepts also loads whole with `read_splat`.
    Any other exception propagates: that is the bug the caller reports."""
    message = ""
    with peak_memory(traced=traced) as peak:
        try:
            read_strictly(path, spill_dir)
        except InputError as exc:
            message = str(exc)
    assert peak.mib < MAX_PEAK_MIB, f"{path.name}: peak {peak.mib:.0f} MiB ({peak.measured})"
    if message:
        assert message.startswith(str(path)) and len(message) > len(str(path)) + 5, message
        return Outcome(False, message, peak)
    if whole:
        read_splat(path, max_gaussians=LIMIT)  # the pipeline's path; InputError here is a disagreement
    return Outcome(True, "", peak)
