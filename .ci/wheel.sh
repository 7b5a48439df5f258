#!/usr/bin/env bash
# CI stage: the project installs and runs like a tool. Builds the wheel, installs it into a clean
# venv under /tmp with the CPU torch, and runs the demo from a folder outside the checkout, so the
# default profile and the tiny CLIP must come from the wheel's package data, not the source tree.
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
work="$(mktemp -d /tmp/bfields-wheel.XXXXXX)"
trap 'rm -rf "$work"' EXIT
unset PYTHONPATH
start=$(date +%s)
step() {
  local t0=$(date +%s)
  echo "+ $*"
  "$@"
  echo "  ($(($(date +%s) - t0)) s)"
}

step python3 -m venv "$work/venv"
step "$work/venv/bin/pip" wheel -q --no-deps --wheel-dir "$work/dist" "$repo"
step "$work/venv/bin/pip" install -q torch==2.13.0 "$work"/dist/bayesian_fields-*.whl
cd "$work"
installed="$("$work/venv/bin/python" -c 'import bayesian_fields_core as m; print(m.__file__)')"
case "$installed" in
  "$work/venv/"*) echo "imported from the wheel: $installed" ;;
  *) echo "wheel stage: bayesian_fields_core imported from $installed, not the clean venv" >&2; exit 1 ;;
esac
# The wheel installs two import packages and no generic top-level `services`.
tops="$(python3 -c 'import sys, zipfile; print(" ".join(sorted({n.split("/")[0] for n in zipfile.ZipFile(sys.argv[1]).namelist() if not n.split("/")[0].endswith(".dist-info")})))' "$work"/dist/bayesian_fields-*.whl)"
echo "wheel top-level entries: $tops"
[ "$tops" = "bayesian_fields_core bayesian_fields_service" ] || { echo "wheel stage: unexpected top-level entries: $tops" >&2; exit 1; }
step "$work/venv/bin/bfields" run "$repo/samples/tabletop" --out "$work/x" --cache-dir "$work/cache" -q
test -s "$work/x/result/summary.json" || { echo "wheel stage: no result/summary.json" >&2; exit 1; }
echo "wheel stage: ok in $(($(date +%s) - start)) s"
