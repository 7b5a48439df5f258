"""Rewrite the tables the code generates in the docs (between `<!-- generated: NAME ... -->`
markers; see `docs/_build/generated.py`), or with `--check` only list the stale ones.

    python scripts/update_docs_tables.py            # rewrite every stale block
    python scripts/update_docs_tables.py --check    # exit 1 if one is stale (what the test checks)
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "docs" / "_build"))
import generated  # noqa: E402 - docs/_build, put on the path above


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="list stale blocks and exit 1; write nothing")
    args = parser.parse_args(argv)
    stale = generated.stale(ROOT)
    for page, name in stale:
        print(f"{page.relative_to(ROOT)}: {name!r} {'is out of date' if args.check else 'rewritten'}")
    if args.check:
        return 1 if stale else 0
    for page in sorted({page for page, _ in stale}):
        page.write_text(generated.refresh(page.read_text(encoding="utf-8"), ROOT), encoding="utf-8")
    if not stale:
        print("every generated table is current")
    return 0


if __name__ == "__main__":
    sys.exit(main())
