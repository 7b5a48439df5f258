#!/usr/bin/env bash
# One-command check of the GPU path on the scale scene: installs what it needs, builds the
# reference models, prints render / fuse / perceive ms per frame, cluster s and the total, and the
# fidelity of our torch rasteriser against gsplat on the same splat and cameras (RGB PSNR, expected
# and median depth agreement, Jaccard of the mask-to-Gaussian associations, fused log-odds
# agreement), so one short GPU run answers both speed and fidelity.
#
#   bench/gpu_check.sh          on a GPU machine: 400k Gaussians, 300 frames at 640x480, 26 tasks;
#                               gsplat, FastSAM-x + CLIP ViT-B/16 at fp16; fidelity on 10 frames
#   bench/gpu_check.sh --cpu    smoke mode: the same code at a small size on the CPU (run it
#                               before spending GPU time: it catches typos and broken installs);
#                               gsplat cannot run there, so the fidelity comparison says it is
#                               skipped and runs with the torch rasteriser on both sides
# Extra arguments go to bench/gpu_check.py (e.g. --fidelity-frames 20).
#
# Environment: BFIELDS_REFERENCE_VENV (default /tmp/venv-tv), GPU_CHECK_WORK (default
# /tmp/bfields-gpu-check), GPU_CHECK_TIMEOUT (seconds for the whole run, default 540).
# Installs: torch 2.14.1 + torchvision 0.29.1 from the local wheel store, the project, ultralytics,
# open_clip, onnx/onnxruntime (scripts/make_reference_venv.sh), and on a GPU gsplat from PyPI.
set -euo pipefail
MODE=gpu
if [ "${1:-}" = "--cpu" ]; then MODE=cpu; shift; fi
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
VENV="${BFIELDS_REFERENCE_VENV:-/tmp/venv-tv}"
WORK="${GPU_CHECK_WORK:-/tmp/bfields-gpu-check}"
LIMIT="${GPU_CHECK_TIMEOUT:-540}"
export HOME="$WORK/home" YOLO_CONFIG_DIR="$WORK/yolo" HF_HOME="$WORK/hf" HF_HUB_OFFLINE=1 YOLO_OFFLINE=1 PYTHONUNBUFFERED=1
mkdir -p "$WORK" "$HOME"

run() {
  local t0; t0=$(date +%s)
  echo "== venv ($VENV)"
  bash "$ROOT/scripts/make_reference_venv.sh" "$VENV" | tail -1
  if [ "$MODE" = gpu ]; then
    echo "== gsplat"
    "$VENV/bin/pip" install -q "gsplat>=1.0" | tail -1 || true
    "$VENV/bin/python" -c "import torch, gsplat; assert torch.cuda.is_available(), 'no CUDA'; print('gsplat', gsplat.__version__, 'on', torch.cuda.get_device_name())"
  fi
  echo "== reference models"
  local models="$WORK/models-$MODE"
  if [ ! -f "$models/profiles/reference-fastsam-hf-clip.yaml" ]; then
    local scales=x; [ "$MODE" = cpu ] && scales=s
    "$VENV/bin/python" "$ROOT/scripts/make_reference_models.py" --out "$models" --fastsam "$scales" --minimal \
      --device "$([ "$MODE" = gpu ] && echo cuda || echo cpu)" | grep -E "^  [a-zA-Z]|^done"
  fi
  echo "== measure (setup took $(( $(date +%s) - t0 )) s)"
  local flag=(); [ "$MODE" = cpu ] && flag=(--cpu)
  cd "$ROOT" && PYTHONPATH="$ROOT" "$VENV/bin/python" bench/gpu_check.py --models "$models" \
    --workdir "$WORK/scene-$MODE" "${flag[@]}" "$@"
}
export -f run
export MODE ROOT VENV WORK
timeout "$LIMIT" bash -c 'run "$@"' _ "$@"
