"""Why a present task gets no candidate object (issue 46 follow-up): trace each such task's GT
objects through the pipeline on public suite scenes.

For every present task of a scene whose full-method selection is empty (realistic regime, the
"not found" rule off, as `bfields eval` scores), and for each of its GT instances, this prints:

- views: frames whose camera has >= half the instance's Gaussian centres inside the image
  (occlusion ignored), frames where any of its Gaussians is associated with a mask, frames with
  an "own" mask (>= 50 % of the mask's associated Gaussians are the instance's);
- scores: the best own-mask cosine for the task as a margin (phi - mu0) / (mu1 - mu0) (1 = a
  typical relevant view), how many own masks score above the midpoint 0.5, how many OR-phi kept;
- posterior: the instance's Gaussians' mean fused probability for the task and the share above
  the prior;
- clustering: the AIB cluster holding most of the instance's Gaussians (before pruning): its
  Gaussian count, purity, and relevance (Gaussian-weighted mean probability) for the task;
- the rule that drops it: every cluster of the scene below `prune_threshold` for the task
  ("relevance < prune") or the ones at or above it all smaller than `min_object_gaussians`
  ("size < min").

Usage: PYTHONPATH=$PWD python bench/no_candidate_trace.py --suite capture --scenes 5 \
    --suite-dir bench/_generated/suite-capture --out bench/_generated/nc-runs \
    --cache bench/_generated/nc-cache [--seeds 1201 1301 ...] [--param key=value ...]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from bayesian_fields_core.eval.regime import regime_models
from bayesian_fields_core.eval.suite import prepare_scenes
from bayesian_fields_core.eval.synthetic.ground_truth import load_ground_truth
from bayesian_fields_core.job.artifacts import ACCEPTED_KEY, FUSION_KEY, PRIMITIVES_KEY, RESULT_PREFIX
from bayesian_fields_core.job.factories import local_job
from bayesian_fields_core.job.pipeline import run_job
from bayesian_fields_core.job.store import get_arrays
from bayesian_fields_core.objects.aib import aib
from bayesian_fields_core.objects.clustering import primitive_graph, primitive_scores
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.perception.models import load_models
from bayesian_fields_core.results.reader import read_result
from bayesian_fields_core.stages.cluster import view_counts


def cluster_means(
    cluster_of_primitive: np.ndarray, gaussian_counts: np.ndarray, values: np.ndarray, n: int
) -> np.ndarray:
    """(C, T) each cluster's Gaussian-weighted mean of per-primitive `values` (P, T): the mean over
    all the cluster's Gaussians, as `prune_and_select` computes relevance and evidence."""
    weight = np.bincount(cluster_of_primitive, weights=gaussian_counts, minlength=n)
    sums = np.zeros((n, values.shape[1]))
    np.add.at(sums, cluster_of_primitive, values * gaussian_counts[:, None])
    return sums / np.maximum(weight, 1e-12)[:, None]


def _in_view(means: np.ndarray, frame: Any) -> float:
    """Share of `means` (n, 3) inside frame's image, in front of the camera (occlusion ignored)."""
    cam = means @ frame.world_to_camera[:3, :3].T + frame.world_to_camera[:3, 3]
    z = cam[:, 2]
    uv = cam @ frame.K.T
    u, v = uv[:, 0] / np.maximum(z, 1e-9), uv[:, 1] / np.maximum(z, 1e-9)
    inside = (z > 0) & (u >= 0) & (u < frame.width) & (v >= 0) & (v < frame.height)
    return float(inside.mean()) if len(means) else 0.0


