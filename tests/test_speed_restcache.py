"""The rest state (and balance-rail placement) cached on disk by content hash (issue 16)."""

from __future__ import annotations

import numpy as np
import pytest

from rig.inputs.params import Parameters
from rig.model import action, restcache
from rig.model.action import ActionModel


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("RIG_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(action, "_REST_CACHE", {})
    monkeypatch.setattr(action, "_RAIL_CACHE", {})
    return tmp_path / "rest"


def forget() -> None:
    """What a new process has: no rest state in memory."""
    action._REST_CACHE.clear()
    action._RAIL_CACHE.clear()


def count_settles(monkeypatch) -> list[int]:
    calls: list[int] = []
    real = ActionModel._settle

    def counted(self, arrays=None):
        calls.append(1)
        return real(self, arrays)

    monkeypatch.setattr(ActionModel, "_settle", counted)
    return calls


def test_a_new_process_reads_the_rest_state_from_disk(cache, monkeypatch):
    settles = count_settles(monkeypatch)
    first = ActionModel().rest_state()
    assert settles == [1] and len(list(cache.glob("*.npy"))) == 1
    forget()
    again = ActionModel().rest_state()
    assert settles == [1]  # not settled again
    np.testing.assert_array_equal(again, first)


def test_a_changed_parameter_settles_again(cache, monkeypatch):
    settles = count_settles(monkeypatch)
    base = ActionModel().rest_state()
    heavier = ActionModel(Parameters.default().set("bodies.hammer_head.mass", 0.0115)).rest_state()
    assert settles == [1, 1] and len(list(cache.glob("*.npy"))) == 2
    assert not np.array_equal(base, heavier)


def test_a_damaged_entry_is_recomputed(cache, monkeypatch):
    first = ActionModel().rest_state()
    (entry,) = cache.glob("*.npy")
    entry.write_bytes(b"\x93NUMPY garbage")
    forget()
    settles = count_settles(monkeypatch)
    np.testing.assert_allclose(ActionModel().rest_state(), first, rtol=0, atol=1e-12)
    assert settles == [1]


def test_the_disk_cache_can_be_switched_off(tmp_path, monkeypatch):
    monkeypatch.setenv("RIG_CACHE_DIR", "")
    assert restcache.folder() is None
    monkeypatch.setattr(action, "_REST_CACHE", {})
    ActionModel().rest_state()
    assert list(tmp_path.iterdir()) == []


def test_the_balance_rail_placement_is_cached_too(cache, monkeypatch):
    first = ActionModel(effects=["key_liftoff"])
    rest = first.rest_state()
    forget()
    settles = count_settles(monkeypatch)
    again = ActionModel(effects=["key_liftoff"])
    assert settles == []  # neither the rail nor the rest state settled again
    assert again.balance_rail == first.balance_rail
    np.testing.assert_array_equal(again.rest_state(), rest)


@pytest.mark.parametrize("effects", [[], ["flexible_shank", "key_liftoff"]])
def test_settling_with_the_models_integrator_gives_the_same_rest(cache, monkeypatch, effects):
    """A first use compiles only the integrator in use (the rest state settles with the
    model's Rosenbrock integrator, not dopri54); the polished equilibrium is the same."""
    from rig.model.integrators import DormandPrince

    real_advance = DormandPrince.advance

    def no_dopri(self, *args, **kwargs):
        raise AssertionError("the rest state settled with dopri54")

    monkeypatch.setattr(DormandPrince, "advance", no_dopri)
    own = ActionModel(effects=effects)
    assert own.integrator.name == "rosenbrock"
    rest = own.rest_state()
    forget()
    monkeypatch.setattr(DormandPrince, "advance", real_advance)
    monkeypatch.setattr(action, "SETTLE_WITH_OWN_INTEGRATOR", ())
    monkeypatch.setenv("RIG_CACHE_DIR", "")
    dopri = ActionModel(effects=effects)
    np.testing.assert_allclose(rest, dopri.rest_state(), rtol=0, atol=1e-10)
    assert own.balance_rail == pytest.approx(dopri.balance_rail, abs=1e-12) \
        if effects else own.balance_rail is None


def test_the_cache_keeps_a_bounded_number_of_entries(tmp_path, monkeypatch):
    monkeypatch.setenv("RIG_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(restcache, "MAX_ENTRIES", 8)
    for i in range(20):
        restcache.store(restcache.key("test", [str(i)]), np.full(3, float(i)))
    kept = list((tmp_path / "rest").glob("*.npy"))
    assert 6 <= len(kept) <= 8
    newest = restcache.key("test", ["19"])
    np.testing.assert_array_equal(restcache.load(newest, 3), np.full(3, 19.0))


USER_DRAG = '''
import numpy as np
from rig.model.effects import Effect


class PullOnHammer(Effect):
    name = "pull_on_hammer"
    summary = "a constant torque on the hammer (a Python generalized force)"

    def generalized_force(self, t, q, qd):
        f = np.zeros(9)
        f[5] = {torque}
        return f
'''


def test_editing_a_user_effects_force_law_changes_the_key(cache, tmp_path):
    """The force law of a Python effect is in no packed array: its source file is in the
    disk key, so an edited law never finds the old rest state."""
    (tmp_path / "pull.py").write_text(USER_DRAG.format(torque="-1e-4"))
    model = ActionModel(effects=["pull.py:PullOnHammer"], base_dir=tmp_path)
    assert model.python_forces
    before = model._disk_key("rest", model.equations_key)
    (tmp_path / "pull.py").write_text(USER_DRAG.format(torque="-2e-4"))
    after = model._disk_key("rest", model.equations_key)
    assert before is not None and after is not None and before != after
