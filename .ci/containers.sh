#!/usr/bin/env bash
# CI stage (issue 29): the service's images built from the project's Dockerfiles and the compose
# stack run for real with podman, on a machine that can pull no image:
#   tools      podman, runc, debootstrap (apt) and podman-compose (PyPI, a venv of its own) when
#              missing, and a containers.conf for this machine (runc, cgroupfs, no default ulimits)
#   base       the stand-in python:3.11-slim-bookworm, made with debootstrap (.ci/containers/base.sh)
#   stand-ins  Redis, PostgreSQL and an S3 server for the compose file's third-party images
#   images     api, worker-cpu (services/Dockerfile), worker-gpu's Python layers on the stand-in base
#   stack      docker-compose.yml + .ci/containers/compose.standins.yml up, every healthcheck passing
#   sample     `bfields submit samples/tabletop --wait` + `bfields fetch` from the host, compared with
#              the CLI's local run of the same sample (.ci/containers/compare_answers.py)
#   faults     a worker killed mid-stage, down + up keeping the data, a graceful stop (faults.sh)
#   down -v    and the volumes are gone
# Every step prints its name and time; any failure fails the stage, and the stack is always taken
# down. Bounded by BFIELDS_CONTAINERS_TIMEOUT_S (default 1800 s). Needs root (debootstrap,
# podman's networks) and apt. Kept between runs outside the checkout, in BFIELDS_CONTAINERS_CACHE
# (default /var/cache/bfields-containers): the base's root file system, the podman-compose venv,
# containers.conf, the torch wheel; images and their layers stay in podman's storage.
# BFIELDS_CONTAINERS_NO_CACHE=1 builds every image without the layer cache (cold build times).
set -euo pipefail
cd "$(dirname "$0")/.."
if [ -z "${BFIELDS_CONTAINERS_BOUNDED:-}" ]; then
  export BFIELDS_CONTAINERS_BOUNDED=1
  exec timeout --kill-after=60 "${BFIELDS_CONTAINERS_TIMEOUT_S:-1800}" "$0" "$@"
fi
source .ci/containers/lib.sh

CACHE="${BFIELDS_CONTAINERS_CACHE:-/var/cache/bfields-containers}"
PODMAN_COMPOSE="$CACHE/podman-compose-venv/bin/podman-compose"
PODMAN_COMPOSE_VERSION=1.6.0
TORCH_VERSION=2.13.0
API_KEY=dev-key-change-me # .env.example's key; the stack gets .env.example's settings
WORK="$(mktemp -d /tmp/bfields-containers.XXXXXX)"
STAGE_START=$SECONDS
mkdir -p "$CACHE"

cleanup() {
  local rc=$?
  if [ -n "${STACK_STARTED:-}" ]; then
    if [ "$rc" -ne 0 ]; then
      podman ps -a --filter "label=io.podman.compose.project=$CI_PROJECT" --format '{{.Names}}  {{.Status}}' || true
    fi
    compose down -v >/dev/null 2>&1 || true
  fi
  [ -z "${WROTE_ENV:-}" ] || rm -f .env
  [ -z "${MADE_MODELS_DIR:-}" ] || rmdir models 2>/dev/null || true
  rm -rf "$WORK"
  [ "$rc" -eq 0 ] || log "containers stage FAILED (exit $rc) in step '${CURRENT_STEP:-?}' after $((SECONDS - STAGE_START))s"
}
trap cleanup EXIT
trap 'exit 124' TERM INT # `timeout` ends the stage with TERM: still take the stack down

[ "$(id -u)" = 0 ] || { log "needs root (debootstrap, rootful podman)"; exit 1; }

