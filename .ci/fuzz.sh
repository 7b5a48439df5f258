#!/usr/bin/env bash
# Fuzzing stage (issue 12): structure-aware hypothesis cases (PLY, camera files, COLMAP, archives,
# task lists) through the library's validators and the API's upload and job routes over real HTTP.
# Property: a clear InputError / 4xx, never another exception or a 5xx, nothing stored changed.
# Bounded by `timeout`; prints the case counts and fails below MIN_CASES.
set -euo pipefail
cd "$(dirname "$0")/.."
export BFIELDS_FUZZ_SCALE="${BFIELDS_FUZZ_SCALE:-1}"
MIN_CASES="${BFIELDS_FUZZ_MIN_CASES:-10000}"
log="$(mktemp)"
trap 'rm -f "$log"' EXIT
set +e
timeout "${BFIELDS_FUZZ_TIMEOUT_S:-480}" .venv/bin/python -m pytest -q -p no:cacheprovider -m fuzz \
  -W ignore::UserWarning tests/fuzz 2>&1 | tee "$log"
status=${PIPESTATUS[0]}
set -e
total="$(awk '$2 == "total" {print $1}' "$log" | tail -1)"
echo "fuzz: ${total:-0} cases (minimum ${MIN_CASES})"
if [ "$status" -ne 0 ]; then exit "$status"; fi
if [ "${BFIELDS_FUZZ_SCALE}" = "1" ] && [ "${total:-0}" -lt "$MIN_CASES" ]; then
  echo "fuzz: fewer cases than ${MIN_CASES}" >&2
  exit 1
fi
