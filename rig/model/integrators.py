"""Integrators for the action model, swappable through one small interface.

An integrator advances the state from ``t0`` to ``t1`` under a key force that is
piecewise linear between the knots ``(force_t, force_f)``, and returns the state
at every requested output time. It keeps what it learnt (its step size) in the
returned ``step`` so a caller that advances in 2 ms pieces continues smoothly.

- :class:`DormandPrince` (default): adaptive explicit 5(4) pair with a PI step
  controller, compiled with numba. The action's stiffness comes from felt
  contacts and regularised friction; explicit steps of 10-100 us resolve it.
- :class:`RungeKutta4`: classical fixed-step RK4, compiled; a cross-check.
- :class:`ScipyIntegrator`: ``scipy.integrate.solve_ivp`` (BDF, LSODA, Radau,
  ...) on the same right-hand side; the independent reference.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numba import njit

from rig.errors import InputError
from rig.model import kernel as k

STATUS_OK = 0
STATUS_STEP_TOO_SMALL = -1
STATUS_NOT_FINITE = -2
STATUS_MAX_STEPS = -3

STATUS_MESSAGES = {
    STATUS_OK: "ok",
    STATUS_STEP_TOO_SMALL: "step size fell below the minimum (the model is too stiff here)",
    STATUS_NOT_FINITE: "the state became NaN or infinite",
    STATUS_MAX_STEPS: "too many steps for this interval",
}


@dataclass
class Advance:
    """Result of one integration call."""

    y: np.ndarray  # state at t1
    out: np.ndarray  # states at the output times, shape (n_out, n_state)
    step: float  # step size to continue with
    n_steps: int
    n_rejected: int
    n_rhs: int
    status: int = STATUS_OK

    @property
    def message(self) -> str:
        return STATUS_MESSAGES.get(self.status, f"status {self.status}")

    @property
    def success(self) -> bool:
        return self.status == STATUS_OK


@njit(**k.HOT)
def force_at(t, force_t, force_f, hint):
    """Key force (N) at t, linear between knots; hint[0] caches the last segment."""
    n = force_t.shape[0]
    if n == 1 or t <= force_t[0]:
        return force_f[0]
    if t >= force_t[n - 1]:
        return force_f[n - 1]
    i = hint[0]
    if i < 0 or i > n - 2:
        i = 0
    while i < n - 2 and force_t[i + 1] < t:
        i += 1
    while i > 0 and force_t[i] > t:
        i -= 1
    hint[0] = i
    span = force_t[i + 1] - force_t[i]
    if span <= 0.0:
        return force_f[i + 1]
    return force_f[i] + (force_f[i + 1] - force_f[i]) * (t - force_t[i]) / span


# Dormand-Prince 5(4) tableau
_C2, _C3, _C4, _C5 = 1 / 5, 3 / 10, 4 / 5, 8 / 9
_A21 = 1 / 5
_A31, _A32 = 3 / 40, 9 / 40
_A41, _A42, _A43 = 44 / 45, -56 / 15, 32 / 9
_A51, _A52, _A53, _A54 = 19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729
_A61, _A62, _A63, _A64, _A65 = 9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656
_B1, _B3, _B4, _B5, _B6 = 35 / 384, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84
_E1 = 71 / 57600
_E3 = -71 / 16695
_E4 = 71 / 1920
_E5 = -17253 / 339200
_E6 = 22 / 525
_E7 = -1 / 40


def link_standalone_rhs(model: k.Model, ws: k.Workspace, y0: np.ndarray) -> bool:
    """Load the compiled right-hand side on its own, before a compiled integrator.

    Numba links a compiled callee into each caller, so an integrator's cached machine
    code carries its own copy of ``kernel.rhs``, which LLVM optimised a second time
    together with the integrator: on this model 19 % more code that runs the blow 10-20 %
    slower than ``kernel.rhs`` compiled on its own (docs/performance.md, "The
    right-hand side loaded on its own"). That copy is a weak symbol, so when
    ``kernel.rhs`` is already loaded the loader binds the integrator's calls to it. Called
    before every compiled integrator's loop; the first call in a process loads it (40-50
    ms from numba's cache on this host, measured) with scratch copies of the state and
    workspace, later calls return at once. True if it loaded it now.
    """
    if not LINK_STANDALONE_RHS or k.rhs.overloads:
        return False
    scratch = type(ws)(*(np.array(a, copy=True) for a in ws))
    y = np.array(y0[: k.NY], dtype=float, copy=True)
    k.rhs(0.0, y, 0.0, model, scratch, np.zeros(k.NY))
    return True


# Off: the integrators use the copy of the right-hand side linked into their own code
# (for tests and measurements of link_standalone_rhs; set before the first blow).
LINK_STANDALONE_RHS = True


@njit(**k.HOT)
def _hermite(t0, h, y0, f0, y1, f1, tau, out, row):
    s = (tau - t0) / h
    s2 = s * s
    s3 = s2 * s
    h00 = 2 * s3 - 3 * s2 + 1
    h10 = s3 - 2 * s2 + s
    h01 = -2 * s3 + 3 * s2
    h11 = s3 - s2
    for i in range(y0.shape[0]):
        out[row, i] = h00 * y0[i] + h10 * h * f0[i] + h01 * y1[i] + h11 * h * f1[i]


@njit(cache=True, error_model="numpy")
def dopri_run(model, ws, y0, t0, t1, h0, force_t, force_f, rtol, atol, hmax, out_t, out_y,
              max_steps):
    """Adaptive Dormand-Prince 5(4) from t0 to t1; Hermite output at out_t."""
    n = y0.shape[0]
    y = y0.copy()
    k1 = np.empty(n)
    k2 = np.empty(n)
    k3 = np.empty(n)
    k4 = np.empty(n)
    k5 = np.empty(n)
    k6 = np.empty(n)
    k7 = np.empty(n)
    yt = np.empty(n)
    ynew = np.empty(n)
    hint = np.zeros(1, dtype=np.int64)
    # the error norm's count: the frozen bristle coordinates of the Dahl option are left out
    # (they stay zero), so a model without it steps as before they existed
    n_err = n - (k.NY - k.NY_BASE) + 2 * k.n_extra_bristles(model.cl, model.jf)
    t = t0
    h = min(h0, hmax)
    hmin = 1e-12
    n_out = out_t.shape[0]
    j = 0
    while j < n_out and out_t[j] <= t0:
        for i in range(n):
            out_y[j, i] = y[i]
        j += 1
    k.rhs(t, y, force_at(t, force_t, force_f, hint), model, ws, k1)
    n_rhs = 1
    steps = 0
    rejected = 0
    err_old = 1e-4
    status = 0
    while t < t1:
        if steps + rejected >= max_steps:
            status = -3
            break
        last = False
        if t + h >= t1 - 1e-15:
            h = t1 - t
            last = True
        for i in range(n):
            yt[i] = y[i] + h * _A21 * k1[i]
        k.rhs(t + _C2 * h, yt, force_at(t + _C2 * h, force_t, force_f, hint), model, ws, k2)
        for i in range(n):
            yt[i] = y[i] + h * (_A31 * k1[i] + _A32 * k2[i])
        k.rhs(t + _C3 * h, yt, force_at(t + _C3 * h, force_t, force_f, hint), model, ws, k3)
        for i in range(n):
            yt[i] = y[i] + h * (_A41 * k1[i] + _A42 * k2[i] + _A43 * k3[i])
        k.rhs(t + _C4 * h, yt, force_at(t + _C4 * h, force_t, force_f, hint), model, ws, k4)
        for i in range(n):
            yt[i] = y[i] + h * (_A51 * k1[i] + _A52 * k2[i] + _A53 * k3[i] + _A54 * k4[i])
        k.rhs(t + _C5 * h, yt, force_at(t + _C5 * h, force_t, force_f, hint), model, ws, k5)
        for i in range(n):
            yt[i] = y[i] + h * (_A61 * k1[i] + _A62 * k2[i] + _A63 * k3[i] + _A64 * k4[i]
                                + _A65 * k5[i])
        k.rhs(t + h, yt, force_at(t + h, force_t, force_f, hint), model, ws, k6)
        for i in range(n):
            ynew[i] = y[i] + h * (_B1 * k1[i] + _B3 * k3[i] + _B4 * k4[i] + _B5 * k5[i]
                                  + _B6 * k6[i])
        k.rhs(t + h, ynew, force_at(t + h, force_t, force_f, hint), model, ws, k7)
        n_rhs += 6
        err = 0.0
        finite = True
        for i in range(n):
            e = h * (_E1 * k1[i] + _E3 * k3[i] + _E4 * k4[i] + _E5 * k5[i] + _E6 * k6[i]
                     + _E7 * k7[i])
            sc = atol[i] + rtol * max(abs(y[i]), abs(ynew[i]))
            r = e / sc
            err += r * r
            if not math.isfinite(ynew[i]):
                finite = False
        err = math.sqrt(err / n_err)
        if not finite or not math.isfinite(err):
            if h <= hmin:
                status = -2
                break
            h *= 0.1
            rejected += 1
            continue
        if err <= 1.0:
            tn = t + h
            if last:
                tn = t1
            while j < n_out and out_t[j] <= tn:
                _hermite(t, tn - t, y, k1, ynew, k7, out_t[j], out_y, j)
                j += 1
            t = tn
            for i in range(n):
                y[i] = ynew[i]
                k1[i] = k7[i]
            steps += 1
            # PI controller (Gustafsson), exponents for a 5th-order pair
            fac = 0.9 * err ** (-0.7 / 5.0) * err_old ** (0.4 / 5.0) if err > 0 else 5.0
            fac = min(5.0, max(0.2, fac))
            err_old = max(err, 1e-4)
            if not last:
                h = min(h * fac, hmax)
        else:
            fac = max(0.2, 0.9 * err ** (-1.0 / 5.0))
            h *= fac
            rejected += 1
            if h < hmin:
                status = -1
                break
    return y, t, h, steps, rejected, n_rhs, status, j


@njit(cache=True, error_model="numpy")
def rk4_run(model, ws, y0, t0, t1, h, force_t, force_f, out_t, out_y):
    """Classical RK4 with fixed step h (the last step is shortened to land on t1)."""
    n = y0.shape[0]
    y = y0.copy()
    k1 = np.empty(n)
    k2 = np.empty(n)
    k3 = np.empty(n)
    k4 = np.empty(n)
    yt = np.empty(n)
    ynew = np.empty(n)
    kend = np.empty(n)
    hint = np.zeros(1, dtype=np.int64)
    t = t0
    j = 0
    n_out = out_t.shape[0]
    while j < n_out and out_t[j] <= t0:
        for i in range(n):
            out_y[j, i] = y[i]
        j += 1
    steps = 0
    status = 0
    while t < t1 - 1e-15:
        hs = min(h, t1 - t)
        k.rhs(t, y, force_at(t, force_t, force_f, hint), model, ws, k1)
        for i in range(n):
            yt[i] = y[i] + 0.5 * hs * k1[i]
        k.rhs(t + 0.5 * hs, yt, force_at(t + 0.5 * hs, force_t, force_f, hint), model, ws, k2)
        for i in range(n):
            yt[i] = y[i] + 0.5 * hs * k2[i]
        k.rhs(t + 0.5 * hs, yt, force_at(t + 0.5 * hs, force_t, force_f, hint), model, ws, k3)
        for i in range(n):
            yt[i] = y[i] + hs * k3[i]
        k.rhs(t + hs, yt, force_at(t + hs, force_t, force_f, hint), model, ws, k4)
        for i in range(n):
            ynew[i] = y[i] + hs / 6.0 * (k1[i] + 2 * k2[i] + 2 * k3[i] + k4[i])
            if not math.isfinite(ynew[i]):
                status = -2
        if status != 0:
            break
        tn = t1 if t + hs >= t1 - 1e-15 else t + hs
        if j < n_out and out_t[j] <= tn:
            k.rhs(tn, ynew, force_at(tn, force_t, force_f, hint), model, ws, kend)
            while j < n_out and out_t[j] <= tn:
                _hermite(t, tn - t, y, k1, ynew, kend, out_t[j], out_y, j)
                j += 1
        for i in range(n):
            y[i] = ynew[i]
        t = tn
        steps += 1
    return y, t, steps, status, j


# (t, y) -> (extra generalized forces (9), derivative of the states past the kernel's 18)
ExtraForce = Callable[[float, np.ndarray], tuple[np.ndarray, np.ndarray]]


def _compiled_only(name: str, extra_force: ExtraForce | None) -> None:
    if extra_force is not None:
        raise RuntimeError(f"integrator {name} is compiled and cannot call Python effect forces; "
                           "use a scipy-<method> integrator")


class Integrator(Protocol):
    """What the simulation needs from an integrator."""

    name: str

    def advance(self, model: k.Model, ws: k.Workspace,
                y0: np.ndarray, t0: float, t1: float, step: float, force_t: np.ndarray,
                force_f: np.ndarray, out_t: np.ndarray, atol: np.ndarray,
                extra_force: ExtraForce | None = None) -> Advance: ...


@dataclass
class DormandPrince:
    """Adaptive explicit Runge-Kutta 5(4), compiled (the default)."""

    rtol: float = 1e-6
    max_step: float = 2e-4
    max_steps: int = 5_000_000
    name: str = field(default="dopri54", init=False)

    def __post_init__(self) -> None:
        if not (0 < self.rtol < 1):
            raise InputError(f"rtol: expected a number in (0, 1), got {self.rtol}")
        if not self.max_step > 0:
            raise InputError(f"max_step: expected a positive time in s, got {self.max_step}")

    def advance(self, model, ws, y0, t0, t1, step, force_t, force_f, out_t, atol,
                extra_force=None):
        _compiled_only(self.name, extra_force)
        link_standalone_rhs(model, ws, y0)
        out = np.empty((out_t.shape[0], y0.shape[0]))
        y, _t, h, steps, rej, nrhs, status, nfill = dopri_run(
            model, ws, y0, t0, t1, step, force_t, force_f, self.rtol, atol, self.max_step, out_t,
            out, self.max_steps)
        return Advance(y, out[:nfill], h, steps, rej, nrhs, status)


@dataclass
class RungeKutta4:
    """Fixed-step classical RK4, compiled. Stable for h up to ~50 us on this model."""

    step: float = 2e-5
    name: str = field(default="rk4", init=False)

    def __post_init__(self) -> None:
        if not self.step > 0:
            raise InputError(f"step: expected a positive time in s, got {self.step}")

    def advance(self, model, ws, y0, t0, t1, step, force_t, force_f, out_t, atol,
                extra_force=None):
        _compiled_only(self.name, extra_force)
        link_standalone_rhs(model, ws, y0)
        out = np.empty((out_t.shape[0], y0.shape[0]))
        y, _t, steps, status, nfill = rk4_run(model, ws, y0, t0, t1, self.step, force_t,
                                              force_f, out_t, out)
        return Advance(y, out[:nfill], self.step, steps, 0, 4 * steps, status)


@dataclass
class ScipyIntegrator:
    """``scipy.integrate.solve_ivp`` with any of its methods (reference solutions)."""

    method: str = "BDF"
    rtol: float = 1e-6
    max_step: float = 2e-4
    name: str = field(default="scipy", init=False)

    def __post_init__(self) -> None:
        self.name = f"scipy-{self.method}"

    def advance(self, model, ws, y0, t0, t1, step, force_t, force_f, out_t, atol,
                extra_force=None):
        hint = np.zeros(1, dtype=np.int64)
        dy = np.empty_like(y0)
        counter = [0]
        qx = ws.qx
        # the Dahl option's bristle coordinates that do not move are left out of the solver's
        # state (they stay as y0 has them), so its error norm and steps are as before they
        # existed
        keep = _solver_states(model, y0.shape[0])
        full = np.array(y0, dtype=float, copy=True)

        def fun(t: float, yr: np.ndarray) -> np.ndarray:
            counter[0] += 1
            full[keep] = yr
            if extra_force is not None:
                qx[:], dz = extra_force(t, full)
                dy[k.NY :] = dz
            k.rhs(t, full, force_at(t, force_t, force_f, hint), model, ws, dy)
            return dy[keep]

        from scipy.integrate import solve_ivp  # (lazy: only reference runs use it)

        sol = solve_ivp(fun, (t0, t1), y0[keep], method=self.method, rtol=self.rtol,
                        atol=atol[keep], max_step=self.max_step, dense_output=True,
                        first_step=min(step, t1 - t0))
        qx[:] = 0.0
        status = STATUS_OK if sol.success else STATUS_STEP_TOO_SMALL
        out_t = out_t[(out_t >= t0) & (out_t <= t1)]
        out = np.repeat(np.asarray(y0, dtype=float)[None, :], out_t.size, axis=0)
        if out_t.size:
            out[:, keep] = sol.sol(out_t).T
        y1 = np.array(y0, dtype=float, copy=True)
        y1[keep] = sol.y[:, -1]
        return Advance(y1, out, step, int(sol.t.size - 1), 0, counter[0], status)


def _solver_states(model: k.Model, n: int) -> np.ndarray:
    """The state's components a solver steps: all but the frozen bristle coordinates of the
    Dahl option (and their rates)."""
    moving = set(k.bristle_coords(model.cl, model.jf))
    frozen = [c for c in range(k.QZ + 1, k.NQ) if c not in moving]
    drop = set(frozen) | {k.NQ + c for c in frozen}
    return np.array([i for i in range(n) if i not in drop], dtype=np.int64)