def _own_margins(
    spec: Any,
    scene: Any,
    acc: dict,
    inst: np.ndarray,
    text_t: np.ndarray,
    mu0: float,
    mu1: float,
    means: np.ndarray,
    frames: dict,
) -> dict:
    """Frame by frame: is the instance in view, masked, does it have its own mask, and that
    mask's margin for the task and its OR-phi flag."""
    offsets = np.concatenate([[0], np.cumsum(acc["mask_counts"])])
    in_view = masked = 0
    margins: list[float] = []
    accepted: list[bool] = []
    for n, index in enumerate(acc["frame_indices"]):
        in_view += _in_view(means[inst], frames[int(index)]) >= 0.5
        vis = get_arrays(spec.cache_store, scene.keys.visibility_key(int(index)))
        g, m = vis["gaussian_ids"].astype(np.int64), vis["mask_ids"].astype(np.int64)
        hit = inst[g]
        if not hit.any():
            continue
        masked += 1
        per_mask = np.bincount(m, minlength=acc["mask_counts"][n])
        mine = np.bincount(m[hit], minlength=acc["mask_counts"][n])
        owned = np.flatnonzero((mine >= 0.5 * np.maximum(per_mask, 1)) & (mine > 0))
        if not len(owned):
            continue
        emb = get_arrays(spec.cache_store, scene.keys.perception_key(int(index)))["embeddings"]
        phi = emb[owned].astype(np.float32) @ text_t
        margins += [float(x) for x in (phi - mu0) / (mu1 - mu0)]
        accepted += [bool(x) for x in acc["accepted"][offsets[n] + owned]]
    return {"in_view": int(in_view), "masked": masked, "margins": margins, "accepted": accepted}


