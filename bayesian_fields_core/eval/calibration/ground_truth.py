"""Labelled CLIP scores from scenes with ground truth, for `bfields calibrate --scene`.

The likelihoods of METHOD step 3 need, per CLIP model, the mean score of irrelevant
(mask, task) pairs (mu0) and the mean and spread of relevant ones (mu1, s). A synthetic scene
knows which Gaussians belong to which task's objects, so every mask the real perception stage
produces can be labelled through the Gaussians it sees:

- positive: at least `positive_overlap` of the mask's visible Gaussians belong to the task's
  GT objects (the mask shows a relevant object, not just a sliver of one);
- negative, with `negatives="absent"` (the paper's recipe for mu0, Sec. 5): any mask scored
  against a task that has no object in the scene; with `negatives="unrelated"`: a mask none of
  whose Gaussians belongs to the task's objects (many more pairs, mostly easy background ones);
- anything in between is ambiguous and left out.

The masks and their Gaussians come from the pipeline's own `perceive` and `fuse` stages, so the
scores are exactly those the fusion will see with that model profile.
"""

from __future__ import annotations

import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.eval.regime import Regime, regime_models
from bayesian_fields_core.eval.synthetic import GroundTruth, load_ground_truth
from bayesian_fields_core.eval.synthetic.tasks import extra_absent_tasks
from bayesian_fields_core.fusion.likelihood import resolve_likelihood
from bayesian_fields_core.job.artifacts import RESULT_PREFIX
from bayesian_fields_core.job.factories import Job, local_job
from bayesian_fields_core.job.pipeline import run_stage
from bayesian_fields_core.job.store import get_arrays
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.perception.models import load_models
from bayesian_fields_core.results.reader import read_result

Negatives = Literal["absent", "unrelated"]

EXTRA_ABSENT_TASKS = 6
"""Absent tasks `bfields calibrate --scene` adds to each scene by default (`--absent-tasks`): the
suites hold one or two per scene, too few to fit the 'not found' threshold against
(docs/research/not-found-decision.md)."""

POSITIVE_OVERLAP = 0.5
"""Share of a mask's visible Gaussians inside a task's GT objects that makes a positive pair."""


def label_masks(
    gaussian_ids: np.ndarray,
    mask_ids: np.ndarray,
    n_masks: int,
    relevant: np.ndarray,
    positive_overlap: float,
) -> tuple[np.ndarray, np.ndarray]:
    """(positive, negative) bool arrays of shape (M, T) for one frame.

    `relevant` (N, T) bool says which Gaussians belong to a GT object of each task. The share of
    a mask's Gaussians that are relevant is a bincount per task, vectorized over masks.
    """
    n_tasks = relevant.shape[1]
    seen = np.bincount(mask_ids, minlength=n_masks).astype(np.float64)
    hits = np.zeros((n_masks, n_tasks))
    np.add.at(hits, mask_ids, relevant[gaussian_ids].astype(np.float64))
    share = np.divide(hits, seen[:, None], out=np.zeros_like(hits), where=seen[:, None] > 0)
    observed = seen[:, None] > 0
    return observed & (share >= positive_overlap), observed & (hits == 0)


@dataclass(frozen=True)
class TaskPeak:
    """One task of a scene with ground truth, as the full pipeline answers it with the "not found"
    rule off: whether the scene holds none of its objects, and its first answer's peak as a raw
    cosine score (the best view's score; None: no answer at all). Raw scores, not margins, so the
    'not found' threshold can be fitted in the margins of whichever likelihoods are fitted."""

    task: str
    absent: bool
    peak_score: float | None


@dataclass(frozen=True)
class SceneLabels:
    """What one scene gives the calibration: positive and negative (mask, task) scores, and each
    task's first-answer peak (`TaskPeak`)."""

    positive: np.ndarray
    negative: np.ndarray
    peaks: list[TaskPeak] = field(default_factory=list)


def scene_absent_tasks(gt: GroundTruth, n: int) -> list[str]:
    """`n` extra absent tasks for a scene with ground truth, by the suite's rule for absent tasks
    (`extra_absent_tasks`), seeded by the scene's seed (0 when its gt.json records none) and
    drawn from the kinds its layout uses (else those of its objects)."""
    if n <= 0:
        return []
    objects = [i for i in gt.instances if i.category == "object" and i.colour is not None]
    held = {(str(i.colour), i.kind) for i in objects}
    kinds = list(gt.spec.get("kinds") or sorted({i.kind for i in objects}))
    if not kinds:
        return []
    return extra_absent_tasks(int(gt.spec.get("seed", 0)), kinds, held, gt.task_texts, n)


