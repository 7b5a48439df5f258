"""Every splat reader against a corpus of its fixtures mutated field by field (issue 30, item 2):
each mutant loads, or is refused with an InputError naming the file and the problem, never any
other exception; and reading it takes less than `reader_check.MAX_PEAK_MIB` whatever it declares.

The corpus (`splat_mutations`) is deterministic: every JSON field of a glTF document and a SOG
meta.json replaced by each wrong type, every header field of SPZ (gzip and zstd) and compressed
PLY at boundary values, members and payloads cut, swapped, extended or lying about their size.
One test per family collects every failing mutant, so one run lists them all.
"""

from __future__ import annotations

import tempfile
import traceback
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from . import splat_mutations as sm
from .reader_check import check_splat_file

FAMILIES: dict[str, Callable[[Path], Iterator[sm.Mutant]]] = {
    "gltf-sh3": lambda tmp: sm.gltf_mutants("sh3.glb"),
    "glb-tabletop": lambda tmp: sm._glb_container_mutants(
        "tabletop.glb", (sm.FIXTURES / "tabletop.glb").read_bytes()
    ),
    "sog-tabletop": lambda tmp: sm.sog_mutants("tabletop.sog"),
    "spz-v3-gzip": lambda tmp: sm.spz_gzip_mutants("tabletop.v3.spz"),
    "spz-v4-zstd": lambda tmp: sm.spz_v4_mutants("tabletop.spz"),
    "spz-v4-sh3": lambda tmp: sm.spz_v4_mutants("sh3.spz"),
    "compressed-ply-tabletop": lambda tmp: sm.compressed_ply_mutants("tabletop.compressed.ply"),
    "compressed-ply-sh3": lambda tmp: sm.compressed_ply_mutants("sh3.compressed.ply"),
    "rgb-ply": sm.rgb_ply_mutants,
    "antimatter-splat": sm.antimatter_mutants,
    "bombs": sm.bomb_mutants,
}


def write_mutant(mutant: sm.Mutant, folder: Path) -> Path:
    folder.mkdir(parents=True)
    for name, data in mutant.files.items():
        (folder / name).parent.mkdir(parents=True, exist_ok=True)
        (folder / name).write_bytes(data)
    return folder / mutant.entry


def run_family(mutants: Iterator[sm.Mutant], tmp: Path) -> tuple[int, int, list[str]]:
    """(mutants, loaded, failures) for one family; a failure names the mutant and what broke."""
    total = loaded = 0
    failures: list[str] = []
    for i, mutant in enumerate(mutants):
        total += 1
        folder = tmp / f"m{i}"
        path = write_mutant(mutant, folder)
        try:
            loaded += check_splat_file(path, folder).loaded
        except Exception as exc:  # noqa: BLE001 - the test reports every escaping exception
            where = traceback.extract_tb(exc.__traceback__)[-1]
            failures.append(
                f"{mutant.name}: {type(exc).__name__}: {str(exc)[:160]} "
                f"({Path(where.filename).name}:{where.lineno})"
            )
        for p in sorted(folder.rglob("*"), reverse=True):
            p.rmdir() if p.is_dir() else p.unlink()
    return total, loaded, failures


@pytest.mark.parametrize("family", list(FAMILIES))
@pytest.mark.slow
def test_mutants_load_or_are_refused_in_bounded_memory(family: str, tmp_path: Path) -> None:
    total, loaded, failures = run_family(FAMILIES[family](tmp_path), tmp_path)
    print(f"{family}: {total} mutants, {loaded} loaded, {total - loaded} refused")
    assert not failures, f"{len(failures)} of {total} mutants broke a reader:\n" + "\n".join(failures)
    assert total >= 8 and 0 < loaded < total, (total, loaded)


def _by_name(mutants: Iterator[sm.Mutant], name: str) -> sm.Mutant:
    return next(m for m in mutants if m.name == name)


def _zip_patched(offset_in_central: int, fmt: str, value: int) -> sm.Mutant:
    import struct

    data = bytearray((sm.FIXTURES / "tabletop.sog").read_bytes())
    struct.pack_into(fmt, data, data.find(b"PK\x01\x02") + offset_in_central, value)
    return sm.Mutant("patched zip", {"splat.sog": bytes(data)}, "splat.sog")


def _local_name_not_utf8() -> sm.Mutant:
    """The first member's local header flags its name UTF-8 (bit 11) and the name is not."""
    import struct

    data = bytearray((sm.FIXTURES / "tabletop.sog").read_bytes())
    at = data.find(b"PK\x03\x04")
    (flags,) = struct.unpack_from("<H", data, at + 6)
    struct.pack_into("<H", data, at + 6, flags | 0x800)
    data[at + 30] = 0xFF
    return sm.Mutant("zip local name not utf-8", {"splat.sog": bytes(data)}, "splat.sog")


REGRESSIONS: list[tuple[str, Callable[[], sm.Mutant], str]] = [
    ("gltf uri too long for the filesystem (OSError ENAMETOOLONG)",
     lambda: _by_name(sm.gltf_mutants("sh3.glb"), f"sh3.gltf uri={'x' * 40!r}"),
     "buffers[0].uri names 'xxxx"),
    ("spz gzip deflate data that does not decode (zlib.error)",
     lambda: _by_name(sm.spz_gzip_mutants("tabletop.v3.spz"), "tabletop.v3.spz gzip body garbage"),
     "corrupt SPZ gzip stream"),
    ("sog member with a wrong CRC (BadZipFile)", lambda: _zip_patched(16, "<I", 0), "SOG member 'means_l.webp' cannot be read"),
    ("sog member of an unknown method (NotImplementedError)", lambda: _zip_patched(10, "<H", 99),
     "SOG member 'means_l.webp' cannot be read"),
    ("sog member whose local header is past the end (BadZipFile)", lambda: _zip_patched(42, "<I", 2**31),
     "SOG member 'means_l.webp' cannot be read"),
    ("sog zip whose directory offset is past the end (OSError from seek)",
     lambda: _by_name(sm.sog_mutants(), "tabletop.sog zip end record directory offset=huge"),
     "SOG member 'meta.json' cannot be read"),
    ("sog member whose local name is flagged UTF-8 and is not (UnicodeDecodeError; found by the fuzz target)",
     _local_name_not_utf8, "cannot be read"),
    ("compressed PLY property declared twice (numpy ValueError)",
     lambda: _by_name(sm.compressed_ply_mutants("tabletop.compressed.ply"), "tabletop.compressed.ply line 23 doubled"),
     "element 'vertex' declares property 'packed_position' more than once"),
    ("RGB PLY vertex element declared twice (KeyError)",
     lambda: _by_name(sm.rgb_ply_mutants(Path(tempfile.mkdtemp())), "rgb.ply line 2 doubled"),
     "declares element 'vertex' more than once"),
]  # fmt: skip
"""One case per reader bug the corpus found: what escaped before, and what the refusal says now."""


@pytest.mark.parametrize(("label", "build", "expected"), REGRESSIONS, ids=[r[0] for r in REGRESSIONS])
@pytest.mark.slow
def test_reader_bugs_the_corpus_found_are_refused_naming_the_problem(
    label: str, build: Callable[[], sm.Mutant], expected: str, tmp_path: Path
) -> None:
    path = write_mutant(build(), tmp_path / "case")
    outcome = check_splat_file(path, tmp_path / "case")
    assert not outcome.loaded and expected in outcome.message, (label, outcome.message)