def trace_scene(case: Any, models: Any, out: Path, cache: Path, overrides: dict[str, Any]) -> list[dict]:
    gt_per_task = {t: sum(1 for g in case.ground_truth if g.task == t) for t in case.tasks}
    top_k = max(5, max(gt_per_task.values(), default=1))
    params = PipelineParams.model_validate(
        {"previews": False, "top_k": top_k, **overrides} | {"answer_min_peak": None}
    )
    job = local_job(
        case.folder, out / case.name, cache, case.tasks, params, models, cache_prefix="scene/cache/"
    )
    run_job(job, force=True)
    spec, scene, runner = job.spec, job.scene, job.runner
    result = read_result(spec.store, RESULT_PREFIX)
    gt = load_ground_truth(case.folder)
    tasks = list(case.tasks)
    cal = models.calibration
    mu0, mu1 = cal.mu0, cal.mu1
    d2 = ((mu1 - mu0) / cal.s) ** 2
    fused = get_arrays(spec.store, spec.key(FUSION_KEY))
    probs, peak = fused["probabilities"], fused["peak_margin"]
    prim = get_arrays(spec.store, spec.key(PRIMITIVES_KEY))["primitive_ids"]
    acc = get_arrays(spec.store, spec.key(ACCEPTED_KEY))
    text = models.encoder.encode_texts(tasks).astype(np.float32)
    means = scene.loaded.gaussians.means
    frames = dict(scene.selected_frames)
    # clusters before pruning, as the cluster stage builds them
    scores = primitive_scores(prim, probs, fused["logodds"], params, view_counts(spec, scene, runner, fused))
    counts = np.bincount(prim[prim >= 0], minlength=scores.pyx.shape[0]).astype(np.float64)
    _, merged = primitive_graph(means, prim, scores.pyx, counts, params, scene.lengths, scores.premerge)
    clustering = aib(merged.pyx, merged.edges, params.aib_delta, weights=merged.weights)
    cluster_of_prim = clustering.labels[merged.labels]
    n_clusters = clustering.pyx.shape[0]
    assert scores.relevance is not None  # the default selection score ranks by evidence
    relevance = cluster_means(cluster_of_prim, counts, scores.relevance, n_clusters)
    evidence = (
        relevance
        if scores.evidence is None
        else cluster_means(cluster_of_prim, counts, scores.evidence, n_clusters)
    )
    gauss_cluster = np.where(prim >= 0, cluster_of_prim[np.maximum(prim, 0)], -1)
    csize = np.bincount(gauss_cluster[gauss_cluster >= 0], minlength=n_clusters)
    big = csize >= params.min_object_gaussians
    kept = (relevance >= params.prune_threshold).any(axis=1)  # the paper's pruning: any task
    n_inst = int(gt.instance_ids.max()) + 1
    rows: list[dict] = []
    for t, task in enumerate(tasks):
        gtask = next(x for x in gt.tasks if x.text == task)
        present = gt_per_task[task] > 0
        ok = relevance[:, t] >= params.prune_threshold
        answered = bool(result.selections.get(task))
        rule = None
        if not answered:
            rule = (
                "relevance < prune" if not ok.any() else ("size < min" if not (ok & big).any() else "other")
            )
        # the paper's selection: best object among those kept for any task, whatever this task's p
        paper = np.flatnonzero(kept & big)
        row: dict[str, Any] = {
            "scene": case.name,
            "task": task,
            "family": "absent" if not present else ("label" if " label" in task else gtask.granularity),
            "present": present,
            "answered": answered,
            "best_peak": None if not answered else result.selections[task][0].peak,
            "rule": rule,
            "max_relevance_any": round(float(relevance[:, t].max()), 4),
        }
        if len(paper):
            top = int(paper[np.argmax(evidence[paper, t])])
            members = np.flatnonzero(gauss_cluster == top)
            majority = int(np.bincount(gt.instance_ids[members], minlength=n_inst).argmax())
            row["paper_rule_top_is_gt"] = majority in {o.instance_id for o in gtask.objects}
            row["paper_rule_top_instance"] = next(
                (i.name for i in gt.instances if i.instance_id == majority), str(majority)
            )
            row["paper_rule_top_peak"] = round(float(np.median(peak[members, t])), 4)
            row["paper_rule_top_relevance"] = round(float(relevance[top, t]), 4)
        objs = []
        for obj in gtask.objects:
            inst = np.zeros(len(means), dtype=bool)
            inst[obj.gaussian_ids] = True
            own = _own_margins(spec, scene, acc, inst, text[t], mu0, mu1, means, frames)
            m = np.asarray(own["margins"])
            a = np.asarray(own["accepted"], dtype=bool)
            counts_c = np.bincount(gauss_cluster[inst & (gauss_cluster >= 0)], minlength=n_clusters)
            c = int(counts_c.argmax()) if counts_c.any() else -1
            objs.append(
                {
                    "instance": obj.name,
                    "gaussians": int(inst.sum()),
                    "frames": len(acc["frame_indices"]),
                    "in_view": own["in_view"],
                    "masked": own["masked"],
                    "own_masks": int(len(m)),
                    "own_accepted": int(a.sum()),
                    "margin_mean": None if not len(m) else round(float(m.mean()), 3),
                    "margin_max": None if not len(m) else round(float(m.max()), 3),
                    "above_mid": None if not len(m) else round(float((m > 0.5).mean()), 3),
                    # the summed per-view log-likelihood ratio of the accepted own masks, nats
                    "evidence_nats": round(float(d2 * (m[a] - 0.5).sum()), 2) if len(m) else 0.0,
                    "post_mean": round(float(probs[inst, t].mean()), 4),
                    "post_above_prior": round(float((probs[inst, t] > params.prior).mean()), 3),
                    "cluster_size": int(csize[c]) if c >= 0 else 0,
                    "cluster_purity": round(float(counts_c[c] / max(csize[c], 1)), 3) if c >= 0 else 0.0,
                    "cluster_share": round(float(counts_c[c] / max(inst.sum(), 1)), 3) if c >= 0 else 0.0,
                    "cluster_relevance": round(float(relevance[c, t]), 4) if c >= 0 else None,
                }
            )
        row["objects"] = objs
        # look-alikes: instances named as a GT object (same colour and kind) that are not answers
        gt_ids = {o.instance_id for o in gtask.objects}
        names = {o.name for o in gtask.objects}
        look = []
        if present and not answered:
            for other in gt.instances:
                if other.name in names and other.instance_id not in gt_ids:
                    inst = np.zeros(len(means), dtype=bool)
                    inst[other.gaussian_ids] = True
                    own = _own_margins(spec, scene, acc, inst, text[t], mu0, mu1, means, frames)
                    m = np.asarray(own["margins"])
                    look.append(
                        {
                            "instance": other.name,
                            "margin_mean": None if not len(m) else round(float(m.mean()), 3),
                            "post_mean": round(float(probs[inst, t].mean()), 4),
                        }
                    )
        row["lookalikes"] = look
        rows.append(row)
    return rows


