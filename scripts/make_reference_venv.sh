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
if [ -x "$VENV/bin/python" ] && "$VENV/bin/python" -c "import torchvision, ultralytics, open_clip, onnxruntime, pytest, bayesian_fields_core" 2>/dev/null \
   && [ "$("$VENV/bin/python" -c 'import bayesian_fields_core, pathlib; print(pathlib.Path(bayesian_fields_core.__file__).parents[1])')" = "$ROOT" ]; then
  echo "reference venv ready at $VENV (already complete)"
  exit 0
fi
[ -x "$VENV/bin/python" ] || python3 -m venv "$VENV"
"$VENV/bin/pip" install -q torch==2.14.1 torchvision==0.29.1
# The project without its dependency list (it pins the other torch), then that list minus torch.
"$VENV/bin/pip" install -q --no-deps -e "$ROOT"
"$VENV/bin/pip" install -q "numpy>=1.26" "scipy>=1.11" "numba>=0.60" "plyfile>=1.0" "pillow>=10" \
  "scikit-image>=0.22" "pyyaml>=6" "pydantic>=2.6" "pydantic-settings>=2.2" "transformers>=4.40" \
  "safetensors>=0.4" "tokenizers>=0.15" "rich>=13" "httpx>=0.27" \
  "onnxruntime>=1.17" "onnx>=1.15" "open_clip_torch>=2.24" "ultralytics>=8.1" \
  "pytest>=8" "pytest-timeout>=2.3"
echo "reference venv ready at $VENV in $(( $(date +%s) - start )) s"
