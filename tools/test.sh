#!/usr/bin/env bash
# The README's test command: set-up from the lock (tools/install.sh), then pytest; with
# --all, headless Chromium first for the report-rendering test (Debian package; needs
# root, else that test skips and says why).
#
#   bash tools/test.sh           # the fast tier: every test not marked slow, on every
#                                # core (pytest-xdist, a file per worker; <= 5 min on 2
#                                # cores, compile included; docs/performance.md)
#   bash tools/test.sh --all     # the whole suite (CI runs this too: .ci/run)
#   bash tools/test.sh ARGS      # pytest's own arguments, e.g. -k yaml, -m slow
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/install.sh
if [ $# -eq 0 ]; then
    exec .venv/bin/python -m pytest -m "not slow" -n auto --dist loadfile
fi
if [ "$1" = "--all" ]; then
    shift
    if ! command -v chromium >/dev/null 2>&1 && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
        (apt-get update -qq && apt-get install -y -qq --no-install-recommends chromium) \
            || echo "chromium could not be installed; the report-rendering test will skip"
    fi
fi
exec .venv/bin/python -m pytest "$@"
