"""Task text rules of the library (the CLI's task files and the API share them): lone surrogates,
control characters and bidirectional controls are refused with the task's number; whitespace
runs collapse to one space."""

from __future__ import annotations

from pathlib import Path

import pytest

from bayesian_fields_core.errors import InputError
from bayesian_fields_core.job.task_list import load_tasks, normalise_tasks


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("get \ud800 mug", "lone surrogate U+D800"),
        ("get\u202emug", "bidirectional control U+202E"),
        ("isolate\u2067d", "bidirectional control U+2067"),
        ("bell\x07", "control character U+0007"),
        ("del\x7f", "control character U+007F"),
    ],
)
def test_bad_task_text_is_refused(text: str, fragment: str) -> None:
    with pytest.raises(InputError) as err:
        normalise_tasks(["fine", text])
    assert "task #2" in str(err.value) and fragment in str(err.value)


def test_whitespace_collapses_and_unicode_letters_pass() -> None:
    assert normalise_tasks(["  get\tthe\n mug ", "café au lait ☕", "湯呑み"]) == [
        "get the mug",
        "café au lait ☕",
        "湯呑み",
    ]


def test_task_files_get_the_same_rules(tmp_path: Path) -> None:
    path = tmp_path / "tasks.txt"
    path.write_text("get mug\nflip \u202eswitch\n", encoding="utf-8")
    with pytest.raises(InputError, match="U\\+202E"):
        load_tasks(path)
