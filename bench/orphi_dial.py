"""The outlier dial's sweep (issue 46 item 4, docs/research/ablation-decision.md): full minus
w/o OR-phi on the public capture scenes as the share S of outlier views rises.

For each S: the suite's public capture scenes with the dial at S (`bfields eval --suite capture
--scenes N --outliers S --rows orphi --lerf-views 0`, realistic regime, through the same
`prepare_scenes` / `evaluate_scene`), then full minus w/o OR-phi in Strict, Relaxed and IoU with
the scene-level paired bootstrap 95 % interval (`eval/bootstrap.paired_differences`, scenes kept
whole, 2,000 resamples), in the geometric scoring (pooled over the (task, GT) pairs, as `bfields
eval` prints it) and in the Clio-code scoring (its per-task counts pooled the same way; `bfields
eval`'s Clio-code table is the mean of the scenes, so its point values can differ from the pooled
ones here). Each S's log goes to <out>/dial-<S>.txt, all numbers to <out>/orphi-dial.json.

Usage: PYTHONPATH=$PWD python bench/orphi_dial.py --shares 0 0.45 0.15 0.30 --scenes 10 \\
    --suite-dir bench/_generated/suite-dial --runs bench/_generated/dial-runs \\
    --out bench/results/ablation-20261207
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from bayesian_fields_core.eval.bootstrap import paired_differences
from bayesian_fields_core.eval.clio import ClioScores
from bayesian_fields_core.eval.regime import describe, regime_models
from bayesian_fields_core.eval.suite import (
    FULL,
    ORPHI,
    evaluate_scene,
    pool_scores,
    prepare_scenes,
    scene_groups,
)
from bayesian_fields_core.perception.models import load_models

METRICS = ("strict_osr", "relaxed_osr", "iou")


class _Tee(io.TextIOBase):
    """Writes to the terminal and to a log file."""

    def __init__(self, *streams: Any) -> None:
        self.streams = streams

    def write(self, text: str) -> int:
        for s in self.streams:
            s.write(text)
            s.flush()
        return len(text)


def differences(per_row: dict[str, list[ClioScores]]) -> dict[str, dict[str, float]]:
    """Full minus w/o OR-phi per metric: pooled values and the scene-level paired interval."""
    pooled = {row: pool_scores(scores) for row, scores in per_row.items()}
    groups = scene_groups(per_row[FULL])
    diff = paired_differences(pooled[FULL], pooled[ORPHI], groups=groups, metrics=METRICS)
    return {
        m: {
            "full": getattr(pooled[FULL], m),
            "without": getattr(pooled[ORPHI], m),
            "diff": diff[m].mean,
            "low": diff[m].low,
            "high": diff[m].high,
        }
        for m in METRICS
    }


def run_share(share: float, args: argparse.Namespace, models: Any) -> dict[str, Any]:
    cases = prepare_scenes(args.suite_dir, args.scenes, suite="capture", outliers=share)
    geo: dict[str, list[ClioScores]] = {}
    code: dict[str, list[ClioScores]] = {}
    for case in cases:
        print(f"scene {case.name}: {len(case.tasks)} tasks, {len(case.ground_truth)} GT objects")
        ev = evaluate_scene(case, models, args.runs, lerf_views=0, rows_shown="orphi")
        for row in (FULL, ORPHI):
            geo.setdefault(row, []).append(ev.clio[row])
            code.setdefault(row, []).append(ev.clio_code[row])
    out: dict[str, Any] = {
        "share": share,
        "scenes": [c.name for c in cases],
        "pairs": pool_scores(geo[FULL]).num_gt,
        "geometric": differences(geo),
        "clio_code": differences(code),
    }
    for scoring in ("geometric", "clio_code"):
        print(f"{scoring} scoring, full minus w/o OR-phi (scene-level paired bootstrap 95 %):")
        for m, d in out[scoring].items():
            print(
                f"  {m:<12} full {d['full']:.3f}  w/o OR-phi {d['without']:.3f}  "
                f"diff {d['diff']:+.3f} [{d['low']:+.3f}, {d['high']:+.3f}]"
            )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--shares", type=float, nargs="+", default=[0.0, 0.45, 0.15, 0.30])
    parser.add_argument("--scenes", type=int, default=10)
    parser.add_argument("--suite-dir", type=Path, default=Path("bench/_generated/suite-dial"))
    parser.add_argument("--runs", type=Path, default=Path("bench/_generated/dial-runs"))
    parser.add_argument("--out", type=Path, default=Path("bench/results/ablation-20261207"))
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    models = regime_models(load_models(None), "realistic")
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True
    ).stdout.strip()
    path = args.out / "orphi-dial.json"
    results = json.loads(path.read_text()) if path.is_file() else {}
    for share in args.shares:
        start = time.time()
        with (
            open(args.out / f"dial-{share:g}.txt", "w") as log,
            contextlib.redirect_stdout(_Tee(sys.stdout, log)),
        ):
            print(
                f"bench/orphi_dial.py --shares {share:g} --scenes {args.scenes} (commit {commit}; realistic regime)"
            )
            print(describe(models, "realistic"))
            results[f"{share:g}"] = run_share(share, args, models) | {"commit": commit}
            print(f"{time.time() - start:.0f} s")
        path.write_text(json.dumps(results, indent=1, sort_keys=True))


if __name__ == "__main__":
    main()
