"""Shared fixtures: the shipped profiles and blows simulated once per session."""

from __future__ import annotations

from pathlib import Path

import pytest

from rig import profiles
from rig.model.action import ActionModel, SimResult

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session", autouse=True)
def _rest_cache(tmp_path_factory):
    """The on-disk rest-state cache in a session folder, not the user's ~/.cache."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("RIG_CACHE_DIR", str(tmp_path_factory.mktemp("rig-cache")))
        yield


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
