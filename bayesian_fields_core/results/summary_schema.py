"""The JSON Schema of a result's summary.json, shipped as package data (`summary.schema.json`).

One schema for both places a summary appears: the result's own summary.json and `bfields run
--json` (summary.json plus the CLI's optional `run` block). Its `schema_version` is the result
format's `FORMAT_VERSION` (a test holds them together). Standard library only, so any reader can
validate without the pipeline.
"""

from __future__ import annotations

import json
from importlib.resources import files
from typing import Any

SCHEMA_FILE = "summary.schema.json"


def summary_schema() -> dict[str, Any]:
    """The schema as a dict (validate with any JSON Schema 2020-12 validator, e.g. `jsonschema`)."""
    text = files("bayesian_fields_core.results").joinpath(SCHEMA_FILE).read_text(encoding="utf-8")
    schema: dict[str, Any] = json.loads(text)
    return schema


__all__ = ["SCHEMA_FILE", "summary_schema"]
