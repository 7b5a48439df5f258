#!/usr/bin/env bash
# CI stage: mypy over both import packages (`bayesian_fields_core`, and `services/` under its
# import name `bayesian_fields_service`), configured in pyproject.toml ([tool.mypy]); zero errors.
# Installs mypy and the stub packages (the dev extra's type-checking entries) into the project venv
# that `.ci/run` made, runs bounded by `timeout`, prints the command, the error count and the time.
# Run it by hand the same way: `bash .ci/typecheck.sh` (a second run reuses .mypy_cache).
set -euo pipefail
cd "$(dirname "$0")/.."
py=.venv/bin/python
start=$(date +%s)

# The type-checking entries of the dev extra (mypy, types-*, *-stubs), so the list lives once.
mapfile -t checker < <("$py" - <<'PY'
import tomllib
dev = tomllib.load(open("pyproject.toml", "rb"))["project"]["optional-dependencies"]["dev"]
for req in dev:
    name = req.split("[")[0].split(">")[0].split("=")[0].strip()
    if name == "mypy" or name.startswith("types-") or name.endswith("-stubs") or name == "celery-types":
        print(req)
PY
)
echo "+ $py -m pip install -q ${checker[*]}"
"$py" -m pip install -q "${checker[@]}"

# mypy finds packages by folder name and cannot follow the editable install's import hook, so
# `services/` is made visible as `bayesian_fields_service` through a link in build/typecheck
# (mypy_path in pyproject.toml). Paths in the report are written back as services/...
mkdir -p build/typecheck
ln -sfn ../../services build/typecheck/bayesian_fields_service

cmd=("$py" -m mypy -p bayesian_fields_core -p bayesian_fields_service)
echo "+ ${cmd[*]}"
log="$(mktemp)"
trap 'rm -f "$log"' EXIT
set +e
timeout "${BFIELDS_TYPECHECK_TIMEOUT_S:-540}" "${cmd[@]}" 2>&1 \
  | sed 's#build/typecheck/bayesian_fields_service/#services/#g' | tee "$log"
status=${PIPESTATUS[0]}
set -e
errors="$(grep -c ': error: ' "$log" || true)"
echo "typecheck: ${errors} error(s), $(($(date +%s) - start)) s ($("$py" -m mypy --version))"
if [ "$status" -eq 124 ]; then echo "typecheck: timed out" >&2; fi
exit "$status"
