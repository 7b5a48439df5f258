"""CLIP towers through onnxruntime (no PyTorch at inference).

Folder layout and I/O contract: see :mod:`bayesian_fields_core.perception.onnx_export` (which
writes it). The image model's first input takes ``(B, 3, S, S)`` float32 pixel values
preprocessed as in ``clip_inputs``; the text model takes ``input_ids`` and, when it declares one,
``attention_mask`` (int64). Each model's first output is the ``(B, D)`` projected embedding; we
L2-normalise it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from bayesian_fields_core.errors import ModelError
from bayesian_fields_core.perception.clip_inputs import ClipImagePreprocessor, ClipTokenizer, ResizeMode
from bayesian_fields_core.perception.digest import files_digest
from bayesian_fields_core.perception.encoder import l2_normalize
from bayesian_fields_core.perception.onnx_export import IMAGE_MODEL, TEXT_MODEL


def onnx_session(path: Path, providers: list[str] | None, threads: int = 0) -> Any:
    """An onnxruntime session for ``path`` (ModelError when onnxruntime or the file is missing)."""
    try:
        import onnxruntime as ort
    except ImportError as exc:
        raise ModelError("onnxruntime is not installed: install the 'onnx' extra") from exc
    if not path.is_file():
        raise ModelError(f"{path}: ONNX model file not found")
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    try:
        return ort.InferenceSession(str(path), options, providers=providers or ["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own untyped errors for bad files
        raise ModelError(f"{path}: cannot load ONNX model ({exc})") from exc


def onnx_clip_model_id(path: str | Path, image_model: str = IMAGE_MODEL, text_model: str = TEXT_MODEL) -> str:
    """``"<folder name>@<12 hex of both ONNX files' sha256>"`` (see ``hf_clip_model_id``)."""
    folder = Path(path)
    return f"{folder.resolve().name}@{files_digest([folder / image_model, folder / text_model])}"


class OnnxClipEncoder:
    """Separate image and text ONNX models + the tokenizer folder as an ``Encoder``.

    Parameters: ``path`` (folder with both models, tokenizer and ``preprocessor_config.json``),
    ``image_model``/``text_model`` (file names inside it), ``providers`` (onnxruntime execution
    providers, default CPU), ``threads`` (intra-op threads, 0 = onnxruntime's default),
    ``resize_mode``.
    """

    kind = "onnx"

    def __init__(
        self,
        path: str | Path,
        *,
        image_model: str = IMAGE_MODEL,
        text_model: str = TEXT_MODEL,
        providers: list[str] | None = None,
        threads: int = 0,
        resize_mode: ResizeMode = "shortest_crop",
    ) -> None:
        self.path = Path(path)
        image_path, text_path = self.path / image_model, self.path / text_model
        self._image = onnx_session(image_path, providers, threads)
        self._text = onnx_session(text_path, providers, threads)
        self.model_id = onnx_clip_model_id(self.path, image_model, text_model)
        self.preprocess = ClipImagePreprocessor.from_folder(self.path, resize_mode)
        self.tokenizer = ClipTokenizer(self.path)
        self._image_input = self._image.get_inputs()[0].name
        self._text_inputs = {i.name for i in self._text.get_inputs()}
        if "input_ids" not in self._text_inputs:
            raise ModelError(f"{text_path}: text model has no 'input_ids' input")
        dim = self._image.get_outputs()[0].shape[-1]
        self.dim = int(dim) if isinstance(dim, int) else int(self.encode_texts([""]).shape[1])

    @property
    def params(self) -> dict[str, Any]:
        """Settings that change the embeddings (for the cache fingerprint)."""
        return {"resize_mode": self.preprocess.mode}

    def encode_images(self, images: list[np.ndarray]) -> np.ndarray:
        """Uint8 RGB images -> ``(M, D)`` float32 unit rows, one session run."""
        if len(images) == 0:
            return np.zeros((0, self.dim), dtype=np.float32)
        (emb, *_) = self._image.run(None, {self._image_input: self.preprocess(images)})
        return l2_normalize(emb)

    def encode_texts(self, texts: list[str]) -> np.ndarray:
        """Texts -> ``(T, D)`` float32 unit rows."""
        if len(texts) == 0:
            return np.zeros((0, getattr(self, "dim", 0)), dtype=np.float32)
        enc = self.tokenizer(texts)
        feeds = {k: v for k, v in enc.items() if k in self._text_inputs}
        (emb, *_) = self._text.run(None, feeds)
        return l2_normalize(emb)
