"""Task lists with ground truth for a synthetic scene, at several granularities.

Fine tasks name one colour+kind ("get the red cube"; plural when the scene repeats it), coarse
tasks name a colour or a kind across objects ("move all the yellow things", "get all the mugs"),
and absent tasks name something the scene does not hold, whose scores calibrate mu0.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bayesian_fields_core.eval.synthetic.pieces import Instance
from bayesian_fields_core.eval.synthetic.spec import SceneSpec
from bayesian_fields_core.eval.vocabulary import COLOURS, COMPOUND_KINDS, plural


@dataclass(frozen=True)
class TaskSpec:
    """A task's text, its granularity ("fine", "coarse", "absent") and its GT instance ids."""

    text: str
    granularity: str
    instance_ids: tuple[int, ...]


def fine_task_text(colour: str, kind: str, count: int) -> str:
    """ "get the red cube" / "pick up the blue mug" (compounds) / "get the red cubes" (repeats)."""
    noun = plural(kind) if count > 1 else kind
    verb = "pick up" if kind in COMPOUND_KINDS else "get"
    return f"{verb} the {colour} {noun}"


def label_task_text(colour: str, kind: str, label: str) -> str:
    """ "get the red cube with the blue label": one object, told from look-alikes by its label."""
    return f"{fine_task_text(colour, kind, 1)} with the {label} label"


def make_tasks(spec: SceneSpec, instances: list[Instance], rng: np.random.Generator) -> list[TaskSpec]:
    """Fine, coarse and absent tasks, capped by the spec, in a seeded but stable order."""
    objects = [i for i in instances if i.category == "object"]
    by_pair: dict[tuple[str, str], list[int]] = defaultdict(list)
    by_colour: dict[str, list[int]] = defaultdict(list)
    by_kind: dict[str, list[int]] = defaultdict(list)
    for obj in objects:
        assert obj.colour is not None
        by_pair[(obj.colour, obj.kind)].append(obj.id)
        by_colour[obj.colour].append(obj.id)
        by_kind[obj.kind].append(obj.id)

    pairs = sorted(by_pair)
    fine = [
        TaskSpec(fine_task_text(c, k, len(by_pair[(c, k)])), "fine", tuple(by_pair[(c, k)]))
        for c, k in (pairs[i] for i in rng.permutation(len(pairs))[: spec.max_fine_tasks])
    ]
    # A labelled object is named by its label: its look-alike duplicates are not the answer.
    fine += [
        TaskSpec(label_task_text(obj.colour, obj.kind, obj.label), "fine", (obj.id,))
        for obj in objects
        if obj.label is not None and obj.colour is not None
    ]
    kinds_of = {c: {k for (cc, k) in by_pair if cc == c} for c in by_colour}
    colours_of = {k: {c for (c, kk) in by_pair if kk == k} for k in by_kind}
    coarse = [
        TaskSpec(f"move all the {c} things", "coarse", tuple(by_colour[c]))
        for c in sorted(by_colour)
        if len(kinds_of[c]) > 1
    ]
    coarse += [
        TaskSpec(f"get all the {plural(k)}", "coarse", tuple(by_kind[k]))
        for k in sorted(by_kind)
        if len(colours_of[k]) > 1
    ]
    coarse = [coarse[i] for i in rng.permutation(len(coarse))[: spec.max_coarse_tasks]]

    absent: list[TaskSpec] = []
    for _ in range(spec.n_absent_tasks):
        text = absent_task_text(rng, spec.kinds, set(by_pair))
        if text is not None and all(t.text != text for t in absent):
            absent.append(TaskSpec(text, "absent", ()))
    return fine + coarse + absent


def absent_task_text(
    rng: np.random.Generator, kinds: Sequence[str], held: set[tuple[str, str]]
) -> str | None:
    """One absent task by the suite's rule: a kind of the layout, in a colour the scene never uses
    (so the task is unrelated to every object), else a colour that kind does not come in here
    (None when the drawn kind comes in every colour). `held` is the scene's (colour, kind) pairs."""
    used = {c for c, _ in held}
    unused = [c for c in COLOURS if c not in used]
    kind = str(rng.choice(list(kinds)))
    colours = unused or [c for c in COLOURS if (c, kind) not in held]
    return fine_task_text(str(rng.choice(colours)), kind, 1) if colours else None


EXTRA_ABSENT_SEED = 4646
"""Mixed with a scene's seed to draw its extra absent tasks (`extra_absent_tasks`): a stream of
its own, so the scene (frames, objects, its own tasks) stays exactly as generated."""


def extra_absent_tasks(
    scene_seed: int, kinds: Sequence[str], held: set[tuple[str, str]], existing: Sequence[str], n: int
) -> list[str]:
    """`n` more absent tasks for a generated scene (fewer only when the vocabulary runs out), by
    the suite's own rule (`absent_task_text`), none equal to a task in `existing`. Fitting the
    'not found' threshold needs more absent tasks than the suite's one or two per scene
    (`bfields calibrate --absent-tasks`, docs/research/not-found-decision.md)."""
    rng = np.random.default_rng([int(scene_seed), EXTRA_ABSENT_SEED])
    taken = set(existing)
    out: list[str] = []
    for _ in range(50 * max(n, 1)):
        if len(out) == n:
            break
        text = absent_task_text(rng, kinds, held)
        if text is not None and text not in taken:
            taken.add(text)
            out.append(text)
    return out