tools() {
  local missing=()
  for tool in podman runc debootstrap; do command -v "$tool" >/dev/null || missing+=("$tool"); done
  if [ ${#missing[@]} -gt 0 ]; then
    log "installing ${missing[*]}"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
  fi
  if [ ! -x "$PODMAN_COMPOSE" ] || ! "$PODMAN_COMPOSE" --version | grep -q "$PODMAN_COMPOSE_VERSION"; then
    python3 -m venv "$CACHE/podman-compose-venv"
    "$CACHE/podman-compose-venv/bin/pip" install -q "podman-compose==$PODMAN_COMPOSE_VERSION" 2>&1 | grep -v "^WARNING: Location" || true
  fi
  # crun (podman's default where installed) fails here ("cgroups in hybrid mode not supported");
  # without systemd the cgroup manager is cgroupfs; the default ulimits make every start fail with
  # "setrlimit RLIMIT_NOFILE: Operation not permitted". Only podman run by this stage reads this file.
  printf '%s\n' '[containers]' 'default_ulimits = []' '[engine]' 'runtime = "runc"' 'cgroup_manager = "cgroupfs"' \
    >"$CACHE/containers.conf"
  export CONTAINERS_CONF="$CACHE/containers.conf"
  log "$(podman --version), $(runc --version | head -1), $("$PODMAN_COMPOSE" --version | head -1)"
}

# The CPU torch wheel that `pip install torch==2.13.0` takes on this machine (pip's find-links),
# copied to the cache and mounted into the builds: these machines cannot reach PyTorch's index. On
# a machine without one, the builds use the Dockerfiles' default, PyTorch's CPU index.
torch_wheel() {
  TORCH_BUILD_ARGS=()
  mkdir -p "$CACHE/torch-wheels"
  if ! ls "$CACHE/torch-wheels"/torch-"$TORCH_VERSION"+cpu-cp311-*.whl >/dev/null 2>&1; then
    python3 -m pip download -q --no-index --no-deps --only-binary=:all: --python-version 3.11 \
      -d "$CACHE/torch-wheels" "torch==$TORCH_VERSION" 2>/dev/null || true
  fi
  if ls "$CACHE/torch-wheels"/torch-"$TORCH_VERSION"+cpu-cp311-*.whl >/dev/null 2>&1; then
    TORCH_BUILD_ARGS=(-v "$CACHE/torch-wheels:/torch-wheels:ro" --build-arg TORCH_WHEELS=/torch-wheels)
    log "torch from $(ls "$CACHE/torch-wheels"/torch-"$TORCH_VERSION"+cpu-cp311-*.whl)"
  else
    log "no local CPU torch wheel: the builds use the Dockerfiles' default index"
  fi
}

# build_image NAME TAG PODMAN-BUILD-ARGS...: one image, its build time and size recorded.
IMAGE_LINES=()
build_image() {
  local name="$1" tag="$2" start=$SECONDS
  shift 2
  local cache_args=()
  [ -n "${BFIELDS_CONTAINERS_NO_CACHE:-}" ] && cache_args=(--no-cache)
  podman build "${cache_args[@]+"${cache_args[@]}"}" -t "$tag" "$@" >"$WORK/build-$name.log" 2>&1 \
    || { tail -40 "$WORK/build-$name.log"; return 1; }
  local size
  size="$(podman image inspect -f '{{.Size}}' "$tag" | numfmt --to=iec-i --suffix=B --format='%.2f')"
  IMAGE_LINES+=("$(printf '%-22s %8s  built in %4ss  %s' "$name" "$size" "$((SECONDS - start))" "$tag")")
  log "    $name: $size in $((SECONDS - start))s"
}

standins() {
  local s
  for s in redis postgres s3; do
    build_image "stand-in $s" "localhost/bfields-standin/$s:latest" -f ".ci/containers/$s.Containerfile" .ci/containers
  done
}

images() {
  build_image api bayesian-fields/api:latest -f services/Dockerfile --target api "${TORCH_BUILD_ARGS[@]}" .
  build_image worker-cpu bayesian-fields/worker-cpu:latest -f services/Dockerfile --target worker-cpu \
    "${TORCH_BUILD_ARGS[@]}" .
  # The GPU image's Python layers (pip, COPY, user, entrypoint) on the stand-in base instead of
  # NVIDIA's CUDA images, with the CPU torch and gsplat built without its CUDA kernels: CUDA itself
  # is not exercised here. Tagged apart, so nothing mistakes it for a GPU image.
  build_image "worker-gpu (stand-in)" bayesian-fields/worker-gpu:standin-base -f services/worker/Dockerfile.gpu \
    --build-arg CUDA_DEVEL_IMAGE=python:3.11-slim-bookworm --build-arg CUDA_RUNTIME_IMAGE=python:3.11-slim-bookworm \
    --build-arg GSPLAT_BUILD_NO_CUDA=1 "${TORCH_BUILD_ARGS[@]}" .
}

# The GPU image's entrypoint and installed packages: its CMD's program with the worker app
# imported, gsplat importable, the runtime user able to write its caches.
gpu_image_smoke() {
  podman run --rm --network none bayesian-fields/worker-gpu:standin-base sh -c '
    set -e
    test "$(id -u)" = 10001
    celery -A bayesian_fields_service.worker.celery_app report | grep -q "^software -> celery"
    python -c "import gsplat, bayesian_fields_service.worker.celery_app; print(\"gsplat\", gsplat.__version__)"
    touch /var/cache/bfields/w /app/.numba-cache/w
    echo "worker-gpu (stand-in): celery $(celery --version | cut -d" " -f1) with the worker app, gsplat, user 10001 writing its caches"'
}

env_file() {
  [ ! -e .env ] || { log ".env exists in the checkout: this stage writes its own; move yours aside"; return 1; }
  cat .env.example .ci/containers/ci.env >.env
  WROTE_ENV=1
  # podman-compose (like Docker) makes the models folder the compose file mounts when it is absent
  [ -e models ] || MADE_MODELS_DIR=1
  API_URL="http://127.0.0.1:$(sed -n 's/^BFIELDS_API_PORT=//p' .env | tail -1)"
}

up() {
  STACK_STARTED=1
  compose down -v >/dev/null 2>&1 || true # a stack left by an earlier run that was killed
  stack_up
  # the non-root users can write every volume they mount
  podman exec "$(container cpu-worker)" sh -c 'touch /var/cache/bfields/.w && rm /var/cache/bfields/.w'
  podman exec "$(container gpu-queue-on-cpu)" sh -c 'touch /var/cache/bfields/.w && rm /var/cache/bfields/.w'
}

sample() {
  if [ ! -s "$WORK/local/result/summary.json" ]; then
    .venv/bin/bfields run samples/tabletop --out "$WORK/local" --cache-dir "$WORK/local-cache" -q >"$WORK/local.log" 2>&1 \
      || { tail -20 "$WORK/local.log"; return 1; }
  fi
  local start=$SECONDS
  bfields_cli submit samples/tabletop --tasks samples/tabletop/tasks.yaml --wait >"$WORK/job" 2>"$WORK/submit.log" \
    || { cat "$WORK/submit.log"; return 1; }
  JOB="$(head -1 "$WORK/job")"
  log "    job $JOB succeeded in $((SECONDS - start))s (upload, perceive, fuse, cluster)"
  bfields_cli fetch "$JOB" --out "$WORK/fetched" 2>"$WORK/fetch.log" || { cat "$WORK/fetch.log"; return 1; }
  .venv/bin/python .ci/containers/compare_answers.py "$WORK/local" "$WORK/fetched"
}

down_v() {
  compose down -v >/dev/null
  STACK_STARTED=
  local left
  left="$(podman volume ls -q --filter "label=io.podman.compose.project=$CI_PROJECT")"
  [ -z "$left" ] || { log "volumes left after down -v: $left"; return 1; }
  log "    containers and volumes of $CI_PROJECT removed"
}

if [ ! -x .venv/bin/bfields ]; then # the README's install (.ci/run has made it by now)
  step "venv (README install)" bash -c "python3 -m venv .venv && .venv/bin/pip install -q torch==$TORCH_VERSION -e '.[api,worker,dev]'"
fi
step "tools" tools
export CONTAINERS_CONF="$CACHE/containers.conf"
step "base image" bash .ci/containers/base.sh "$CACHE"
step "torch wheel" torch_wheel
step "stand-in images" standins
step "project images" images
step "worker-gpu image smoke" gpu_image_smoke
step ".env" env_file
step "stack up, every healthcheck passing" up
step "sample through the stack vs the local CLI" sample
source .ci/containers/faults.sh # three steps, each printing what it proved
step "down -v" down_v

log "images (size, build time this run):"
printf '    %s\n' "${IMAGE_LINES[@]}"
log "steps:"
printf '  %s\n' "${STEP_TIMES[@]}"
log "containers stage passed in $((SECONDS - STAGE_START))s"
