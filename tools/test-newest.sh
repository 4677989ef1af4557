#!/usr/bin/env bash
# The drift check (.ci/run's last step): pyproject.toml's version ranges, installed at the
# newest versions they allow (tools/install.sh --newest, in .venv-newest), must still pass
# the fast tier and print what the docs show (tests/test_docs_commands.py). A failure here
# means a new release of a dependency changed rig's results or broke it: refresh the lock
# (docs/performance.md, "The lock file"), then the docs (tools/refresh_docs.py), or narrow
# the range in pyproject.toml. The installed versions are printed first.
set -euo pipefail
cd "$(dirname "$0")/.."
bash tools/install.sh --newest
echo "newest versions (differing from requirements.lock):"
.venv-newest/bin/python - <<'PY'
import re
from pathlib import Path
locked = dict(re.findall(r"^([A-Za-z0-9_.\-]+)==(\S+)", Path("requirements.lock").read_text(), re.M))
norm = lambda n: re.sub(r"[-_.]+", "-", n).lower()
locked = {norm(k): v for k, v in locked.items()}
for line in Path(".venv-newest/versions.txt").read_text().splitlines():
    name, _, version = line.partition("==")
    if version and locked.get(norm(name)) != version:
        print(f"  {name} {version} (lock: {locked.get(norm(name), 'not locked')})")
PY
exec .venv-newest/bin/python -m pytest -m "not slow or docs" -n auto --dist loadfile "$@"
