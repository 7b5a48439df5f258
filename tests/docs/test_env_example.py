"""`.env.example` is what an operator copies: every `BFIELDS_*` name it holds is a real setting (or
one of the few that only docker-compose.yml reads, in its compose-only block), and every setting is
in it, so a renamed or removed setting cannot leave a line that silently does nothing."""

from __future__ import annotations

import re
from pathlib import Path

from bayesian_fields_service.config.settings import ServiceSettings

REPO = Path(__file__).resolve().parents[2]
ENV_EXAMPLE = (REPO / ".env.example").read_text(encoding="utf-8")
COMPOSE = (REPO / "docker-compose.yml").read_text(encoding="utf-8")
SETTINGS = {f"BFIELDS_{name.upper()}" for name in ServiceSettings.model_fields}
NAME = re.compile(r"\bBFIELDS_[A-Z0-9_]+\b")


def _compose_only() -> str:
    start = ENV_EXAMPLE.index("# ---- compose-only")
    return ENV_EXAMPLE[start : ENV_EXAMPLE.index("# ---- end of compose-only ----", start)]


def test_every_bfields_name_is_a_setting_or_set_in_the_compose_block() -> None:
    compose_only = set(re.findall(r"^#?(BFIELDS_[A-Z0-9_]+)=", _compose_only(), re.MULTILINE))
    unknown = sorted(set(NAME.findall(ENV_EXAMPLE)) - SETTINGS - compose_only)
    assert unknown == [], f".env.example names variables no process reads: {unknown}"


def test_the_compose_only_names_are_read_by_compose_and_are_no_settings() -> None:
    names = set(re.findall(r"^#?(BFIELDS_[A-Z0-9_]+)=", _compose_only(), re.MULTILINE))
    assert names, "the compose-only block lost its variables"
    assert names.isdisjoint(SETTINGS), names & SETTINGS
    missing = sorted(n for n in names if "${" + n not in COMPOSE)
    assert missing == [], f"docker-compose.yml does not read {missing}"


def test_every_setting_is_described_in_env_example() -> None:
    listed = set(re.findall(r"^#?(BFIELDS_[A-Z0-9_]+)=", ENV_EXAMPLE, re.MULTILINE))
    missing = sorted(SETTINGS - listed)
    assert missing == [], f"settings without a line in .env.example: {missing}"
