"""The README is the front page: the two set-up commands first, short, and its links lead somewhere.

CI runs the README's test command verbatim (`.ci/run`) and the set-up commands are what users
paste, so they stay at the top exactly as written; everything else lives on the documentation
site (`docs/`, built strictly by `.ci/docs.sh`).
"""

from __future__ import annotations

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
README = REPO / "README.md"
SETUP = "python3 -m venv .venv && .venv/bin/pip install -q torch==2.13.0 -e '.[api,worker,dev]'"
DEMO = f"{SETUP} && .venv/bin/bfields run samples/tabletop --out out/demo"
TESTS = f"{SETUP} && .venv/bin/python -m pytest -q"


def test_the_two_setup_commands_open_the_readme() -> None:
    lines = README.read_text(encoding="utf-8").splitlines()
    assert lines[5:9] == ["```bash", DEMO, TESTS, "```"]
    assert not any("```" in line for line in lines[:5]), "no code block before the set-up commands"


def test_ci_runs_the_readme_test_command_verbatim() -> None:
    assert TESTS in (REPO / ".ci" / "run").read_text(encoding="utf-8")


def test_readme_stays_short() -> None:
    assert len(README.read_text(encoding="utf-8").splitlines()) <= 250, "move the detail into docs/"


def test_readme_links_resolve() -> None:
    """Every relative link and image of the README names a file or folder of the repository, and
    every `#anchor` into a docs page names one of its headings."""
    text = README.read_text(encoding="utf-8")
    links = re.findall(r"\]\(([^)\s]+)\)", text)
    relative = [link for link in links if not re.match(r"[a-z]+:", link)]
    assert len(relative) >= 10
    for link in relative:
        path, _, anchor = link.partition("#")
        target = REPO / path
        assert target.exists(), f"README links to {link}, which does not exist"
        if anchor:
            headings = re.findall(r"^#+ (.+)$", target.read_text(encoding="utf-8"), re.M)
            slugs = {re.sub(r"[-\s]+", "-", re.sub(r"[^\w\s-]", "", h).strip().lower()) for h in headings}
            assert anchor in slugs, f"README links to {link}: no such heading in {path}"
