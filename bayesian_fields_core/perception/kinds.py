"""The model kinds a profile can name: one class per kind (see ``kind_base``).

Each class types the kind's ``params`` (the model class's keyword arguments; unset ones take that
class's defaults), builds the model, and, for an encoder, computes its ``model_id`` from its files
without loading it. Model modules are imported inside ``build`` / ``model_id`` so that reading a
profile or fingerprinting it does not import torch, ultralytics or onnxruntime.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field

from bayesian_fields_core.perception.classical import Method
from bayesian_fields_core.perception.clip_inputs import ResizeMode
from bayesian_fields_core.perception.encoder import Encoder
from bayesian_fields_core.perception.kind_base import (
    ENCODERS,
    SEGMENTERS,
    EncoderConfig,
    KindParams,
    ModelFile,
    Runtime,
    SegmenterConfig,
)
from bayesian_fields_core.perception.segmenter import Segmenter


@SEGMENTERS.register
class ClassicalKind(SegmenterConfig):
    """Felzenszwalb or SLIC superpixels (``perception/classical.py``); no model files."""

    class Params(KindParams):
        method: Method | None = None
        scale: float | None = None
        sigma: float | None = None
        min_size: int | None = None
        n_segments: int | None = None
        compactness: float | None = None
        min_area: int | None = None
        max_side: int | None = None  # null: segment at full resolution

    kind: Literal["classical"] = "classical"
    params: Params = Field(default_factory=Params)

    def build(self, *, device: str | None = None) -> Segmenter:
        from bayesian_fields_core.perception.classical import ClassicalSegmenter

        return ClassicalSegmenter(**self.params.kwargs())

    def identity(self) -> dict[str, Any]:
        # Built (cheap) so that an explicit default and an omitted one fingerprint alike.
        return {"kind": self.kind, "params": self.build().params}


@SEGMENTERS.register
class FastSAMKind(SegmenterConfig):
    """FastSAM through ultralytics (``perception/fastsam.py``, extra ``fastsam``)."""

    class Params(KindParams):
        weights: ModelFile  # the FastSAM .pt file
        conf: float | None = None
        iou: float | None = None
        imgsz: int | None = None
        retina_masks: bool | None = None
        device: Runtime[str | None] = None
        min_area: int | None = None
        threshold: float | None = None
        half: bool | None = None

    kind: Literal["fastsam"] = "fastsam"
    params: Params

    def build(self, *, device: str | None = None) -> Segmenter:
        from bayesian_fields_core.perception.fastsam import FastSAMSegmenter

        kwargs = self.params.kwargs() | ({"device": device} if device is not None else {})
        return FastSAMSegmenter(**kwargs)


@SEGMENTERS.register
class OnnxSegmenterKind(SegmenterConfig):
    """A segmenter exported to ONNX (``perception/onnx_segmenter.py``, extra ``onnx``)."""

    class Params(KindParams):
        path: ModelFile  # the .onnx file
        input_size: int | tuple[int, int] | None = None
        threshold: float | None = None
        mask_output: Literal["probabilities", "logits"] | None = None
        score_threshold: float | None = None
        min_area: int | None = None
        providers: Runtime[list[str] | None] = None
        threads: Runtime[int | None] = None

    kind: Literal["onnx"] = "onnx"
    params: Params

    def build(self, *, device: str | None = None) -> Segmenter:
        from bayesian_fields_core.perception.onnx_segmenter import OnnxSegmenter

        return OnnxSegmenter(**self.params.kwargs())


@ENCODERS.register
class HFClipKind(EncoderConfig):
    """A transformers ``CLIPModel`` folder (``perception/hf_clip.py``)."""

    class Params(KindParams):
        resize_mode: ResizeMode | None = None
        max_batch: Runtime[int | None] = None
        dtype: Literal["float32", "float16", "bfloat16"] | None = None

    kind: Literal["hf_clip"] = "hf_clip"
    params: Params = Field(default_factory=Params)

    def build(self, *, device: str | None = None) -> Encoder:
        from bayesian_fields_core.perception.hf_clip import HFClipEncoder

        return HFClipEncoder(self.path, device=device or self.device, **self.params.kwargs())

    def model_id(self) -> str:
        from bayesian_fields_core.perception.hf_clip import hf_clip_model_id

        return hf_clip_model_id(self.path)


@ENCODERS.register
class OnnxClipKind(EncoderConfig):
    """CLIP image and text towers as ONNX files in one folder (``perception/onnx_clip.py``)."""

    class Params(KindParams):
        image_model: str | None = None  # file names inside the folder
        text_model: str | None = None
        providers: Runtime[list[str] | None] = None
        threads: Runtime[int | None] = None
        resize_mode: ResizeMode | None = None

    kind: Literal["onnx"] = "onnx"
    params: Params = Field(default_factory=Params)

    def build(self, *, device: str | None = None) -> Encoder:
        from bayesian_fields_core.perception.onnx_clip import OnnxClipEncoder

        return OnnxClipEncoder(self.path, **self.params.kwargs())

    def model_id(self) -> str:
        from bayesian_fields_core.perception.onnx_clip import onnx_clip_model_id

        towers = self.params.model_dump(include={"image_model", "text_model"}, exclude_none=True)
        return onnx_clip_model_id(self.path, **towers)


@ENCODERS.register
class OpenClipKind(EncoderConfig):
    """An open_clip checkpoint file (``perception/open_clip_encoder.py``, extra ``open_clip``)."""

    class Params(KindParams):
        model_name: str  # the architecture, e.g. ViT-B-16

    kind: Literal["open_clip"] = "open_clip"
    params: Params

    def build(self, *, device: str | None = None) -> Encoder:
        from bayesian_fields_core.perception.open_clip_encoder import OpenClipEncoder

        return OpenClipEncoder(self.params.model_name, self.path, device=device or self.device)

    def model_id(self) -> str:
        from bayesian_fields_core.perception.open_clip_encoder import open_clip_model_id

        return open_clip_model_id(self.params.model_name, self.path)
