"""Perception: class-agnostic segmenters and CLIP encoders behind two small protocols.

- ``segmenter.Segmenter`` (``classical``, ``fastsam``, ``onnx_segmenter``) -> exclusive labels;
- ``encoder.Encoder`` (``hf_clip``, ``onnx_clip``, ``open_clip_encoder``) -> unit embeddings;
- ``masks`` (exclusivity, boxes), ``crops`` (masked crops, one-batch embedding),
  ``registry`` (YAML model profiles, builders, cache fingerprint).

Submodules are imported on demand so that importing the package does not load torch.
"""
