"""Cached machine code loads without numba's compiler registries (issue 16),
and whatever compiles later in the same process still compiles as before.

Each check runs in a fresh interpreter (a real subprocess): what a process has
imported is the point. ``blow`` runs its process twice: the first may compile the
model's functions into numba's cache (a fresh checkout), the second, whose result
is checked, loads them from it.
"""

from __future__ import annotations

from pathlib import Path

import pytest

pytestmark = pytest.mark.interpreter  # what these tests cost (pyproject.toml)

ROOT = Path(__file__).resolve().parents[1]

# a rigid blow of 20 ms, then (optionally) a new compiled function that needs the
# registries a cache load skips: array math (np.median), linear algebra (np.dot,
# through scipy's BLAS) and typed containers
_BLOW = """
import json, sys
import numpy as np
from rig.model import cache_loading
from rig.model.action import ActionModel
from rig.inputs import profiles
m = ActionModel.from_yaml(None)
p = profiles.load(sys.argv[1])
r = m.simulate(p, 0.02)
out = {"installed": cache_loading.installed(), "success": bool(r.success),
       "key_end": float(r.channels["key_angle"][-1]),
       "arraymath_after_blow": "numba.np.arraymath" in sys.modules,
       "scipy_linalg_after_blow": "scipy.linalg" in sys.modules}
if sys.argv[2] == "compile":
    from numba import njit
    from numba.typed import List

    @njit
    def later(a, b):
        acc = List()
        acc.append(np.median(a))
        acc.append(np.dot(a, b))
        return acc[0] + acc[1]

    a = np.arange(1.0, 6.0)
    b = np.linspace(0.0, 1.0, 5)
    out["later"] = float(later(a, b))
    out["later_expected"] = float(np.median(a) + np.dot(a, b))
print("RESULT" + json.dumps(out))
"""


def blow(fresh_twice, tmp_path: Path, then: str = "", **env: str) -> dict:
    """A fresh process's blow (run twice: the second loads everything from the cache)."""
    return fresh_twice(_BLOW, [str(ROOT / "profiles" / "forte.yaml"), then or "-"], tmp_path,
                       **env)


@pytest.mark.slow
def test_a_cached_blow_loads_without_the_compiler_registries(fresh_twice, tmp_path):
    lazy = blow(fresh_twice, tmp_path)
    assert lazy["installed"] and lazy["success"]
    assert not lazy["arraymath_after_blow"]
    assert not lazy["scipy_linalg_after_blow"]
    eager = blow(fresh_twice, tmp_path, RIG_NUMBA_EAGER_REGISTRIES="1")
    assert not eager["installed"]
    assert eager["arraymath_after_blow"]  # numba's own refresh imports it
    assert eager["key_end"] == lazy["key_end"]  # the same machine code, the same blow


@pytest.mark.slow
def test_a_compile_after_a_cached_load_sees_every_registry(fresh_twice, tmp_path):
    out = blow(fresh_twice, tmp_path, "compile")
    assert out["installed"] and not out["arraymath_after_blow"]
    assert out["later"] == out["later_expected"]