def scene_scores(
    scene_dir: Path,
    models: Any,
    work_dir: Path,
    positive_overlap: float,
    max_frames: int | None = None,
    negatives: Negatives = "absent",
    extra_absent: int = 0,
    cache_dir: Path | None = None,
) -> SceneLabels:
    """Positive and negative scores of one scene, and its tasks' first-answer peaks (the
    pipeline's own stages, perceive -> fuse -> cluster at the default parameters).

    `extra_absent` more absent tasks (`scene_absent_tasks`) add negatives and first-answer peaks
    of absent tasks: the scene's own tasks are answered by a run with exactly those tasks (as
    every run of the scene answers them), the extra ones by a second run with the scene's tasks
    and the extra ones together (the perception and visibility caches are shared)."""
    gt = load_ground_truth(scene_dir)
    own = gt.task_texts
    if not own:
        raise InputError("ground truth lists no tasks", source=str(scene_dir / "gt.json"))
    extra = scene_absent_tasks(gt, extra_absent)
    tasks = own + extra
    absent = np.array([not task.objects for task in gt.tasks] + [True] * len(extra))
    relevant = np.zeros((len(gt.instance_ids), len(tasks)), dtype=bool)
    for t, task in enumerate(gt.tasks):
        ids = [o.instance_id for o in task.objects]
        relevant[:, t] = np.isin(gt.instance_ids, ids)

    params = PipelineParams(max_frames=max_frames, answer_min_peak=None)
    cache_root = work_dir / "cache" if cache_dir is None else cache_dir
    job = local_job(scene_dir, work_dir / "job", cache_root, own, params, models, cache_prefix="scene/cache/")
    cache, keys = job.spec.cache_store, job.scene.keys
    run_stage("perceive", job)
    run_stage("fuse", job)  # computes and caches the per-frame mask-to-Gaussian associations
    text = models.encoder.encode_texts(tasks).astype(np.float32)
    text /= np.linalg.norm(text, axis=1, keepdims=True)

    pos: list[np.ndarray] = []
    neg: list[np.ndarray] = []
    for index, _frame in job.scene.selected_frames:
        embeddings = get_arrays(cache, keys.perception_key(index))["embeddings"]
        if embeddings.shape[0] == 0:
            continue
        vis = get_arrays(cache, keys.visibility_key(index))
        emb = embeddings.astype(np.float32)
        emb /= np.maximum(np.linalg.norm(emb, axis=1, keepdims=True), 1e-12)
        scores = emb @ text.T
        is_pos, is_neg = label_masks(
            vis["gaussian_ids"].astype(np.int64),
            vis["mask_ids"].astype(np.int64),
            emb.shape[0],
            relevant,
            positive_overlap,
        )
        if negatives == "absent":
            seen = np.bincount(vis["mask_ids"].astype(np.int64), minlength=emb.shape[0]) > 0
            is_neg = seen[:, None] & absent[None, :]
        pos.append(scores[is_pos])
        neg.append(scores[is_neg])
    peaks = first_answer_peaks(job, [not task.objects for task in gt.tasks])
    if extra:
        with_extra = local_job(
            scene_dir, work_dir / "job-absent", cache_root, tasks, params, models, cache_prefix="scene/cache/"
        )
        run_stage("fuse", with_extra)
        peaks += first_answer_peaks(with_extra, [False] * len(own) + [True] * len(extra))[len(own) :]
    return SceneLabels(np.concatenate(pos or [np.zeros(0)]), np.concatenate(neg or [np.zeros(0)]), peaks)


def first_answer_peaks(job: Job, absent: list[bool]) -> list[TaskPeak]:
    """Run the cluster stage (rule off) and read each task's first answer's peak, as a raw
    cosine score: the stored peaks are margins of the profile's likelihoods, turned back into
    scores here (`phi = mu0 + margin (mu1 - mu0)`, exact: the object peak is a median of a
    linear function)."""
    run_stage("cluster", job)
    result = read_result(job.spec.store, RESULT_PREFIX)
    likelihood = resolve_likelihood(job.spec.params, job.runner.models.calibration)
    peaks = []
    for task, is_absent in zip(job.spec.tasks, absent, strict=True):
        answers = result.selections.get(task, [])
        margin = answers[0].peak if answers else None
        score = None if margin is None else likelihood.mu0 + margin * (likelihood.mu1 - likelihood.mu0)
        peaks.append(TaskPeak(task, is_absent, score))
    return peaks


def collect_scores(
    scene_dirs: list[Path],
    profile: str | None,
    *,
    positive_overlap: float = POSITIVE_OVERLAP,
    max_frames: int | None = None,
    negatives: Negatives = "absent",
    regime: Regime = "strong",
    extra_absent: int = 0,
    cache_dir: Path | None = None,
) -> tuple[SceneLabels, str]:
    """(the scenes' labels pooled, encoder model id) over scenes with ground truth; `regime`
    "realistic" scores the evaluation's weak-evidence embeddings (`eval/regime.py`);
    `extra_absent` more absent tasks per scene (`scene_scores`); `cache_dir` keeps the
    perception cache between calls (default: a temporary one)."""
    if not 0.0 < positive_overlap <= 1.0:
        raise InputError(f"positive_overlap must be in (0, 1], got {positive_overlap}")
    models = regime_models(load_models(profile), regime)
    scenes = []
    with tempfile.TemporaryDirectory(prefix="bfields-calibrate-") as tmp:
        for n, scene_dir in enumerate(scene_dirs):
            scenes.append(
                scene_scores(
                    Path(scene_dir),
                    models,
                    Path(tmp) / str(n),
                    positive_overlap,
                    max_frames,
                    negatives,
                    extra_absent=extra_absent,
                    cache_dir=cache_dir,
                )
            )
    pooled = SceneLabels(
        np.concatenate([s.positive for s in scenes]),
        np.concatenate([s.negative for s in scenes]),
        [peak for s in scenes for peak in s.peaks],
    )
    return pooled, str(models.encoder.model_id)
