"""Command line: ``python -m bayesian_fields_core.eval.synthetic OUT --seed N [--n-objects K ...]``.

Every SceneSpec field is an option (``--n-frames 24``, ``--orbit-heights 1.2,1.5``); ``--suite
NAME`` starts from one of the eval suite's specs instead of the defaults.
"""

from __future__ import annotations

import argparse
import sys
import time

from pydantic import ValidationError

from bayesian_fields_core.eval.synthetic.spec import SceneSpec, suite_specs


def generator_parser() -> argparse.ArgumentParser:
    """The generator's parser (also shown by `bfields generate --help`)."""
    p = argparse.ArgumentParser(
        prog="python -m bayesian_fields_core.eval.synthetic", description=__doc__.split("\n")[0]
    )
    p.add_argument("out", help="output scene folder")
    p.add_argument("--suite", choices=[s.name for s in suite_specs()], help="start from a suite scene's spec")
    p.add_argument("--device", default="cpu", help="render device (cpu or cuda)")
    for name, info in SceneSpec.model_fields.items():
        p.add_argument(
            "--" + name.replace("_", "-"),
            dest=name,
            default=None,
            help=info.description or f"default {info.default!r}",
        )
    return p


def _value(raw: str, default: object) -> object:
    """Parse an option string to the type of the field's default (tuples are comma-separated)."""
    if isinstance(default, tuple):
        items = [s.strip() for s in raw.split(",") if s.strip()]
        return tuple(type(default[0])(s) if default else s for s in items)
    return raw


def main(argv: list[str] | None = None) -> int:
    args = generator_parser().parse_args(argv)
    base = next((s for s in suite_specs() if s.name == args.suite), SceneSpec())
    overrides = {
        name: _value(getattr(args, name), getattr(base, name))
        for name in SceneSpec.model_fields
        if getattr(args, name) is not None
    }
    try:
        spec = SceneSpec.model_validate({**base.model_dump(), **overrides})
    except ValidationError as exc:
        print(f"invalid scene spec: {exc}", file=sys.stderr)
        return 2
    from bayesian_fields_core.eval.synthetic.generate import generate_scene
    from bayesian_fields_core.eval.synthetic.ground_truth import load_ground_truth

    start = time.perf_counter()
    out = generate_scene(args.out, spec, device=args.device)
    gt = load_ground_truth(out)
    print(
        f"{out}: {gt.instance_ids.size} Gaussians, {spec.n_frames} frames {spec.width}x{spec.height}, "
        f"{len(gt.tasks)} tasks, {sum(i.category == 'object' for i in gt.instances)} objects "
        f"in {time.perf_counter() - start:.1f} s"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