def summary(rows: list[dict], threshold: float | None) -> list[str]:
    """The counts the write-up quotes: lost present tasks per family and per rule, what their
    objects' views and posteriors look like, and the paper's any-task selection beside."""
    out = []
    present = [r for r in rows if r["present"]]
    absent = [r for r in rows if not r["present"]]
    lost = [r for r in present if not r["answered"]]
    out.append(
        f"{len({r['scene'] for r in rows})} scenes: {len(present)} present tasks, {len(lost)} without a "
        f"candidate; {len(absent)} absent tasks, {sum(not r['answered'] for r in absent)} without a candidate"
    )
    for fam in ("fine", "label", "coarse"):
        fr = [r for r in present if r["family"] == fam]
        fl = [r for r in fr if not r["answered"]]
        out.append(f"  {fam:<7} {len(fl):>3} / {len(fr):<3} lost")
    rules: dict[str, int] = {}
    for r in lost:
        rules[r["rule"]] = rules.get(r["rule"], 0) + 1
    out.append(f"  rule that empties the selection: {rules}")
    objs = [o for r in lost for o in r["objects"]]
    kept_objs = [o for r in present if r["answered"] for o in r["objects"]]
    for name, group in (("lost tasks' GT objects", objs), ("answered tasks' GT objects", kept_objs)):
        if not group:
            continue

        def med(key: str, group: list[dict] = group) -> float:
            vals = [o[key] for o in group if o[key] is not None]
            return float(np.median(vals)) if vals else float("nan")

        out.append(
            f"  {name} ({len(group)}): no own mask {sum(o['own_masks'] == 0 for o in group)}, "
            f"own masks median {med('own_masks'):.0f} of {med('frames'):.0f} frames, OR-phi kept "
            f"{sum(o['own_accepted'] for o in group)}/{sum(o['own_masks'] for o in group)}; margin mean "
            f"median {med('margin_mean'):.2f}, share above 0.5 median {med('above_mid'):.2f}, best view "
            f"median {med('margin_max'):.2f}; evidence <= 0 nats: {sum(o['evidence_nats'] <= 0 for o in group)}; "
            f"posterior mean median {med('post_mean'):.4f}; main cluster share {med('cluster_share'):.2f}, "
            f"purity {med('cluster_purity'):.2f}, relevance {med('cluster_relevance'):.4f}"
        )
    gt_top = [r for r in lost if r.get("paper_rule_top_is_gt")]
    out.append(
        f"  the paper's selection (pruned for every task only) would answer {len(gt_top)} of the {len(lost)} lost with a GT object first"
    )
    if threshold is not None:
        passing = [r for r in gt_top if r["paper_rule_top_peak"] >= threshold]
        absent_pass = [r for r in absent if r.get("paper_rule_top_peak", -9) >= threshold]
        out.append(
            f"  ... of them {len(passing)} above the fitted threshold {threshold:.4f}; absent tasks whose paper-rule "
            f"candidate passes it: {len(absent_pass)} / {len(absent)}"
        )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--suite", default="capture")
    ap.add_argument("--scenes", type=int, default=5)
    ap.add_argument("--seeds", type=int, nargs="*")
    ap.add_argument("--suite-dir", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--param", action="append", default=[], help="key=json value, e.g. prune_threshold=0.05")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--regime", default="realistic", choices=["realistic", "strong"])
    args = ap.parse_args()
    overrides = {k: json.loads(v) for k, v in (p.split("=", 1) for p in args.param)}
    models = regime_models(load_models(None), args.regime)
    cases = prepare_scenes(args.suite_dir, args.scenes, args.seeds, args.suite)
    every: list[dict] = []
    for case in cases:
        t0 = time.time()
        rows = trace_scene(case, models, args.out, args.cache, overrides)
        every += rows
        for row in rows:
            if row["present"] and not row["answered"]:
                print(json.dumps(row), flush=True)
        print(f"# {case.name} {time.time() - t0:.0f}s", flush=True)
    if args.json:
        args.json.write_text(json.dumps(every, indent=1))
    cal = models.calibration
    print(f"regime {args.regime}, parameters {overrides or 'default'}")
    for line in summary(every, None if cal is None else cal.answer_min_peak):
        print(line)


if __name__ == "__main__":
    main()
