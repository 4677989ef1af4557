"""Each command imports what it uses (issue 16): checked in a fresh interpreter."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.interpreter  # what these tests cost (pyproject.toml)

ROOT = Path(__file__).resolve().parents[1]
# what no light command needs: numerical libraries simulate does not use, plotting,
# the analysis package, the rig's hardware and service layers; numba's compiler
# registries (a cached blow loads without them: rig.model.cache_loading) and the
# scipy.linalg they import; pydantic (typer 0.29's option coercion: pinned below it);
# rich's progress bar (only on a terminal)
NOT_FOR_SIMULATE = ("scipy.optimize", "scipy.integrate", "scipy.signal", "scipy.linalg",
                    "numba.np.arraymath", "numba.np.linalg", "pydantic", "rich.progress",
                    "matplotlib",
                    "plotly", "pandas", "xarray", "SALib", "rig.analysis", "rig.sim_backend",
                    "rig.services.run", "rig.services.diagnose", "rig.calibration",
                    "nidaqmx", "serial")
NOT_FOR_LIGHT = NOT_FOR_SIMULATE + ("numba", "scipy", "rig.model", "rig.services.simulate")

_PROBE = """
import json, runpy, sys
sys.argv = ["rig", *json.loads(sys.argv[1])]
code = 0
try:
    runpy.run_module("rig", run_name="__main__")
except SystemExit as exc:
    code = exc.code or 0
print("MODULES" + json.dumps({"code": code, "modules": sorted(sys.modules)}))
"""


def loaded(args: list[str], cache: Path, cwd: Path) -> set[str]:
    """The modules a fresh ``python -m rig ARGS`` has imported when it ends (exit 0)."""
    env = {**os.environ, "RIG_CACHE_DIR": str(cache)}
    proc = subprocess.run([sys.executable, "-c", _PROBE, json.dumps(args)], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=600)
    line = next((x for x in proc.stdout.splitlines() if x.startswith("MODULES")), None)
    assert line is not None, proc.stdout + proc.stderr
    data = json.loads(line[len("MODULES"):])
    assert data["code"] == 0, proc.stdout + proc.stderr
    return set(data["modules"])


def heavy(modules: set[str], names: tuple[str, ...]) -> list[str]:
    return sorted(m for m in modules if any(m == n or m.startswith(n + ".") for n in names))


@pytest.fixture(scope="module")
def simulated(tmp_path_factory) -> tuple[Path, Path, set[str]]:
    """A run file written by ``rig simulate`` (twice: the second finds the rest state
    cached) and the modules the second run imported."""
    work = tmp_path_factory.mktemp("imports")
    cache = work / "cache"
    args = ["simulate", str(ROOT / "profiles" / "forte.yaml"), "--duration", "0.05",
            "--out"]
    loaded(args + [str(work / "first.h5")], cache, work)
    mods = loaded(args + [str(work / "second.h5")], cache, work)
    return work, cache, mods


@pytest.mark.slow
def test_simulate_imports_only_what_it_uses(simulated):
    _, _, mods = simulated
    assert "rig.model.action" in mods  # (the probe ran the command)
    assert heavy(mods, NOT_FOR_SIMULATE) == []


@pytest.mark.slow
def test_help_and_info_are_light(simulated):
    work, cache, _ = simulated
    assert heavy(loaded(["--help"], cache, work), NOT_FOR_LIGHT) == []
    info = loaded(["info", str(work / "second.h5")], cache, work)
    assert "h5py" in info  # (it read the file)
    assert heavy(info, NOT_FOR_LIGHT) == []


_EXIT_PROBE = """
import atexit, gc, sys
atexit.register(lambda: print("FROZEN", gc.get_freeze_count()))
sys.argv = ["rig", *sys.argv[1:]]
from rig.cli import main
main()
"""


@pytest.mark.parametrize("args,code", [(["--help"], 0),
                                       (["simulate", "no-such-profile.yaml"], 2)])
def test_the_command_ends_without_the_last_collection_and_keeps_its_exit_code(tmp_path, args,
                                                                             code):
    """``rig`` freezes the collector as it ends (the interpreter's final collection of
    every imported object cost 0.08-0.1 s a command); atexit handlers still run."""
    proc = subprocess.run([sys.executable, "-c", _EXIT_PROBE, *args], cwd=tmp_path,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == code, proc.stdout + proc.stderr
    frozen = [int(x.split()[1]) for x in proc.stdout.splitlines() if x.startswith("FROZEN")]
    assert frozen and frozen[0] > 1000, proc.stdout + proc.stderr
