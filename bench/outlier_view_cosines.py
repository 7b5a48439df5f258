"""Are the outlier dial's views the paper's Fig. 2b outliers? (issue 46 item 4, checked before
the sweep is read; docs/research/ablation-decision.md.)

On public capture scenes with the dial at S > 0, realistic regime, the full method's run (the
sweep's own, bench/orphi_dial.py, read from its run folder; run afresh only where missing): every mask of a frame is given to the GT instance
holding >= 50 % of the Gaussians associated with it (as bench/no_candidate_trace.py does). For
masks of task objects (answers of a present task):

- ordinary views (frames the dial did not replace): the cosine to the object's own tasks
  (relevant) and to the scene's other tasks (irrelevant), and the share OR-phi rejected
  (`fusion.bayes.accepted_masks`, as the fuse stage stored its flags);
- outlier views, per kind (near, far, occluded): the same for the masks of the view's object,
  and how many views have no mask of their object at all (nothing to reject: the view gives the
  object no measurement).

Cosines are the regime's (`eval/regime.py`), beside its likelihoods' mu0 / mu1. Nothing here is
tuned against the sweep's result.

Usage: PYTHONPATH=$PWD python bench/outlier_view_cosines.py --share 0.45 --scenes 10 \\
    --suite-dir bench/_generated/suite-dial --runs bench/_generated/dial-runs \\
    --cache bench/_generated/dial-runs/cache \\
    --out bench/results/ablation-20261207/outlier-view-cosines
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from bayesian_fields_core.eval.regime import regime_models
from bayesian_fields_core.eval.suite import FULL, prepare_scenes, row_folder_name
from bayesian_fields_core.eval.synthetic.ground_truth import load_ground_truth
from bayesian_fields_core.job.artifacts import ACCEPTED_KEY
from bayesian_fields_core.job.factories import local_job
from bayesian_fields_core.job.pipeline import run_job
from bayesian_fields_core.job.store import get_arrays
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.perception.models import load_models

GROUPS = ("ordinary", "near", "far", "occluded")


def _owners(
    gaussian_ids: np.ndarray, mask_ids: np.ndarray, instance_of: np.ndarray, n_masks: int
) -> np.ndarray:
    """(M,) the instance holding >= 50 % of each mask's associated Gaussians, or -1."""
    owner = np.full(n_masks, -1)
    inst = instance_of[gaussian_ids]
    for m in range(n_masks):
        members = inst[mask_ids == m]
        if len(members):
            values, counts = np.unique(members, return_counts=True)
            if counts.max() >= 0.5 * len(members):
                owner[m] = int(values[np.argmax(counts)])
    return owner


def scene_records(case: Any, models: Any, runs: Path, cache: Path) -> tuple[list[dict], dict[str, int]]:
    """One record per task-object mask (group, own/other cosines, accepted) and, per kind, the
    outlier views with no mask of their object."""
    gt_per_task = {t: sum(1 for g in case.ground_truth if g.task == t) for t in case.tasks}
    params = PipelineParams.model_validate(
        {"previews": False, "top_k": max(5, max(gt_per_task.values(), default=1))} | {"answer_min_peak": None}
    )
    # The sweep's own full-method run when it is there (same folder as `evaluate_scene` writes),
    # else a fresh one on the shared perception cache.
    job = local_job(
        case.folder, runs / case.name / row_folder_name(FULL), cache, case.tasks, params, models,
        cache_prefix=f"scenes/{case.cache_name or case.name}/cache/",
    )  # fmt: skip
    spec, scene = job.spec, job.scene
    try:
        get_arrays(spec.store, spec.key(ACCEPTED_KEY))
    except Exception:  # noqa: BLE001 - not run yet
        run_job(job, force=True)
    gt = load_ground_truth(case.folder)
    doc = json.loads((case.folder / "gt.json").read_text())
    views = {f"frame_{v['frame']:05d}": v for v in doc.get("outlier_views", [])}
    tasks = list(case.tasks)
    own_tasks: dict[int, set[int]] = {}
    for t, task in enumerate(tasks):
        for obj in next(x for x in gt.tasks if x.text == task).objects:
            own_tasks.setdefault(obj.instance_id, set()).add(t)
    text = models.encoder.encode_texts(tasks).astype(np.float32)
    acc = get_arrays(spec.store, spec.key(ACCEPTED_KEY))
    offsets = np.concatenate([[0], np.cumsum(acc["mask_counts"])])
    frames = dict(scene.selected_frames)
    records: list[dict] = []
    unmasked = dict.fromkeys(GROUPS[1:], 0)
    for n, index in enumerate(acc["frame_indices"]):
        view = views.get(Path(frames[int(index)].name).stem)
        vis = get_arrays(spec.cache_store, scene.keys.visibility_key(int(index)))
        n_masks = int(acc["mask_counts"][n])
        owner = _owners(
            vis["gaussian_ids"].astype(np.int64), vis["mask_ids"].astype(np.int64), gt.instance_ids, n_masks
        )
        emb = get_arrays(spec.cache_store, scene.keys.perception_key(int(index)))["embeddings"]
        phi = emb.astype(np.float32) @ text.T
        accepted = acc["accepted"][offsets[n] : offsets[n + 1]]
        if view is not None and not (owner == view["instance_id"]).any():
            unmasked[view["kind"]] += 1
        for m in np.flatnonzero(owner >= 0):
            inst_id = int(owner[m])
            if inst_id not in own_tasks:
                continue
            if view is None:
                group = "ordinary"
            elif inst_id == view["instance_id"]:
                group = view["kind"]
            else:
                continue  # another object seen in an outlier frame: neither group
            own = sorted(own_tasks[inst_id])
            other = [t for t in range(len(tasks)) if t not in own_tasks[inst_id]]
            records.append(
                {
                    "scene": case.name,
                    "group": group,
                    "relevant": [float(phi[m, t]) for t in own],
                    "irrelevant": [float(phi[m, t]) for t in other],
                    "accepted": bool(accepted[m]),
                }
            )
    return records, unmasked


