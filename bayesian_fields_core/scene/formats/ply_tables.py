"""The elements of a binary PLY as record tables, for the PLY-based formats other than INRIA's.

Why: the compressed and RGB PLY readers both need each element's rows at a known offset, with
the file checked to hold every declared row before any is read (a header can declare any
count). Elements are stored one after another, so an element's offset is the sum of the sizes
of those before it; element counts are bounded by the reader before their tables are used.
"""

from __future__ import annotations

from pathlib import Path
from typing import BinaryIO

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.scene.formats.source import RecordTable

BYTE_ORDER = {"binary_little_endian": "<", "binary_big_endian": ">"}


def element_tables(
    f: BinaryIO, path: Path, fmt: str, elements: list[tuple[str, int, list]], offset: int, *, formats: str
) -> dict[str, RecordTable]:
    """One `RecordTable` per element of a binary PLY (`formats`: what the reader calls the file,
    for messages). InputError for ASCII, list properties or a body shorter than declared."""
    if fmt not in BYTE_ORDER:
        raise InputError(f"{formats} must be binary, not {fmt}", source=str(path))
    order = BYTE_ORDER[fmt]
    check_unique(path, elements, formats=formats)
    tables: dict[str, RecordTable] = {}
    for name, count, props in elements:
        if any(p[1] == "list" for p in props):
            raise InputError(f"element {name!r} has list properties; a splat has none", source=str(path))
        dtype = np.dtype([(p[0], order + p[1]) for p in props])
        tables[name] = RecordTable(f, offset, dtype, count, what=f"{name!r} data", source=path)
        offset += dtype.itemsize * count
    return tables


def check_unique(path: Path, elements: list[tuple[str, int, list]], *, formats: str) -> None:
    """Refuse an element named twice or a property named twice within an element. Why: a
    reader looks elements and properties up by name (the second `vertex` or `min_x` would be
    silently ignored, or numpy refuses the record type with a ValueError far from the header)."""
    names = [name for name, _, _ in elements]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise InputError(f"{formats} header declares element {twice[0]!r} more than once", source=str(path))
    for name, _, props in elements:
        props_named = [p[0] for p in props]
        again = sorted({n for n in props_named if props_named.count(n) > 1})
        if again:
            raise InputError(
                f"{formats} element {name!r} declares property {again[0]!r} more than once", source=str(path)
            )
