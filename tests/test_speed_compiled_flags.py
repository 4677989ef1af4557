"""How the model's hot compiled functions are compiled (issue 16).

The functions the default integration runs per step and per output row allocate
nothing (the Rosenbrock loop gets its work arrays from Python), so they run without
numba's reference counting (``_nrt=False``: 9 % of a full blow went to counting the
references of arrays they only read); and the model's compiled code uses numpy's error
model, so a division by zero gives inf or NaN, which the integrators report as a
non-finite state (a status and a message), instead of raising from inside a blow.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rig.inputs import profiles
from rig.inputs.params import Parameters
from rig.model import integrators as itg
from rig.model import integrators_stiff as ist
from rig.model import kernel as k
from rig.model.action import ActionModel

HOT = [k.rhs, k.sample_outputs, k.energy, itg.force_at, itg._hermite, ist.ros_run, ist.jacobian,
       ist._lu, ist._lu_solve, ist._force_slope, ist._spectral_radius, ist.axial_advance]
ROOT = Path(__file__).resolve().parents[1]
LOOPS = [itg.dopri_run, itg.rk4_run]  # they allocate their work arrays


@pytest.mark.parametrize("fn", HOT + LOOPS, ids=lambda f: f.py_func.__name__)
def test_the_hot_functions_count_no_references_and_use_numpys_error_model(fn):
    assert fn.targetoptions.get("error_model") == "numpy"
    assert fn.targetoptions.get("_nrt", True) is (fn in LOOPS)


def _loaded_contact_without_slip_speed(model: ActionModel):
    """The packed arrays with a contact that carries load at rest given a zero Stribeck
    speed (its friction law then divides by zero), and the rest state."""
    rest = model.rest_state()
    ws = model.workspace()
    k.rhs(0.0, rest[: k.NY], 0.0, model.packed.arrays, ws, np.zeros(k.NY))
    cl = model.packed.arrays.cl
    loaded = [i for i in range(cl.shape[0])
              if ws.cout[i, k.O_FN] > 0 and cl[i, k.L_MU_A] > 0
              and cl[i, k.L_FLAW] != k.FRICTION_BRISTLE]
    assert loaded, "no loaded contact with the smoothed Coulomb law at rest"
    cl_bad = cl.copy()
    cl_bad[loaded[0], k.L_VT] = 0.0
    return model.packed.arrays._replace(cl=cl_bad), rest


def test_a_division_by_zero_in_the_kernel_gives_nan_not_an_exception():
    model = ActionModel(Parameters.default())
    arrays, rest = _loaded_contact_without_slip_speed(model)
    dy = np.zeros(k.NY)
    k.rhs(0.0, rest[: k.NY], 0.0, arrays, model.workspace(), dy)  # no ZeroDivisionError
    assert not np.all(np.isfinite(dy))


@pytest.mark.parametrize("integrator", ["rosenbrock", "dopri54", "rk4"])
def test_the_integrators_report_the_non_finite_state_with_a_status(integrator):
    from rig.model.integration import by_name

    model = ActionModel(Parameters.default())
    arrays, rest = _loaded_contact_without_slip_speed(model)
    ft, ff = model.input_force(profiles.load(ROOT / "profiles" / "forte.yaml"))
    adv = by_name(integrator).advance(arrays, model.workspace(), rest[: k.NY].copy(), 0.0,
                                      0.002, 1e-5, ft, ff, np.zeros(0), model.atol)
    assert not adv.success
    assert adv.status in (itg.STATUS_NOT_FINITE, itg.STATUS_STEP_TOO_SMALL)
    assert adv.message
