#!/usr/bin/env bash
# Set-up on a fresh machine with Python 3.11: the virtual environment .venv with every
# dependency at the version of requirements.lock (hash-checked; the versions the docs'
# numbers were made with), then rig itself, editable, built with the locked setuptools.
#
#   bash tools/install.sh            # .venv from the lock (the README, tools/test.sh, CI)
#   bash tools/install.sh --newest   # .venv-newest: the newest versions pyproject.toml
#                                    # allows, for the drift check (tools/test-newest.sh)
#
# The lock is made by `uv pip compile` (docs/performance.md, "The lock file"); uv installs
# from it (pip alone can too: pip install --require-hashes -r requirements.lock).
set -euo pipefail
cd "$(dirname "$0")/.."
if [ "${1:-}" = "--newest" ]; then
    rm -rf .venv-newest
    python3 -m venv .venv-newest
    .venv-newest/bin/pip install -q --upgrade pip
    .venv-newest/bin/pip install -q --upgrade --upgrade-strategy eager -e '.[test]'
    .venv-newest/bin/pip freeze --exclude-editable > .venv-newest/versions.txt
    exit 0
fi
python3 -m venv .venv
# pip installs uv (tools/installer.lock, hash-checked); uv installs the lock, compiling the
# bytecode as pip would, then rig itself
.venv/bin/pip install -q --require-hashes -r tools/installer.lock
.venv/bin/uv pip install -q --python .venv/bin/python --compile-bytecode --require-hashes \
    -r requirements.lock
.venv/bin/uv pip install -q --python .venv/bin/python --no-deps --no-build-isolation -e .
