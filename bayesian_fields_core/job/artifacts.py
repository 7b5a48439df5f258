"""Names of the artifacts the stages hand to each other, in one place.

A stage reads and writes named artifacts through a `Store` (METHOD: a job resumes from the last
finished stage); the worker, the CLI, the viewer and the evaluation read the same names, so
they are written once, here. Job artifacts are relative to the job's prefix (`JobSpec.key`);
cache folders are relative to the cache root (`JobSpec.cache_prefix`).
"""

from __future__ import annotations

FUSION_KEY = "fusion/gaussian_probabilities.npz"
"""`fuse` output: (N, T) probabilities and log-odds of every Gaussian for every task."""

ACCEPTED_KEY = "fusion/accepted_masks.npz"
"""`fuse` output: per-frame mask counts and OR-phi acceptance flags, read by `cluster`."""

PRIMITIVES_KEY = "fusion/primitive_ids.npz"
"""`fuse` output: (N,) primitive of every Gaussian (METHOD step 6), built frame by frame while the
associations are in memory, so `cluster` need not read every frame's associations again."""

RESULT_PREFIX = "result/"
"""`cluster` output: the result folder (`results/format.py` names the files inside it)."""

MARKER_DIR = "stages/"
"""A finished stage's marker, `stages/<stage>.json` (its report)."""

PERCEPTION_CACHE_DIR = "perception/"
"""Per-frame masks and embeddings, `perception/<models>/<image digest>.npz`."""

VISIBILITY_CACHE_DIR = "visibility/"
"""Per-frame mask-to-Gaussian associations, `visibility/<models>/<digest>.npz`."""

ALIGNMENT_CACHE_DIR = "alignment/"
"""Verdicts of the alignment check (`checks/alignment.py`), `alignment/<digest>.json`: the check
renders and reads photos, so a warm re-run of the same scene reuses its report."""
