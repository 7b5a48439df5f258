#!/bin/sh
# Installs torch into an image's Python, from the source the build arguments name (every
# Dockerfile of the project calls this, so the choice is written once):
#
#   TORCH_WHEELS    a folder of wheels made visible to the build, e.g. a machine without access
#                   to PyTorch's index (CI: `podman build -v /opt/wheels:/torch-wheels:ro
#                   --build-arg TORCH_WHEELS=/torch-wheels`). torch itself comes only from there;
#                   its small pure-Python dependencies from the default index.
#   TORCH_INDEX_URL otherwise: the index torch comes from (each Dockerfile's default: PyTorch's CPU
#                   index for the CPU images, so they carry no CUDA libraries; PyPI for the GPU one).
#   TORCH_VERSION   the release, pinned: a later `pip install` of the project finds it satisfied and
#                   never swaps it for another build.
set -eu
spec="torch==${TORCH_VERSION:?build argument TORCH_VERSION is empty}"
if [ -n "${TORCH_WHEELS:-}" ]; then
  pip install --no-index --find-links "$TORCH_WHEELS" --no-deps "$spec"
  pip install "$spec"  # torch is satisfied now: this fetches only its dependencies
else
  pip install --index-url "${TORCH_INDEX_URL:?build argument TORCH_INDEX_URL is empty}" "$spec"
fi
python -c "import torch; print('torch', torch.__version__, 'installed')"
