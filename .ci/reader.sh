#!/usr/bin/env bash
# CI stage: the light reader on a robot. Installs the project the way docs/results-format.md
# ("Reading a result without torch") says, into a fresh venv with numpy and nothing else, checks
# that torch is not importable there, and runs that page's Python snippet on a result of the
# bundled sample (made with the main venv's `bfields`, which is $BFIELDS or .venv/bin/bfields).
set -euo pipefail
repo="$(cd "$(dirname "$0")/.." && pwd)"
work="$(mktemp -d /tmp/bfields-reader.XXXXXX)"
trap 'rm -rf "$work"' EXIT
unset PYTHONPATH
bfields="${BFIELDS:-$repo/.venv/bin/bfields}"
page="$repo/docs/results-format.md"
start=$(date +%s)
step() {
  local t0=$(date +%s)
  echo "+ $*"
  "$@"
  echo "  ($(($(date +%s) - t0)) s)"
}
fail() { echo "reader stage: $*" >&2; exit 1; }

# The install lines, as the page gives them (a copy of this checkout for /path/to/bayesian-fields).
install_lines=("pip install --no-deps /path/to/bayesian-fields" "pip install 'numpy>=1.26'")
for line in "${install_lines[@]}"; do
  grep -qF -- "$line" "$page" || fail "$page no longer says '$line': update this script with the page"
done
# pip builds in the source folder (build/, *.egg-info): build from a copy of the checkout's files
# (tracked and new, not ignored) so the checkout is left as it was and nothing stale gets in.
mkdir "$work/src"
(cd "$repo" && git ls-files -z --cached --others --exclude-standard | tar --null -T - --ignore-failed-read -cf -) \
  | tar -xf - -C "$work/src"
step python3 -m venv "$work/robot"
step "$work/robot/bin/pip" install -q --no-deps "$work/src"
step "$work/robot/bin/pip" install -q 'numpy>=1.26'
echo "+ robot venv holds: $("$work/robot/bin/pip" list --format=freeze 2>/dev/null | grep -v '^pip==' | tr '\n' ' ')"
if "$work/robot/bin/python" -c 'import torch' 2>/dev/null; then
  fail "torch is importable in the robot venv: the check would prove nothing"
fi
echo "torch is not importable in the robot venv (as intended)"

# A result of the bundled sample, from the full install.
[ -x "$bfields" ] || fail "no bfields at $bfields (set BFIELDS to the main venv's bfields)"
echo "+ $bfields run $repo/samples/tabletop --out $work/demo --cache-dir $work/cache -q  (output in run.log)"
t0=$(date +%s)
"$bfields" run "$repo/samples/tabletop" --out "$work/demo" --cache-dir "$work/cache" -q >"$work/run.log" 2>&1 \
  || { tail -40 "$work/run.log" >&2; fail "the sample run failed"; }
echo "  ($(($(date +%s) - t0)) s)"

# The page's snippet: the first python block after its "Reading a result without torch" heading,
# run from outside the checkout on that result (its "out/demo" is the folder the demo wrote).
"$work/robot/bin/python" - "$page" "$work/snippet.py" "$work/demo" <<'PY'
import re
import sys

page, out, demo = sys.argv[1:]
text = open(page, encoding="utf-8").read()
section = text.split("### Reading a result without torch", 1)[1]
snippet = re.search(r"```python\n(.*?)```", section, re.S).group(1)
assert '"out/demo"' in snippet, "the snippet no longer reads out/demo: update .ci/reader.sh"
snippet = snippet.replace('"out/demo"', repr(demo))
# What the snippet must not pull in on a robot: checked after it ran, in the same process.
snippet += "\nimport sys\nheavy = sorted(m for m in ('torch', 'scipy') if m in sys.modules)\n"
snippet += "assert not heavy, f'the reader imported {heavy}'\nprint('reader snippet: ok')\n"
open(out, "w", encoding="utf-8").write(snippet)
PY
cd "$work"
echo "+ $work/robot/bin/python snippet.py   (the snippet of docs/results-format.md)"
"$work/robot/bin/python" "$work/snippet.py"
echo "reader stage: ok in $(($(date +%s) - start)) s"
