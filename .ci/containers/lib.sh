# Helpers of .ci/containers.sh and .ci/containers/faults.sh (sourced, not run): timed steps, the
# compose command of the CI stack, waiting for healthchecks, talking to the API.

# Every container of the CI stack belongs to this compose project, so the stage never touches a
# developer's own `bayesian-fields` stack or its volumes.
CI_PROJECT=bfields-ci
STEP_TIMES=()

log() { echo "[containers $(date -u +%H:%M:%S)] $*"; }

# step NAME COMMAND...: runs the command, prints its name before and its time after. A failing
# command anywhere inside ends the stage (set -e; the EXIT trap names the step, CURRENT_STEP).
step() {
  local name="$1" start=$SECONDS
  shift
  CURRENT_STEP="$name"
  log ">>> $name"
  "$@"
  local took=$((SECONDS - start))
  STEP_TIMES+=("$(printf '%5ss  %s' "$took" "$name")")
  log "<<< $name: ${took}s"
  CURRENT_STEP=
}

# podman-compose on docker-compose.yml with the stand-ins' override, in the CI project. Dropped
# from its errors: podman without systemd cannot schedule healthchecks and says so on every start
# (wait_healthy runs them instead), and `down` asks for the gpu-worker this stack never starts.
compose() {
  "$PODMAN_COMPOSE" -p "$CI_PROJECT" -f docker-compose.yml -f .ci/containers/compose.standins.yml \
    --profile cpu-only "$@" \
    2> >(grep -v -e 'systemd connection' -e 'connect to syslog' -e "\"${CI_PROJECT}_gpu-worker_1\" found" >&2)
}

container() { echo "${CI_PROJECT}_$1_1"; }  # podman-compose's container name of a service

# wait_healthy TIMEOUT_S SERVICE...: runs each service's own healthcheck (the one its compose
# entry or image declares) every 2 s until all pass; prints how long each took. Docker runs
# healthchecks itself; podman needs systemd timers for that, which a CI machine does not have.
wait_healthy() {
  local deadline=$((SECONDS + $1)) start=$SECONDS svc
  shift
  local pending=("$@")
  while [ ${#pending[@]} -gt 0 ]; do
    local still=()
    for svc in "${pending[@]}"; do
      if podman healthcheck run "$(container "$svc")" >/dev/null 2>&1; then
        log "    $svc healthy after $((SECONDS - start))s"
      else
        still+=("$svc")
      fi
    done
    pending=("${still[@]+"${still[@]}"}")
    [ ${#pending[@]} -eq 0 ] && break
    if [ "$SECONDS" -ge "$deadline" ]; then
      log "    not healthy: ${pending[*]}"
      for svc in "${pending[@]}"; do podman logs --tail 30 "$(container "$svc")" 2>&1 | sed "s/^/    $svc| /"; done
      return 1
    fi
    sleep 2
  done
}

# The compose file's order (depends_on with service_healthy / service_completed_successfully),
# step by step: podman-compose enforces service_healthy only on podman >= 4.6 (Debian 12 has
# 4.3), so the backing services come first and their healthchecks are awaited here.
stack_up() {
  compose up -d postgres redis minio >/dev/null
  wait_healthy 120 postgres redis minio
  compose up -d --no-deps minio-init >/dev/null
  local rc
  rc="$(podman wait "$(container minio-init)")"
  [ "$rc" = 0 ] || { podman logs "$(container minio-init)"; log "minio-init exited $rc"; return 1; }
  compose up -d --no-deps api control cpu-worker gpu-queue-on-cpu >/dev/null
  wait_healthy 240 api control cpu-worker gpu-queue-on-cpu
}

# The client side: the host's CLI (the checkout's venv) against the stack's published API port.
bfields_cli() { BFIELDS_SERVER="$API_URL" BFIELDS_API_KEY="$API_KEY" .venv/bin/bfields "$@"; }

# job_field JOB_ID FIELD: one field of the job's record (GET /v1/jobs/{id}).
job_field() {
  curl -fsS -H "X-API-Key: $API_KEY" "$API_URL/v1/jobs/$1" \
    | python3 -c "import json,sys; print(json.load(sys.stdin).get('$2') or '')"
}

# job_now JOB_ID: "<state> <stage>", or "unknown" while the API does not answer (a restart).
job_now() {
  curl -fsS -H "X-API-Key: $API_KEY" "$API_URL/v1/jobs/$1" 2>/dev/null \
    | python3 -c "import json,sys; j=json.load(sys.stdin); print(j['state'], j.get('stage') or '-')" \
    || echo unknown
}

# wait_for_stage JOB_ID STAGE TIMEOUT_S: until the job is running that stage.
wait_for_stage() {
  local deadline=$((SECONDS + $3))
  until [ "$(job_now "$1")" = "running $2" ]; do
    [ "$SECONDS" -lt "$deadline" ] || { log "job $1 never ran $2 (now: $(job_now "$1"))"; return 1; }
    sleep 0.3
  done
}

# wait_for_state JOB_ID STATE TIMEOUT_S: until the job is in that state; a job that ends in
# another state fails at once, saying why.
wait_for_state() {
  local deadline=$((SECONDS + $3)) now
  while now="$(job_now "$1")" && [ "${now%% *}" != "$2" ]; do
    case "${now%% *}" in
      succeeded | failed | cancelled) log "job $1 ${now%% *}: $(job_field "$1" error)"; return 1 ;;
    esac
    [ "$SECONDS" -lt "$deadline" ] || { log "job $1 still '$now' after $3 s"; return 1; }
    sleep 1
  done
}
