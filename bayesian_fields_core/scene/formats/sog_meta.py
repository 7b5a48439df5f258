"""SOG v2 `meta.json` as typed, bounded models (the layout is described in `formats.sog`).

Every field `sog.py` uses is validated here first: the count a positive integer, `mins` / `maxs`
three finite numbers each (and mins <= maxs), each codebook exactly 256 finite numbers, file
names short strings of the right number. Unknown keys (`asset`, `shN`, future ones) are ignored.
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, Field, model_validator

from bayesian_fields_core.scene.formats.typed_json import STRICT

Finite = Annotated[float, Field(allow_inf_nan=False)]
FileName = Annotated[str, Field(min_length=1, max_length=255)]
CODEBOOK_SIZE = 256
"""Entries of a SOG codebook: one per byte value."""


class MeansEntry(BaseModel):
    """Positions: two 8-bit images (lower and upper bytes) of values lerped in [mins, maxs]."""

    model_config = STRICT
    mins: Annotated[list[Finite], Field(min_length=3, max_length=3)]
    maxs: Annotated[list[Finite], Field(min_length=3, max_length=3)]
    files: Annotated[list[FileName], Field(min_length=2, max_length=2)]

    @model_validator(mode="after")
    def _ordered(self) -> MeansEntry:
        if any(lo > hi for lo, hi in zip(self.mins, self.maxs, strict=True)):
            raise ValueError("mins must not exceed maxs")
        return self


class CodebookEntry(BaseModel):
    """Scales or colours: one image whose bytes index a 256-entry codebook."""

    model_config = STRICT
    codebook: Annotated[list[Finite], Field(min_length=CODEBOOK_SIZE, max_length=CODEBOOK_SIZE)]
    files: Annotated[list[FileName], Field(min_length=1, max_length=1)]


class ImageEntry(BaseModel):
    """Rotations: one image, no codebook."""

    model_config = STRICT
    files: Annotated[list[FileName], Field(min_length=1, max_length=1)]


class SogMeta(BaseModel):
    """The fields of a version-2 meta.json this reader uses."""

    model_config = STRICT
    version: int
    count: Annotated[int, Field(ge=1)]
    means: MeansEntry
    scales: CodebookEntry
    quats: ImageEntry
    sh0: CodebookEntry
    shN: Any = None  # noqa: N815 - the format's key; higher bands, dropped (see formats.sog)

    def images(self) -> dict[str, str]:
        """Block name -> image file, for the five images the reader decodes."""
        return {
            "means_l": self.means.files[0],
            "means_u": self.means.files[1],
            "scales": self.scales.files[0],
            "quats": self.quats.files[0],
            "sh0": self.sh0.files[0],
        }
