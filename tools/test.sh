#!/usr/bin/env bash
# The whole test suite on a fresh machine: test dependencies, headless Chromium for
# the report-rendering test (Debian package; needs root, else that test skips and
# says why), then pytest. Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
if ! command -v chromium >/dev/null 2>&1 && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    (apt-get update -qq && apt-get install -y -qq --no-install-recommends chromium) \
        || echo "chromium could not be installed; the report-rendering test will skip"
fi
python3 -m venv .venv
.venv/bin/pip install -q -e '.[test]'
exec .venv/bin/python -m pytest "$@"
