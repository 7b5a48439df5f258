"""Extra absent tasks for fitting the "not found" threshold: the suite's rule, seeded apart from
the scene."""

from __future__ import annotations

from bayesian_fields_core.eval.synthetic.tasks import extra_absent_tasks, fine_task_text
from bayesian_fields_core.eval.vocabulary import COLOURS

KINDS = ["cube", "sphere", "mug"]


def test_extra_absent_tasks_name_nothing_the_scene_holds() -> None:
    held = {("red", "cube"), ("blue", "mug")}
    existing = [fine_task_text("green", "cube", 1)]  # the scene's own absent task
    tasks = extra_absent_tasks(11, KINDS, held, existing, 6)
    assert len(tasks) == 6 and len(set(tasks)) == 6
    assert not set(tasks) & set(existing)
    used = {c for c, _ in held}
    for text in tasks:
        colour = next(c for c in COLOURS if f" {c} " in text)
        assert colour not in used  # an unused colour, so unrelated to every object
        assert any(text.endswith(k) for k in KINDS)
    assert extra_absent_tasks(11, KINDS, held, existing, 6) == tasks  # seeded by the scene
    assert extra_absent_tasks(12, KINDS, held, existing, 6) != tasks


def test_every_colour_used_falls_back_to_pairs_the_scene_lacks() -> None:
    first = list(COLOURS)[0]
    held = {(c, "cube") for c in COLOURS} | {(first, "mug")}
    tasks = extra_absent_tasks(3, ["cube", "mug"], held, [], 4)
    assert tasks  # only mugs in colours other than the first can be absent
    assert all("mug" in t and f" {first} " not in t for t in tasks)
    # the vocabulary runs out: fewer than asked, never a held pair, never a repeat
    assert len(extra_absent_tasks(3, ["cube"], held, [], 4)) == 0
    assert extra_absent_tasks(3, KINDS, set(), [], 0) == []