def summarise(records: list[dict], unmasked: dict[str, int], mu0: float, mu1: float) -> dict[str, dict]:
    out: dict[str, dict] = {}
    for group in GROUPS:
        rows = [r for r in records if r["group"] == group]
        rel = [x for r in rows for x in r["relevant"]]
        irr = [x for r in rows for x in r["irrelevant"]]
        out[group] = {
            "masks": len(rows),
            "relevant_mean": float(np.mean(rel)) if rel else None,
            "relevant_margin": float((np.mean(rel) - mu0) / (mu1 - mu0)) if rel else None,
            "irrelevant_mean": float(np.mean(irr)) if irr else None,
            "rejected_share": float(np.mean([not r["accepted"] for r in rows])) if rows else None,
            "views_without_a_mask_of_their_object": unmasked.get(group),
        }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--share", type=float, default=0.45)
    parser.add_argument("--scenes", type=int, default=10)
    parser.add_argument("--suite-dir", type=Path, default=Path("bench/_generated/suite-dial"))
    parser.add_argument("--runs", type=Path, default=Path("bench/_generated/dial-runs"))
    parser.add_argument("--cache", type=Path, default=Path("bench/_generated/dial-runs/cache"))
    parser.add_argument(
        "--out", type=Path, default=Path("bench/results/ablation-20261207/outlier-view-cosines")
    )
    args = parser.parse_args()
    models = regime_models(load_models(None), "realistic")
    assert models.calibration is not None  # the realistic regime sets its likelihoods
    mu0, mu1 = models.calibration.mu0, models.calibration.mu1
    cases = prepare_scenes(args.suite_dir, args.scenes, suite="capture", outliers=args.share)
    records: list[dict] = []
    unmasked = dict.fromkeys(GROUPS[1:], 0)
    for case in cases:
        recs, missing = scene_records(case, models, args.runs, args.cache)
        records += recs
        for k, v in missing.items():
            unmasked[k] += v
    summary = summarise(records, unmasked, mu0, mu1)
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        print(
            f"Outlier views vs ordinary views, {len(cases)} public capture scenes at S = {args.share:g} "
            f"({', '.join(c.name for c in cases)}), realistic regime (mu0 {mu0:.3f}, mu1 {mu1:.3f}); "
            "masks of task objects:"
        )
        print(
            f"{'views':<10} {'masks':>6} {'own-task cos':>13} {'margin':>7} {'other-task cos':>15} {'OR-phi rejects':>15} {'views w/o a mask':>17}"
        )
        for group, s in summary.items():
            fmt = lambda v, f: "-" if v is None else format(v, f)  # noqa: E731
            print(
                f"{group:<10} {s['masks']:>6} {fmt(s['relevant_mean'], '.4f'):>13} {fmt(s['relevant_margin'], '+.2f'):>7} "
                f"{fmt(s['irrelevant_mean'], '.4f'):>15} {fmt(s['rejected_share'], '.0%'):>15} "
                f"{fmt(s['views_without_a_mask_of_their_object'], 'd'):>17}"
            )
        print(
            "margin = (own-task cos - mu0) / (mu1 - mu0): 1 = the likelihoods' relevant mean, 0 = the irrelevant one."
        )
    sys.stdout.write(buffer.getvalue())
    args.out.parent.mkdir(parents=True, exist_ok=True)
    Path(f"{args.out}.txt").write_text(buffer.getvalue())
    Path(f"{args.out}.json").write_text(
        json.dumps({"share": args.share, "mu0": mu0, "mu1": mu1, "summary": summary}, indent=1)
    )


if __name__ == "__main__":
    main()
