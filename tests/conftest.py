"""Shared fixtures: the shipped profiles and blows simulated once per session, and a
fresh interpreter's result read twice (for checks of what a new process loads)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from rig.inputs import profiles
from rig.model.action import ActionModel, SimResult

ROOT = Path(__file__).resolve().parents[1]
COSTLY = ("cluster", "browser")  # cost markers that always imply slow (seconds to start)
# fixtures that bring a costly resource: a test using one is marked by it
BY_FIXTURE = {"cluster": "cluster", "fresh_twice": "interpreter"}


@pytest.hookimpl(tryfirst=True)  # before `-m "not slow"` deselects
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Cost markers from the fixtures a test uses; a test that starts a cluster or a
    browser is slow too, so the fast tier (tools/test.sh) leaves it to the whole suite."""
    for item in items:
        for fixture, marker in BY_FIXTURE.items():
            if fixture in getattr(item, "fixturenames", ()):
                item.add_marker(marker)
        if any(item.get_closest_marker(m) for m in COSTLY) and not item.get_closest_marker(
                "slow"):
            item.add_marker(pytest.mark.slow)


@pytest.fixture(scope="session", autouse=True)
def _rest_cache(tmp_path_factory):
    """The on-disk rest-state cache in a session folder, not the user's ~/.cache."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("RIG_CACHE_DIR", str(tmp_path_factory.mktemp("rig-cache")))
        yield


def _fresh_twice(code: str, args: list[str], cwd: Path, **env: str) -> dict[str, Any]:
    """``python -c CODE ARGS`` in a fresh interpreter, twice (the first may compile into
    numba's cache, on a fresh checkout; the second loads from it), with RIG_CACHE_DIR in
    ``cwd``: the JSON the second prints after ``RESULT``."""
    environ = {**os.environ, "RIG_CACHE_DIR": str(cwd / "cache"), **env}
    for _ in range(2):
        proc = subprocess.run([sys.executable, "-c", code, *args], cwd=cwd, env=environ,
                              capture_output=True, text=True, timeout=1800)
        assert proc.returncode == 0, proc.stdout + proc.stderr
    line = next(x for x in proc.stdout.splitlines() if x.startswith("RESULT"))
    return json.loads(line[len("RESULT"):])


@pytest.fixture
def tmpfs(tmp_path: Path):
    """``mount(options, name)``: a tmpfs mounted with ``options`` (``"size=6m"``,
    ``"ro,size=64m"``) at ``tmp_path / name``, unmounted after the test; the test skips
    where it cannot be mounted (not root, no mount)."""
    mounted: list[Path] = []

    def mount(options: str, name: str = "small") -> Path:
        mnt = tmp_path / name
        mnt.mkdir()
        if os.geteuid() != 0:
            pytest.skip("mounting a filesystem needs root")
        res = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(mnt)],
                             capture_output=True, text=True)
        if res.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here: {res.stderr.strip()}")
        mounted.append(mnt)
        return mnt

    yield mount
    for mnt in mounted:
        subprocess.run(["umount", "-l", str(mnt)], check=False)


@pytest.fixture
def fresh_twice() -> Callable[..., dict[str, Any]]:
    """Run code in a fresh interpreter twice and read the second's RESULT line."""
    return _fresh_twice


@pytest.fixture(scope="session")
def forte() -> profiles.Profile:
    return profiles.load(ROOT / "profiles" / "forte.yaml")


@pytest.fixture(scope="session")
def piano() -> profiles.Profile:
    return profiles.load(ROOT / "profiles" / "piano.yaml")


@pytest.fixture(scope="session")
def rigid_model() -> ActionModel:
    return ActionModel()


@pytest.fixture(scope="session")
def forte_rigid(rigid_model: ActionModel, forte: profiles.Profile) -> SimResult:
    return rigid_model.simulate(forte)


@pytest.fixture(scope="session")
def piano_rigid(rigid_model: ActionModel, piano: profiles.Profile) -> SimResult:
    return rigid_model.simulate(piano)


@pytest.fixture(scope="session")
def flex_model() -> ActionModel:
    return ActionModel(effects=["flexible_shank"])


@pytest.fixture(scope="session")
def forte_flex(flex_model: ActionModel, forte: profiles.Profile) -> SimResult:
    return flex_model.simulate(forte)
