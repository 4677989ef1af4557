"""The compiled integrators call the right-hand side loaded on its own (issue 16).

An integrator's cached machine code carries its own, slower copy of ``kernel.rhs``
(a weak symbol); ``integrators.link_standalone_rhs`` loads ``kernel.rhs`` first so
the loader binds the integrator's calls to it. What can be checked without a clock:
in a fresh process the right-hand side is looked up in numba's cache before the
integrator, for each compiled integrator, and the blow is bit for bit the one the
integrator's own copy gives. (The speed: benchmarks/simulate.py, docs/performance.md.)

Each check runs in a fresh interpreter (a real subprocess), twice: the first may
compile into numba's cache (a fresh checkout), the second, which is checked, loads.
"""

from __future__ import annotations

from pathlib import Path

import pytest

pytestmark = pytest.mark.interpreter  # what these tests cost (pyproject.toml)

ROOT = Path(__file__).resolve().parents[1]

# a blow of the full model (flexible shank and key lift-off) for 60 ms with the named
# integrator, recording the order in which compiled functions are looked up in the cache
_BLOW = """
import hashlib, json, sys
from rig.model import integrators, integrators_stiff, kernel as k
integrators.LINK_STANDALONE_RHS = sys.argv[3] == "1"
order = []
for name, disp in (("rhs", k.rhs), ("rosenbrock", integrators_stiff.ros_run),
                   ("dopri54", integrators.dopri_run), ("rk4", integrators.rk4_run)):
    load = disp._cache.load_overload

    def record(sig, ctx, _load=load, _name=name):
        order.append(_name)
        return _load(sig, ctx)

    disp._cache.load_overload = record
from rig.inputs import profiles
from rig.model.action import ActionModel
m = ActionModel.from_yaml(None, effects=["flexible_shank", "key_liftoff"],
                          integrator=sys.argv[2])
r = m.simulate(profiles.load(sys.argv[1]), 0.06)
digest = hashlib.sha256()
for name in sorted(r.channels):
    digest.update(r.channels[name].tobytes())
print("RESULT" + json.dumps({"order": order, "success": bool(r.success),
                             "steps": r.stats["steps"], "digest": digest.hexdigest()}))
"""


def blow(fresh_twice, tmp_path: Path, integrator: str, link: bool) -> dict:
    """A fresh process's blow (run twice: the second loads everything from the cache)."""
    return fresh_twice(_BLOW, [str(ROOT / "profiles" / "forte.yaml"), integrator,
                               "1" if link else "0"], tmp_path)


@pytest.mark.parametrize("integrator", ["rosenbrock", "dopri54", "rk4"])
@pytest.mark.slow
def test_the_integrator_calls_the_standalone_rhs_and_the_blow_is_unchanged(fresh_twice,
                                                                          tmp_path, integrator):
    linked = blow(fresh_twice, tmp_path, integrator, link=True)
    assert linked["success"]
    assert integrator in linked["order"] and "rhs" in linked["order"]
    assert linked["order"].index("rhs") < linked["order"].index(integrator)
    own = blow(fresh_twice, tmp_path, integrator, link=False)
    assert "rhs" not in own["order"][: own["order"].index(integrator)]
    assert own["digest"] == linked["digest"] and own["steps"] == linked["steps"]
