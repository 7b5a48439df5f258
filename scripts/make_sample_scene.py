"""Regenerate the bundled sample scene ``samples/tabletop/`` (committed; the demo and docs use it).

A small synthetic tabletop (~20k Gaussians, 20 frames at 320x240) with tasks and ground truth,
kept to a few MB so it can live in the repository. Deterministic: rerunning gives the same files.
Usage: ``.venv/bin/python scripts/make_sample_scene.py [--out samples/tabletop]``.
"""

from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path

from bayesian_fields_core.eval.synthetic import SceneSpec, generate_scene, load_ground_truth

SAMPLE_SPEC = SceneSpec(
    name="sample-tabletop",
    seed=7,
    n_objects=7,
    n_duplicates=1,
    n_colours=4,
    n_groups=3,
    object_density=14000.0,
    table_density=1200.0,
    room_density=260.0,
    n_frames=20,
    max_fine_tasks=5,
    max_coarse_tasks=2,
    n_absent_tasks=1,
)


def folder_size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--out", default="samples/tabletop")
    out = Path(parser.parse_args(argv).out)
    if out.exists():
        shutil.rmtree(out)  # stale frames from an older spec must not linger
    start = time.perf_counter()
    generate_scene(out, SAMPLE_SPEC)
    gt = load_ground_truth(out)
    print(
        f"{out}: {gt.instance_ids.size} Gaussians, {SAMPLE_SPEC.n_frames} frames, {len(gt.tasks)} tasks, "
        f"{folder_size(out) / 1e6:.2f} MB in {time.perf_counter() - start:.1f} s"
    )


if __name__ == "__main__":
    main()
