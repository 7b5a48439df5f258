#!/usr/bin/env bash
# CI stage: the documentation site. Installs the `docs` extra into the project venv and builds the
# site strictly: any warning, a link to a missing page or anchor (mkdocs.yml `validation:`), a
# docstring griffe cannot read or a failing generator (API reference, parameter table) fails it.
# The site goes to site/ (ignored by git). Prints what it ran and how long each step took.
set -euo pipefail
cd "$(dirname "$0")/.."
start=$(date +%s)
step() {
  local t0=$(date +%s)
  echo "+ $*"
  "$@"
  echo "  ($(($(date +%s) - t0)) s)"
}
# Banners some plugins print about MkDocs 2 (not warnings of this build).
export NO_MKDOCS_2_WARNING=1 DISABLE_MKDOCS_2_WARNING=true

# The project venv (the tests stage made it; BFIELDS_VENV names another). The build imports the
# checkout itself (the parameter table runs `bfields params`), so only the extra's packages are
# installed into an existing venv; the project install there is left as it is.
venv="${BFIELDS_VENV:-.venv}"
if [ ! -x "$venv/bin/python" ]; then
  step python3 -m venv "$venv"
  step "$venv/bin/pip" install -q torch==2.13.0 -e '.[docs]'
else
  mapfile -t reqs < <("$venv/bin/python" -c 'import tomllib; print("\n".join(tomllib.load(open("pyproject.toml", "rb"))["project"]["optional-dependencies"]["docs"]))')
  step "$venv/bin/pip" install -q "${reqs[@]}"
fi
step timeout "${DOCS_BUILD_TIMEOUT:-300}" "$venv/bin/mkdocs" build --strict --site-dir site
pages=$(find site -name index.html | wc -l)
echo "docs stage: ok, ${pages} pages in site/, $(($(date +%s) - start)) s"
