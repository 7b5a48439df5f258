"""Print one digest of what a result answers, to check that a change leaves every output as it was.

Covers the object and primitive id maps, the probability and relevance tables, the object keys
and every task's selected objects (ids, keys, probabilities, best-view scores, Gaussian counts, boxes);
leaves out what legitimately differs between two runs of the same thing (timings, paths, the
preview images). Usage: ``python3 scripts/result_digest.py RESULT_FOLDER`` (a run's ``--out``
or its ``result/`` folder); reads only the standard library, so any Python runs it.
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

ARRAYS = ("object_ids.bin", "primitive_ids.bin", "probabilities.bin", "relevance.bin")
SELECTED_FIELDS = ("object_id", "key", "probability", "peak", "num_gaussians", "box", "centroid")
"""Digested under these names; "peak" is the best-view score, read from `best_view_score` (format
1.6) or `peak` (1.3-1.5), so a digest compares results of either format."""


def _selected(obj: dict) -> dict:
    """An object's digested fields (the best-view score under its 1.3-1.5 name, whichever key holds it)."""
    fields = {k: obj.get(k) for k in SELECTED_FIELDS}
    fields["peak"] = obj.get("best_view_score", obj.get("peak"))
    return fields


def result_digest(folder: Path) -> str:
    """16 hex digits over the arrays' bytes and the summary's answers (module docstring)."""
    result = folder / "result" if (folder / "result" / "summary.json").is_file() else folder
    digest = hashlib.sha256()
    for name in ARRAYS:
        digest.update(name.encode() + b"\0" + (result / name).read_bytes())
    summary = json.loads((result / "summary.json").read_text(encoding="utf-8"))
    answers = {
        "tasks": summary.get("tasks"),
        "object_keys": summary.get("object_keys"),
        "selections": [
            [_selected(obj) for obj in selection.get("objects", [])]
            for selection in summary.get("selections", [])
        ],
    }
    digest.update(json.dumps(answers, sort_keys=True).encode())
    return digest.hexdigest()[:16]


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: result_digest.py RESULT_FOLDER")
    print(result_digest(Path(sys.argv[1])))
