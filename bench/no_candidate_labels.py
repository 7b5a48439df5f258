"""Label tasks on the capture suite: how a labelled object's views score for its label task when
the label faces the camera and when it does not (follow-up of `no_candidate_trace.py`).

Reads the full-method jobs `no_candidate_trace.py` left in `--out` (it runs nothing but the
scene builder, to get each label's normal and surfels). A view of the labelled object (an own
mask: >= 50 % of the mask's associated Gaussians are the object's) "shows the label" when the
camera lies within the spec's `label_half_angle_deg` of the label's normal and the mask holds
some of the label's Gaussians. Prints, per label task and pooled, the mean margin
(phi - mu0) / (mu1 - mu0) and the summed per-view evidence d'^2 (margin - 0.5) of the
OR-phi-kept views in each group, and whether the task got a candidate.

Usage: PYTHONPATH=$PWD python bench/no_candidate_labels.py --scenes 10 \
    --suite-dir bench/_generated/suite-capture --out bench/_generated/nc-runs --cache bench/_generated/nc-cache
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from bayesian_fields_core.eval.regime import regime_models
from bayesian_fields_core.eval.suite import prepare_scenes
from bayesian_fields_core.eval.synthetic.builder import build_scene
from bayesian_fields_core.eval.synthetic.ground_truth import load_ground_truth
from bayesian_fields_core.eval.synthetic.spec import suite_specs
from bayesian_fields_core.job.artifacts import ACCEPTED_KEY, RESULT_PREFIX
from bayesian_fields_core.job.factories import local_job
from bayesian_fields_core.job.store import get_arrays
from bayesian_fields_core.params import PipelineParams
from bayesian_fields_core.perception.models import load_models
from bayesian_fields_core.results.reader import read_result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=10)
    ap.add_argument("--suite-dir", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--cache", type=Path, required=True)
    args = ap.parse_args()
    models = regime_models(load_models(None), "realistic")
    cal = models.calibration
    assert cal is not None
    mu0, mu1, d2 = cal.mu0, cal.mu1, ((cal.mu1 - cal.mu0) / cal.s) ** 2
    specs = {s.name: s for s in suite_specs(suite="capture")}
    pooled: dict[str, list[float]] = {"shows label": [], "label away": []}
    for case in prepare_scenes(args.suite_dir, args.scenes, None, "capture"):
        spec_ = specs[case.name]
        built = build_scene(spec_)
        gt = load_ground_truth(case.folder)
        params = PipelineParams.model_validate({"previews": False, "answer_min_peak": None})
        job = local_job(case.folder, args.out / case.name, args.cache, case.tasks, params, models,
                        cache_prefix="scene/cache/")  # fmt: skip
        spec, scene = job.spec, job.scene
        offset = float(np.abs(scene.loaded.gaussians.means - built.gaussians.means).max())
        assert offset < 1e-3, f"built scene differs from the loaded one by {offset}"
        result = read_result(spec.store, RESULT_PREFIX)
        acc = get_arrays(spec.store, spec.key(ACCEPTED_KEY))
        offsets = np.concatenate([[0], np.cumsum(acc["mask_counts"])])
        frames = dict(scene.selected_frames)
        text = models.encoder.encode_texts(list(case.tasks)).astype(np.float32)
        for label in built.labels:
            task = next((t for t in gt.tasks if any(o.instance_id == label.instance_id for o in t.objects)
                         and " label" in t.text), None)  # fmt: skip
            if task is None:
                continue
            t = list(case.tasks).index(task.text)
            inst = built.instance_ids == label.instance_id
            lab = inst & built.label_gaussians
            centre = built.gaussians.means[lab].mean(axis=0)
            groups: dict[str, list[float]] = {"shows label": [], "label away": []}
            for n, index in enumerate(acc["frame_indices"]):
                frame = frames[int(index)]
                cam_to_world = np.linalg.inv(frame.world_to_camera)
                view = cam_to_world[:3, 3] - centre
                facing = float(view @ label.normal) / np.linalg.norm(view) >= np.cos(
                    np.radians(spec_.label_half_angle_deg)
                )
                vis = get_arrays(spec.cache_store, scene.keys.visibility_key(int(index)))
                g, m = vis["gaussian_ids"].astype(np.int64), vis["mask_ids"].astype(np.int64)
                per_mask = np.bincount(m, minlength=acc["mask_counts"][n])
                mine = np.bincount(m[inst[g]], minlength=acc["mask_counts"][n])
                with_label = np.bincount(m[lab[g]], minlength=acc["mask_counts"][n])
                owned = np.flatnonzero((mine >= 0.5 * np.maximum(per_mask, 1)) & (mine > 0))
                owned = owned[acc["accepted"][offsets[n] + owned]]
                if not len(owned):
                    continue
                emb = get_arrays(spec.cache_store, scene.keys.perception_key(int(index)))["embeddings"]
                margins = (emb[owned].astype(np.float32) @ text[t] - mu0) / (mu1 - mu0)
                for mask, margin in zip(owned, margins, strict=True):
                    key = "shows label" if facing and with_label[mask] > 0 else "label away"
                    groups[key].append(float(margin))
            row = {"scene": case.name, "task": task.text, "answered": bool(result.selections.get(task.text))}
            for key, values in groups.items():
                v = np.asarray(values)
                pooled[key] += values
                row[key] = {
                    "views": len(v),
                    "margin_mean": None if not len(v) else round(float(v.mean()), 3),
                    "evidence_nats": round(float(d2 * (v - 0.5).sum()), 1),
                }
            print(json.dumps(row), flush=True)
    for key, values in pooled.items():
        v = np.asarray(values)
        print(
            f"pooled, {key}: {len(v)} kept views, margin mean {v.mean():.3f} (median {np.median(v):.3f}), "
            f"share above 0.5 {(v > 0.5).mean():.2f}, evidence {d2 * (v - 0.5).sum():.0f} nats"
        )


if __name__ == "__main__":
    main()
