#!/usr/bin/env bash
# CI stage: the reference-architecture models (ViT-B/16 through HF / open_clip / ONNX, FastSAM-x/-s)
# in the second venv that ultralytics and open_clip need (scripts/make_reference_venv.sh; measured
# 408 s to build from nothing on the 2-core dev machine, under the 10-minute bar), then
# tests/reference_models on them, then bench/gpu_check.sh --cpu. Bounded by its own timeout.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV="${BFIELDS_REFERENCE_VENV:-/tmp/venv-tv}"
WORK="$(mktemp -d /tmp/bfields-reference-ci.XXXXXX)"
export HOME="$WORK/home" YOLO_CONFIG_DIR="$WORK/yolo" HF_HOME="$WORK/hf" HF_HUB_OFFLINE=1 YOLO_OFFLINE=1
timeout "${REFERENCE_CI_TIMEOUT:-2400}" bash -c '
  set -euo pipefail
  bash scripts/make_reference_venv.sh "$0"
  "$0/bin/python" scripts/make_reference_models.py --out "$1/models" | grep -E "^  [a-zA-Z]|^done"
  BFIELDS_REFERENCE_MODELS="$1/models" PYTHONPATH="$PWD" "$0/bin/python" -m pytest -q -p no:cacheprovider tests/reference_models
  echo "--- bench/gpu_check.sh --cpu (the GPU check, smoke size, so that a GPU run never meets a broken script)"
  BFIELDS_REFERENCE_VENV="$0" GPU_CHECK_WORK="$1/gpu-check" bash bench/gpu_check.sh --cpu
' "$VENV" "$WORK"
rm -rf "$WORK"
