#!/usr/bin/env bash
# Browser tests (tests/services/api/ui: the /ui page against the real stack; tests/core/viewer: `bfields view`) in
# headless Debian chromium driven by Playwright. Installs chromium with apt when it is missing, so
# the tests run instead of skipping. Usage: .ci/browser.sh [--install-only] (tests need .venv).
set -euo pipefail
cd "$(dirname "$0")/.."
if [ ! -x /usr/bin/chromium ] && command -v apt-get >/dev/null 2>&1; then
  (apt-get update -qq && apt-get install -y -qq chromium >/dev/null) || echo "warning: could not install chromium"
fi
echo "browser tests: $(/usr/bin/chromium --version 2>/dev/null || echo 'no /usr/bin/chromium: they will skip')"
if [ "${1:-}" = "--install-only" ]; then exit 0; fi  # CI: the README's test command runs them
echo "running: .venv/bin/python -m pytest -q -rs tests/services/api/ui tests/core/viewer"
.venv/bin/python -m pytest -q -rs tests/services/api/ui tests/core/viewer
