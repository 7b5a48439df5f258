"""The parts of a glTF 2.0 document the splat reader uses, as typed, bounded models.

Strict on purpose: an index given as the string "0", a count of 21650.5, a list where an object
belongs or a primitive that is a number are refused here, naming the field, before the reader
follows any index. Offsets, lengths and counts are non-negative integers; the reader then checks
that every accessor it reads fits its buffer view and every view its buffer.
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, Field

from bayesian_fields_core.scene.formats.typed_json import STRICT

Index = Annotated[int, Field(ge=0)]


class Accessor(BaseModel):
    model_config = STRICT
    bufferView: Index  # noqa: N815 - glTF's key names
    byteOffset: Index = 0  # noqa: N815
    componentType: int  # noqa: N815
    count: Annotated[int, Field(ge=1)]
    type: str
    normalized: bool = False


class BufferView(BaseModel):
    model_config = STRICT
    buffer: Index
    byteOffset: Index = 0  # noqa: N815
    byteLength: Index  # noqa: N815
    byteStride: Annotated[int, Field(ge=4, le=252)] | None = None  # noqa: N815 - the spec's range


class Buffer(BaseModel):
    model_config = STRICT
    uri: Annotated[str, Field(min_length=1)] | None = None
    byteLength: Index  # noqa: N815


class Primitive(BaseModel):
    model_config = STRICT
    attributes: dict[str, Index]
    extensions: dict[str, Any] | None = None


class Mesh(BaseModel):
    model_config = STRICT
    primitives: list[Primitive]


class GltfDocument(BaseModel):
    """A glTF document's meshes, accessors, buffer views and buffers (the rest is ignored)."""

    model_config = STRICT
    meshes: list[Mesh] = []
    accessors: list[Accessor] = []
    bufferViews: list[BufferView] = []  # noqa: N815
    buffers: list[Buffer] = []
