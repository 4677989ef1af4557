"""The Rosenbrock-W integrator: its tableau on a linear stiff problem, its compiled
building blocks, and forte blows against DormandPrince and a tight BDF reference."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rig.inputs import profiles
from rig.inputs.params import Parameters
from rig.model import kernel as k
from rig.model.action import ActionModel, SimResult
from rig.model.integration import by_name
from rig.model.integrators import DormandPrince, ScipyIntegrator
from rig.model.integrators_stiff import (
    ROS_A,
    ROS_ALPHA,
    ROS_C,
    ROS_E,
    ROS_GAMMA,
    ROS_GSUM,
    ROS_M,
    Rosenbrock,
    _active,
    _lu,
    _lu_solve,
    _spectral_radius,
    jacobian,
)

FULL = ["flexible_shank", "key_liftoff"]


# -- the method on a linear stiff problem with a known solution ---------------------------

L = np.array([[-1.0, 0.5], [0.0, -1e4]])


def _exact(t: float) -> np.ndarray:
    return np.array([math.sin(t), math.cos(t)])


def _g(t: float) -> np.ndarray:
    """Forcing that makes _exact solve y' = L y + g(t)."""
    return np.array([math.cos(t), -math.sin(t)]) - L @ _exact(t)


def _ros_step(y: np.ndarray, t: float, h: float, jac: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One step of the shipped tableau (u-form) in numpy; returns (y1, error estimate)."""
    s = ROS_M.shape[0]
    W = np.eye(2) / (h * ROS_GAMMA) - jac
    ft = (_g(t + 1e-6) - _g(t - 1e-6)) / 2e-6
    U = np.zeros((s, 2))
    for i in range(s):
        yi = y + ROS_A[i, :i] @ U[:i]
        ti = t + ROS_ALPHA[i] * h
        r = L @ yi + _g(ti) + (ROS_C[i, :i] / h) @ U[:i] + h * ROS_GSUM[i] * ft
        U[i] = np.linalg.solve(W, r)
    return y + ROS_M @ U, ROS_E @ U


def _solve_linear(h: float, jac: np.ndarray, t_end: float = 1.0) -> float:
    y, t = _exact(0.0), 0.0
    for _ in range(round(t_end / h)):
        y, _err = _ros_step(y, t, h, jac)
        t += h
    return float(np.max(np.abs(y - _exact(t_end))))


def test_tableau_third_order_on_a_stiff_linear_problem() -> None:
    # h |lambda| from 1e3 down to 1.25e2: stable, and the error falls as h^3
    errs = [_solve_linear(h, L) for h in (0.1, 0.05, 0.025, 0.0125)]
    rates = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    assert errs[-1] < 1e-5
    assert np.all(rates > 2.6), rates


def test_w_method_keeps_its_order_with_an_inexact_jacobian() -> None:
    # a W-method stays third order when the Jacobian is wrong in its non-stiff part
    # (here the slow eigenvalue and the coupling are off), as a reused Jacobian is
    for jac in (np.array([[-1.3, 0.0], [0.0, -1e4]]), np.array([[0.0, 0.0], [0.0, -1e4]])):
        errs = [_solve_linear(h, jac) for h in (0.05, 0.025, 0.0125)]
        rates = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
        assert np.all(rates > 2.6), rates


def test_embedded_estimate_tracks_the_local_error() -> None:
    y0 = _exact(0.3)
    for h in (0.02, 0.01):
        y1, err = _ros_step(y0, 0.3, h, L)
        true = np.abs(y1 - _exact(0.3 + h)).max()
        assert np.abs(err).max() > true  # the order-2 estimate bounds the order-3 error
        assert np.abs(err).max() < 1e-3


def test_l_stable_stability_function() -> None:
    # y' = z y / h: the step multiplies by R(z); R(-inf) = 0 and |R| <= 1 on the left
    def R(z: complex) -> complex:
        s = ROS_M.shape[0]
        U = np.zeros(s, dtype=complex)
        for i in range(s):
            yi = 1.0 + ROS_A[i, :i] @ U[:i]
            U[i] = (z * yi + ROS_C[i, :i] @ U[:i]) / (1.0 / ROS_GAMMA - z)
        return 1.0 + ROS_M @ U

    assert abs(R(-1e8)) < 1e-6
    for z in (-1.0, -10.0, -1e3, -50 + 300j, -1 + 1e4j):
        assert abs(R(z)) <= 1.0 + 1e-12
    assert abs(R(0.01) - math.exp(0.01)) < 1e-8


# -- compiled building blocks ---------------------------------------------------------------

def test_lu_solve_matches_numpy() -> None:
    rng = np.random.default_rng(1)
    for n in (1, 5, 9):
        S = rng.normal(size=(n, n)) + 3 * np.eye(n)
        b = rng.normal(size=n)
        F = S.copy()
        piv = np.zeros(n, dtype=np.int64)
        assert _lu(F, piv, n)
        x = b.copy()
        _lu_solve(F, piv, x, n)
        np.testing.assert_allclose(x, np.linalg.solve(S, b), rtol=1e-12, atol=1e-12)


@pytest.fixture(scope="module")
def full_model() -> ActionModel:
    return ActionModel(effects=FULL)


def test_jacobian_and_spectral_radius(full_model: ActionModel) -> None:
    arrays = full_model.packed.arrays
    ws = full_model.workspace()
    y = full_model.rest_state()
    y[k.NQ + k.QH] = 2.0  # moving hammer
    y[k.NQ + k.QK] = -0.5
    act = _active(arrays, k.NY)
    # every mechanism coordinate and the back check's bristle (the Dahl option's are off)
    assert act.tolist() == list(range(k.QZ + 1))
    na = act.shape[0]
    f = np.zeros(k.NY)
    k.rhs(0.0, y, 3.0, arrays, ws, f)
    JA, JB, gk = np.zeros((na, na)), np.zeros((na, na)), np.zeros(k.NY)
    calls = jacobian(0.0, y, f, 3.0, arrays, ws, act, JA, JB, gk, np.zeros(k.NY),
                     np.zeros(k.NY))
    assert calls == 2 * na + 1
    # independent central differences on a few columns (FD noise ~1e-3 relative)
    for col in (k.QK, k.QH, k.QV2, k.NQ + k.QH, k.NQ + k.QV1):
        d = 1e-6 * max(abs(y[col]), 1e-2 if col < k.NQ else 1.0)
        yp, ym = y.copy(), y.copy()
        yp[col] += d
        ym[col] -= d
        fp, fm = np.zeros(k.NY), np.zeros(k.NY)
        k.rhs(0.0, yp, 3.0, arrays, ws, fp)
        k.rhs(0.0, ym, 3.0, arrays, ws, fm)
        ref = ((fp - fm) / (2 * d))[k.NQ:][act]
        got = (JA if col < k.NQ else JB)[:, col % k.NQ]
        np.testing.assert_allclose(got, ref, rtol=5e-3, atol=1e-4 * np.abs(ref).max())
    # the key-force sensitivity: the rhs is affine in the force
    f5 = np.zeros(k.NY)
    k.rhs(0.0, y, 5.0, arrays, ws, f5)
    np.testing.assert_allclose(f5, f + 2.0 * gk, rtol=1e-9, atol=1e-9)
    J = np.block([[np.zeros((na, na)), np.eye(na)], [JA, JB]])
    rho = _spectral_radius(JA, JB, na, np.zeros(2 * na), np.zeros(2 * na))
    true = np.abs(np.linalg.eigvals(J)).max()
    assert 0.5 * true < rho < 2.0 * true


def test_rigid_model_freezes_coordinates() -> None:
    act = _active(ActionModel().packed.arrays, k.NY)
    assert act.tolist() == [k.QK, k.QW, k.QJ, k.QR, k.QH, k.QZ]  # z_b: the back check's law
    thesis_law = Parameters.default().set("friction_law.contact.4", "smoothed")
    act = _active(ActionModel(thesis_law).packed.arrays, k.NY)
    assert act.tolist() == [k.QK, k.QW, k.QJ, k.QR, k.QH]


@pytest.mark.parametrize("kwargs", [{"rtol": 0.0}, {"max_step": -1.0}, {"jac_reuse": 0},
                                    {"to_explicit": 0.0}, {"to_implicit": 0}])
def test_bad_arguments_name_the_argument(kwargs: dict[str, float]) -> None:
    with pytest.raises(ValueError, match=next(iter(kwargs))):
        Rosenbrock(**kwargs)  # type: ignore[arg-type]


def test_by_name() -> None:
    integ = by_name("rosenbrock", rtol=1e-5, max_step=5e-4)
    assert isinstance(integ, Rosenbrock)
    assert (integ.rtol, integ.max_step) == (1e-5, 5e-4)


# -- forte blows ------------------------------------------------------------------------------

def _check_agree(res: SimResult, ref: SimResult) -> None:
    assert res.success and ref.success
    assert abs(res.events["strike"] - ref.events["strike"]) < 1e-4
    assert abs(res.strike_speed / ref.strike_speed - 1.0) < 0.01
    for name, t_ref in ref.events.items():
        assert math.isfinite(t_ref), name
        assert abs(res.events[name] - t_ref) < 2e-4, name


_BLOWS: dict[tuple[str, ...], SimResult] = {}


def _blow(forte: profiles.Profile, effects: tuple[str, ...], integ: object) -> SimResult:
    key = (*effects, repr(integ))
    if key not in _BLOWS:
        _BLOWS[key] = ActionModel(effects=list(effects), integrator=integ).simulate(forte)
    return _BLOWS[key]


@pytest.mark.parametrize("effects", [(), tuple(FULL)], ids=["rigid", "full"])
def test_agrees_with_dormand_prince(forte: profiles.Profile, effects: tuple[str, ...]) -> None:
    integ = Rosenbrock()
    res = _blow(forte, effects, integ)
    ref = _blow(forte, effects, DormandPrince(max_step=1e-3))
    _check_agree(res, ref)
    # the Jacobian is reused: far fewer Jacobians than steps
    assert 0 < integ.n_jac < res.stats["steps"] / 10


def test_implicit_only_agrees_with_dormand_prince(forte: profiles.Profile) -> None:
    # every step a Rosenbrock step (no switching to explicit steps)
    integ = Rosenbrock(switching=False)
    res = ActionModel(integrator=integ).simulate(forte)
    _check_agree(res, _blow(forte, (), DormandPrince(max_step=1e-3)))
    assert integ.n_jac > 0


def test_two_ms_pieces_match_one_run(forte: profiles.Profile) -> None:
    integ = Rosenbrock()
    model = ActionModel(effects=FULL, integrator=integ)
    whole = _blow(forte, tuple(FULL), Rosenbrock())
    st = model.stepper()
    t = 0.0
    for _ in range(300):
        f0, f1 = (float(forte.at(np.array([x]))[0]) for x in (t, t + 0.002))
        st.advance(t + 0.002, f0, f1)
        t += 0.002
    pieces = st.result()
    assert pieces.time.shape == whole.time.shape
    _check_agree(pieces, whole)
    # continuing calls keep the Jacobian: not one new Jacobian per piece
    assert integ.n_jac < 300


@pytest.mark.slow
@pytest.mark.parametrize("effects", [(), tuple(FULL)], ids=["rigid", "full"])
def test_agrees_with_tight_bdf(forte: profiles.Profile, effects: tuple[str, ...]) -> None:
    res = _blow(forte, effects, Rosenbrock())
    model = ActionModel(effects=list(effects),
                        integrator=ScipyIntegrator("BDF", rtol=1e-8, max_step=1e-3))
    ref = model.simulate(forte, chunk=0.6)
    _check_agree(res, ref)


# -- the one-way coupled axial shank coordinate (hammer_shank_axial.coupling) ----------------

def _one_way(**kw: object) -> ActionModel:
    par = Parameters.default().set("hammer_shank_axial.coupling", "one_way")
    return ActionModel(par, effects=FULL, **kw)  # type: ignore[arg-type]


@pytest.mark.parametrize("w2, beta", [(1.09e9, 1.14e-5), (1.09e9, 0.0), (1.09e9, 2e-4),
                                      (1.09e9, 2.0 / math.sqrt(1.09e9)), (4e6, 1e-3)],
                         ids=["under", "undamped", "over", "critical", "slow"])
def test_axial_advance_is_exact_under_linear_forcing(w2: float, beta: float) -> None:
    from scipy.integrate import solve_ivp

    from rig.model.integrators_stiff import axial_advance

    # u'' + beta w2 u' + w2 u = w2 s(t), s linear over each step, several steps chained
    knots = np.array([0.0, 3e-5, 2.3e-4, 2.4e-4, 9e-4])
    s = np.array([0.0, -4e-5, 1e-5, 2e-5, -3e-6])
    u, v = 2e-6, -0.1
    y = np.array([u, v])
    for i in range(knots.size - 1):
        h = knots[i + 1] - knots[i]
        u, v = axial_advance(h, u, v, s[i], s[i + 1], w2, beta)

        def f(t: float, x: np.ndarray, i: int = i, h: float = h) -> list[float]:
            si = s[i] + (s[i + 1] - s[i]) * t / h
            return [x[1], w2 * (si - x[0] - beta * x[1])]

        y = solve_ivp(f, (0.0, h), y, method="DOP853", rtol=1e-12, atol=1e-16).y[:, -1]
        assert u == pytest.approx(y[0], abs=1e-11)
        assert v == pytest.approx(y[1], abs=1e-11 * math.sqrt(w2))


def test_one_way_axial_mode_is_the_coupled_models_axial_mode(full_model: ActionModel) -> None:
    # the oscillator's frequency: the coupled model's 5.2 kHz eigenvalue (its Jacobian at
    # rest), which the one-way model keeps with the hammer and the bending free to react
    one_way = _one_way()
    assert _active(one_way.packed.arrays, k.NY).tolist() == [
        k.QK, k.QYK, k.QW, k.QJ, k.QR, k.QH, k.QV1, k.QV2, k.QZ]
    arrays = full_model.packed.arrays
    y = full_model.rest_state()
    ws = full_model.workspace()
    f = np.zeros(k.NY)
    k.rhs(0.0, y, 0.0, arrays, ws, f)
    J = np.zeros((k.NY, k.NY))
    for j in range(k.NY):
        yp = y.copy()
        d = 1e-7 * max(abs(y[j]), 1e-3 if j < k.NQ else 0.1)
        yp[j] += d
        fp = np.zeros(k.NY)
        k.rhs(0.0, yp, 0.0, arrays, ws, fp)
        J[:, j] = (fp - f) / d
    lam = np.linalg.eigvals(J)
    axial = lam[np.argmax(np.abs(lam.imag))]
    assert math.sqrt(one_way.packed.arrays.sp[k.S_AXW2]) == pytest.approx(abs(axial), rel=0.01)


def test_one_way_axial_exact_steps_agree_with_dormand_prince(forte: profiles.Profile) -> None:
    # the same one-way equations: the Rosenbrock advances u1 exactly between its steps
    # (the axial force linear over each step), DormandPrince steps the stiff oscillator like
    # any other coordinate; both tight, through the strike and the string's release
    runs = []
    for integ in (Rosenbrock(rtol=1e-9), DormandPrince(rtol=1e-10, max_step=1e-3)):
        model = _one_way(integrator=integ)
        model.atol = model.atol * 1e-3
        runs.append(model.simulate(forte, 0.068))
    a, b = runs
    assert a.success and b.success
    strain_a, strain_b = a.channels["shank_strain"], b.channels["shank_strain"]
    # measured 1.9e-8: the axial force held linear over each step
    assert np.abs(strain_a - strain_b).max() < 1e-7
    # the axial strain is there: u1 alone is tens of microstrain while the jack pushes
    assert np.abs(strain_a).max() > 1e-4


def test_axial_coupling_parameter_is_checked() -> None:
    par = Parameters.default().set("hammer_shank_axial.coupling", "none")
    with pytest.raises(ValueError, match="hammer_shank_axial.coupling"):
        ActionModel(par, effects=FULL)


def test_the_force_slope_from_a_remembered_segment_is_the_tables_slope_anywhere():
    """_force_slope keeps the last segment in hint[1] (force_at's is hint[0]) and walks
    from it either way: the slope just after t, for times in any order, is the table's."""
    from rig.model.integrators_stiff import _force_slope

    rng = np.random.default_rng(7)
    ft = np.cumsum(rng.uniform(1e-4, 2e-3, 400))
    ff = rng.uniform(0.0, 50.0, ft.size)
    hint = np.array([3, 250], dtype=np.int64)
    times = np.r_[rng.uniform(ft[0] - 0.01, ft[-1] + 0.01, 300), ft[::37], ft[-1], ft[0]]
    for t in times:
        got = _force_slope(t, ft, ff, hint)
        if t < ft[0] or t >= ft[-1]:
            assert got == 0.0
            continue
        i = np.searchsorted(ft, t, side="right") - 1  # the segment [ft[i], ft[i+1]) holding t
        assert got == (ff[i + 1] - ff[i]) / (ft[i + 1] - ft[i])
        assert hint[0] == 3  # force_at's entry is left alone
