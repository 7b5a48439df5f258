# The stack under faults (issue 29, item 3); sourced by .ci/containers.sh once the sample's job
# ($JOB, fetched into $WORK/fetched) has succeeded. Each check prints what it proved.
#
# The jobs here change a parameter of the fuse stage's cache key (depth_tolerance_relative, 0.03
# by default), so their fuse stage really computes (~15 s here) instead of reading the cache the
# sample's job filled: the faults land in the middle of real work.

fuse_params() {  # fuse_params VALUE -> a parameters file
  echo "depth_tolerance_relative: $1" >"$WORK/params-$1.yaml"
  echo "$WORK/params-$1.yaml"
}

submit_sample() {  # submit_sample PARAMS_FILE -> job id (the CLI's upload, not waiting)
  bfields_cli submit samples/tabletop --tasks samples/tabletop/tasks.yaml --parameters "$1" 2>>"$WORK/submit.log" | head -1
}

# 1. A worker dies in the middle of a stage (SIGKILL to its main process, as the OOM killer would
#    send): the restart policy brings the container back, the control process re-enqueues the
#    stage once its lock expires, and the job succeeds.
kill_worker_mid_stage() {
  local worker job restarts pid start killed_at
  worker="$(container gpu-queue-on-cpu)"
  job="$(submit_sample "$(fuse_params 0.031)")"
  wait_for_stage "$job" fuse 180
  sleep 2
  restarts="$(podman inspect -f '{{.RestartCount}}' "$worker")"
  pid="$(podman inspect -f '{{.State.Pid}}' "$worker")"
  killed_at="$(date -u +%s.%N)"
  kill -KILL "$pid"
  start=$SECONDS
  until [ "$(podman inspect -f '{{.RestartCount}} {{.State.Status}}' "$worker")" = "$((restarts + 1)) running" ]; do
    [ $((SECONDS - start)) -lt 60 ] || { log "worker not restarted"; return 1; }
    sleep 0.5
  done
  log "    kill: worker killed during fuse of $job; its restart policy restarted it after $((SECONDS - start))s"
  wait_for_state "$job" succeeded 300
  # the fuse stage that counts is a new run, started after the kill, from the stage's inputs
  curl -fsS -H "X-API-Key: $API_KEY" "$API_URL/v1/jobs/$job" | python3 -c '
import datetime, json, sys
fuse = json.load(sys.stdin)["stage_reports"]["fuse"]
start = datetime.datetime.fromisoformat(fuse["started_at"]).timestamp()
assert start > float(sys.argv[1]), "the fuse stage of record started before the kill"
print(f"    kill: fuse ran again from its inputs, from {start - float(sys.argv[1]):.1f} s after the kill")
' "$killed_at"
  log "    kill: $job succeeded $((SECONDS - start))s after the kill"
}

# 2. `stop` (SIGTERM, then SIGKILL after stop_grace_period: 2 min) during a stage: celery's warm
#    shutdown lets the stage finish and the container exits 0 well within the grace period. With
#    the GPU-queue worker still stopped, the job then completes on the CPU worker: the stage was
#    finished, not abandoned to be run again.
graceful_stop() {
  local worker job start took code stopped_at
  worker="$(container gpu-queue-on-cpu)"
  job="$(submit_sample "$(fuse_params 0.032)")"
  wait_for_stage "$job" fuse 180
  sleep 1
  stopped_at="$(date -u +%s.%N)"
  start=$SECONDS
  compose stop gpu-queue-on-cpu >/dev/null
  took=$((SECONDS - start))
  code="$(podman inspect -f '{{.State.ExitCode}}' "$worker")"
  [ "$code" = 0 ] || { log "stop: worker exited $code (137: killed at the end of the grace period)"; return 1; }
  wait_for_state "$job" succeeded 120
  # the job's own record of its fuse stage: it had started before the stop and ended after it
  curl -fsS -H "X-API-Key: $API_KEY" "$API_URL/v1/jobs/$job" | python3 -c '
import datetime, json, sys
fuse = json.load(sys.stdin)["stage_reports"]["fuse"]
start, end = (datetime.datetime.fromisoformat(fuse[k]).timestamp() for k in ("started_at", "finished_at"))
stop = float(sys.argv[1])
assert start < stop < end, f"fuse ran {start:.1f}..{end:.1f}, the stop came at {stop:.1f}"
print(f"    stop: fuse had run {stop - start:.1f} s when the stop came and finished {end - stop:.1f} s later")
' "$stopped_at"
  log "    stop: worker stopped during fuse of $job in ${took}s (grace 120 s), exit 0; $job then succeeded with the GPU-queue worker still stopped"
  compose start gpu-queue-on-cpu >/dev/null
  wait_healthy 240 gpu-queue-on-cpu
}

# 3. `down` (containers and network removed, volumes kept) then `up`: the records, the scenes and
#    the results are still there; the sample's result downloads byte for byte as before, and a new
#    job on the sample's scene (no new upload) succeeds.
down_up_keeps_data() {
  local scene job
  scene="$(job_field "$JOB" scene_id)"
  local start=$SECONDS
  # Compose's order: the services before what they depend on (podman-compose's own `stop` / `down`
  # stop everything at once, and a worker whose broker went first takes ~30 s to give up on it).
  compose stop api control cpu-worker gpu-queue-on-cpu >/dev/null
  compose stop >/dev/null
  # how each container ended: 0 a clean exit on SIGTERM, 137 killed at the end of its grace period
  log "    down: stopped in $((SECONDS - start))s; exit codes: $(podman ps -a --filter "label=io.podman.compose.project=$CI_PROJECT" \
    --format '{{.Names}}={{.ExitCode}}' | sed "s/${CI_PROJECT}_//; s/_1=/=/" | sort | tr '\n' ' ')"
  compose down >/dev/null
  [ -z "$(podman ps -aq --filter "label=io.podman.compose.project=$CI_PROJECT")" ] \
    || { log "down left containers"; return 1; }
  log "    down: containers removed, volumes kept: $(podman volume ls -q --filter "label=io.podman.compose.project=$CI_PROJECT" | tr '\n' ' ')"
  stack_up
  [ "$(job_field "$JOB" state)" = succeeded ] || { log "job $JOB lost its record"; return 1; }
  bfields_cli fetch "$JOB" --out "$WORK/fetched-again" 2>>"$WORK/fetch.log"
  diff -r -x result.json "$WORK/fetched" "$WORK/fetched-again" >/dev/null \
    || { log "the result of $JOB changed across down/up"; return 1; }
  job="$(curl -fsS -H "X-API-Key: $API_KEY" -H 'Content-Type: application/json' \
    -d "{\"scene_id\": \"$scene\", \"tasks\": [\"get the cyan cube\"]}" "$API_URL/v1/jobs" \
    | python3 -c 'import json,sys; print(json.load(sys.stdin)["id"])')"
  wait_for_state "$job" succeeded 300
  log "    down/up: $JOB still succeeded, its result identical; new job $job on scene $scene succeeded"
}

step "fault: worker killed mid-stage" kill_worker_mid_stage
step "fault: graceful stop mid-stage" graceful_stop
step "fault: down + up keeps scenes and results" down_up_keeps_data
