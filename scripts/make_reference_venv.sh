#!/usr/bin/env bash
# Build the second virtual environment that the reference-architecture models need.
#
# ultralytics (FastSAM) and open_clip import torchvision, and torchvision must match torch
# exactly: the project venv's torch 2.13.0 has no torchvision wheel beside it, so these live in a
# venv of their own with torch 2.14.1 + torchvision 0.29.1 (both from the machine's local wheel
# store), the project installed editable without its torch pin, and the model libraries.
# Usage: scripts/make_reference_venv.sh [VENV_DIR]   (default /tmp/venv-tv; idempotent)
set -euo pipefail
VENV="${1:-${BFIELDS_REFERENCE_VENV:-/tmp/venv-tv}}"
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
start=$(date +%s)
# Already complete (an earlier run): pip's resolver alone costs minutes on a busy machine.
if [ -x "$VENV/bin/python" ] && "$VENV/bin/python" -c "import torchvision, ultralytics, open_clip, onnxruntime, pytest, pytest_timeout, gsply, celery, redis, boto3, sqlalchemy, bayesian_fields_core" 2>/dev/null \
   && [ "$("$VENV/bin/python" -c 'import bayesian_fields_core, pathlib; print(pathlib.Path(bayesian_fields_core.__file__).parents[1])')" = "$ROOT" ]; then
  echo "reference venv ready at $VENV (already complete)"
  exit 0
fi
[ -x "$VENV/bin/python" ] || python3 -m venv "$VENV"
"$VENV/bin/pip" install -q torch==2.14.1 torchvision==0.29.1
# The project without its dependency list (torch is the one above), then that list minus torch,
# read from pyproject.toml with the api and worker extras: the test harness's shared fixtures
# (tests/conftest.py's plugins) import the service, so the reference tests need its packages too.
"$VENV/bin/pip" install -q --no-deps -e "$ROOT"
mapfile -t project_deps < <("$VENV/bin/python" - "$ROOT/pyproject.toml" <<'PY'
import re
import sys
import tomllib

project = tomllib.load(open(sys.argv[1], "rb"))["project"]
extras = project["optional-dependencies"]
for req in dict.fromkeys(project["dependencies"] + extras["api"] + extras["worker"]):
    if re.split(r"[<>=!~\[; ]", req, maxsplit=1)[0].lower() != "torch":
        print(req)
PY
)
"$VENV/bin/pip" install -q "${project_deps[@]}" \
  "onnxruntime>=1.17" "onnx>=1.15" "open_clip_torch>=2.24" "ultralytics>=8.1" \
  "pytest>=8" "pytest-timeout>=2.3"
echo "reference venv ready at $VENV in $(( $(date +%s) - start )) s"
