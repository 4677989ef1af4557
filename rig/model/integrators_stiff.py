"""Linearly implicit (Rosenbrock-W) integrator for the stiff action model.

The explicit :class:`~rig.model.integrators.DormandPrince` is held to steps of
10-100 us by stability alone: friction at the jack/knuckle contact puts a real
eigenvalue of about -3e5 1/s on the light jack, and the flexible shank adds
lightly damped modes at |lambda| ~ 3e4 1/s. :class:`Rosenbrock` (ROS34PW2, an
L-stable, stiffly accurate 4-stage W-method of order 3 with an embedded order-2
error estimate, Rang & Angermann 2005) takes the steps accuracy allows.

Being a *W-method* it keeps its order with any approximation of the Jacobian,
so one finite-difference Jacobian serves many steps; it is refreshed after a
rejected step or after ``jac_reuse`` accepted steps. The structure of the
system is used twice:

- the upper half of the Jacobian is exactly [0 I] (dq/dt = qdot), so only
  d(qddot)/d(q, qdot) is differenced, over the active coordinates only (frozen
  coordinates have zero rows and columns): 2 * n_active right-hand sides;
- each stage's linear system (I/(h gamma) - J) u = r of size 2 n then reduces
  to one n_active x n_active solve, (g^2 I - g B - A) u_v = g r_v + A r_q with
  g = 1/(h gamma), u_q = (r_q + u_v)/g.

The key force is linear in the rhs, so its time derivative (the W-method's
f_t term) is the force sensitivity, differenced once per Jacobian, times the
force slope. Output is the cubic Hermite interpolant of each step, as in
DormandPrince; the Jacobian is kept between calls that continue one another,
so stepping in 2 ms pieces costs no extra Jacobians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import njit

from rig.model import kernel as k
from rig.model.integrators import Advance, _compiled_only, _hermite, force_at


def _transformed(alpha: np.ndarray, gamma: np.ndarray, b: np.ndarray,
                 bhat: np.ndarray) -> tuple[np.ndarray, ...]:
    """Coefficients for the u = Gamma k form (Hairer & Wanner IV.7, (7.25))."""
    gi = np.linalg.inv(gamma)
    a = alpha @ gi
    c = np.diag(1.0 / np.diag(gamma)) - gi
    m = b @ gi
    e = m - bhat @ gi
    return (np.ascontiguousarray(a), np.ascontiguousarray(c), m, e,
            alpha.sum(axis=1), gamma.sum(axis=1))


_G = 0.4358665215084590
# ROS34PW2 (Rang & Angermann, BIT 45 (2005) 761-787), in the original k-form
_ALPHA = np.array([
    [0.0, 0.0, 0.0, 0.0],
    [0.87173304301691801, 0.0, 0.0, 0.0],
    [0.84457060015369423, -0.11299064236484185, 0.0, 0.0],
    [0.0, 0.0, 1.0, 0.0],
])
_GAMMA = np.array([
    [_G, 0.0, 0.0, 0.0],
    [-0.87173304301691801, _G, 0.0, 0.0],
    [-0.90338057013044082, 0.054180672388095326, _G, 0.0],
    [0.24212380706095346, -1.2232505839045147, 0.54526025533510214, _G],
])
_B = np.array([0.24212380706095346, -1.2232505839045147, 1.5452602553351020, _G])
_BHAT = np.array([0.37810903145819369, -0.096042292212423178, 0.5, 0.2179332607542295])
ROS34PW2 = _transformed(_ALPHA, _GAMMA, _B, _BHAT)
ROS34PW2_GAMMA = _G
ROS34PW2_ORDER = 3  # error estimate is O(h^3)


@njit(cache=True)
def _lu(S, piv, n):
    """In-place LU factorisation with partial pivoting of S[:n, :n]."""
    for c in range(n):
        p = c
        big = abs(S[c, c])
        for r in range(c + 1, n):
            if abs(S[r, c]) > big:
                big = abs(S[r, c])
                p = r
        piv[c] = p
        if p != c:
            for j in range(n):
                tmp = S[c, j]
                S[c, j] = S[p, j]
                S[p, j] = tmp
        d = S[c, c]
        if d == 0.0:
            return False
        for r in range(c + 1, n):
            f = S[r, c] / d
            S[r, c] = f
            if f != 0.0:
                for j in range(c + 1, n):
                    S[r, j] -= f * S[c, j]
    return True


@njit(cache=True)
def _lu_solve(S, piv, x, n):
    """Solve with the factors of _lu, x overwritten."""
    for c in range(n):
        p = piv[c]
        if p != c:
            tmp = x[c]
            x[c] = x[p]
            x[p] = tmp
    for r in range(1, n):
        acc = x[r]
        for j in range(r):
            acc -= S[r, j] * x[j]
        x[r] = acc
    for r in range(n - 1, -1, -1):
        acc = x[r]
        for j in range(r + 1, n):
            acc -= S[r, j] * x[j]
        x[r] = acc / S[r, r]


@njit(cache=True)
def _force_slope(t, force_t, force_f):
    """d(key force)/dt just after t (zero outside the knots)."""
    n = force_t.shape[0]
    if n < 2 or t < force_t[0] or t >= force_t[n - 1]:
        return 0.0
    i = 0
    while i < n - 2 and force_t[i + 1] <= t:
        i += 1
    span = force_t[i + 1] - force_t[i]
    if span <= 0.0:
        return 0.0
    return (force_f[i + 1] - force_f[i]) / span


@njit(cache=True)
def jacobian(t, y, fy, fkey, model, ws, act, JA, JB, gk, ytmp, ftmp):
    """Finite-difference d(qddot)/dq (JA) and d(qddot)/dqdot (JB) on the active
    coordinates, and gk = d(dy/dt)/d(key force). Returns the rhs calls used."""
    nq = k.NQ
    na = act.shape[0]
    n = y.shape[0]
    for i in range(n):
        ytmp[i] = y[i]
    for half in range(2):
        for jj in range(na):
            col = act[jj] + half * nq
            yj = y[col]
            d = 1.5e-8 * max(abs(yj), 1e-3)
            ytmp[col] = yj + d
            d = ytmp[col] - yj
            k.rhs(t, ytmp, fkey, model, ws, ftmp)
            ytmp[col] = yj
            for ii in range(na):
                r = nq + act[ii]
                v = (ftmp[r] - fy[r]) / d
                if half == 0:
                    JA[ii, jj] = v
                else:
                    JB[ii, jj] = v
    # the rhs is affine in the key force: exact sensitivity from one more call
    k.rhs(t, y, fkey + 1.0, model, ws, ftmp)
    for i in range(n):
        gk[i] = ftmp[i] - fy[i]
    return 2 * na + 1


@njit(cache=True)
def ros_run(model, ws, y0, t0, t1, h0, force_t, force_f, rtol, atol, hmax, out_t, out_y,
            max_steps, act, JA, JB, gk, jac_state, jac_reuse, a, c, m, e, alpha, gsum, gam,
            order):
    """Adaptive Rosenbrock-W steps from t0 to t1 with Hermite output at out_t.

    JA, JB, gk hold the Jacobian on entry when jac_state[0] > 0 (it is then
    reused) and the latest one on exit; jac_state[0] counts the steps it served.
    """
    n = y0.shape[0]
    nq = k.NQ
    na = act.shape[0]
    s = m.shape[0]
    y = y0.copy()
    f0 = np.empty(n)
    f1 = np.empty(n)
    fs = np.empty(n)
    yt = np.empty(n)
    ynew = np.empty(n)
    r = np.empty(n)
    U = np.zeros((s, n))
    S = np.empty((na, na))
    piv = np.zeros(na, dtype=np.int64)
    x = np.empty(na)
    ftmp = np.empty(n)
    ytmp = np.empty(n)
    hint = np.zeros(1, dtype=np.int64)
    t = t0
    h = min(h0, hmax, t1 - t0)
    hmin = 1e-13
    n_out = out_t.shape[0]
    j = 0
    while j < n_out and out_t[j] <= t0:
        for i in range(n):
            out_y[j, i] = y[i]
        j += 1
    fk = force_at(t, force_t, force_f, hint)
    k.rhs(t, y, fk, model, ws, f0)
    n_rhs = 1
    n_jac = 0
    steps = 0
    rejected = 0
    status = 0
    err_old = 1e-4
    h_prop = h
    age = jac_state[0]
    fresh = False
    while t < t1:
        if steps + rejected >= max_steps:
            status = -3
            break
        if age <= 0 or age >= jac_reuse:
            n_rhs += jacobian(t, y, f0, fk, model, ws, act, JA, JB, gk, ytmp, ftmp)
            n_jac += 1
            age = 0
            fresh = True
        last = False
        if t + h >= t1 - 1e-15:
            h_prop = h
            h = t1 - t
            last = True
        # S = g^2 I - g B - A, g = 1/(h gamma)
        g = 1.0 / (h * gam)
        for ii in range(na):
            for jj in range(na):
                S[ii, jj] = -g * JB[ii, jj] - JA[ii, jj]
            S[ii, ii] += g * g
        ok = _lu(S, piv, na)
        slope = _force_slope(t, force_t, force_f)
        finite = ok
        for st in range(s):
            if not finite:
                break
            if st == 0:
                for i in range(n):
                    fs[i] = f0[i]
            else:
                for i in range(n):
                    acc = y[i]
                    for q in range(st):
                        acc += a[st, q] * U[q, i]
                    yt[i] = acc
                ts = t + alpha[st] * h
                k.rhs(ts, yt, force_at(ts, force_t, force_f, hint), model, ws, fs)
                n_rhs += 1
            for i in range(n):
                acc = fs[i] + h * gsum[st] * slope * gk[i]
                for q in range(st):
                    acc += c[st, q] / h * U[q, i]
                r[i] = acc
            # reduced solve on the active coordinates
            for ii in range(na):
                acc = g * r[nq + act[ii]]
                for jj in range(na):
                    acc += JA[ii, jj] * r[act[jj]]
                x[ii] = acc
            _lu_solve(S, piv, x, na)
            for i in range(n):
                U[st, i] = 0.0
            for ii in range(na):
                qi = act[ii]
                U[st, nq + qi] = x[ii]
                U[st, qi] = (r[qi] + x[ii]) / g
            for ii in range(na):
                if not math.isfinite(x[ii]):
                    finite = False
        err = 0.0
        if finite:
            for i in range(n):
                acc = y[i]
                ea = 0.0
                for st in range(s):
                    acc += m[st] * U[st, i]
                    ea += e[st] * U[st, i]
                ynew[i] = acc
                sc = atol[i] + rtol * max(abs(y[i]), abs(acc))
                err += (ea / sc) ** 2
            err = math.sqrt(err / n)
            if not math.isfinite(err):
                finite = False
        if not finite:
            if h <= hmin:
                status = -2
                break
            h *= 0.1
            rejected += 1
            if not fresh:
                age = 0
            continue
        if err <= 1.0:
            tn = t1 if last else t + h
            fk1 = force_at(tn, force_t, force_f, hint)
            k.rhs(tn, ynew, fk1, model, ws, f1)
            n_rhs += 1
            while j < n_out and out_t[j] <= tn:
                _hermite(t, tn - t, y, f0, ynew, f1, out_t[j], out_y, j)
                j += 1
            t = tn
            fk = fk1
            for i in range(n):
                y[i] = ynew[i]
                f0[i] = f1[i]
            steps += 1
            age += 1
            fresh = False
            # PI controller (Gustafsson) for an error of order h^order
            if err > 0.0:
                fac = 0.9 * err ** (-0.7 / order) * err_old ** (0.4 / order)
            else:
                fac = 5.0
            fac = min(5.0, max(0.2, fac))
            err_old = max(err, 1e-4)
            h = min(h * fac, hmax)
            if last:
                h = min(max(h, h_prop), hmax)
        else:
            h *= max(0.2, 0.9 * err ** (-1.0 / order))
            rejected += 1
            if not fresh:
                age = 0  # a stale Jacobian may be the cause: refresh before retrying
            if h < hmin:
                status = -1
                break
    jac_state[0] = age
    return y, t, h, steps, rejected, n_rhs, n_jac, status, j


@dataclass
class Rosenbrock:
    """Adaptive Rosenbrock-W ROS34PW2 with a reused finite-difference Jacobian, compiled.

    ``jac_reuse``: accepted steps one Jacobian may serve (a rejected step
    refreshes it sooner).
    """

    rtol: float = 1e-6
    max_step: float = 1e-3
    max_steps: int = 5_000_000
    jac_reuse: int = 20
    name: str = field(default="rosenbrock", init=False)
    n_jac: int = field(default=0, init=False)
    _cache: Any = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        if not (0 < self.rtol < 1):
            raise ValueError(f"rtol: expected a number in (0, 1), got {self.rtol}")
        if not self.max_step > 0:
            raise ValueError(f"max_step: expected a positive time in s, got {self.max_step}")
        if self.max_steps < 1:
            raise ValueError(f"max_steps: expected a positive count, got {self.max_steps}")
        if self.jac_reuse < 1:
            raise ValueError(f"jac_reuse: expected a positive count, got {self.jac_reuse}")

    def advance(self, model, ws, y0, t0, t1, step, force_t, force_f, out_t, atol,
                extra_force=None):
        _compiled_only(self.name, extra_force)
        y0 = np.ascontiguousarray(y0, dtype=float)
        act = _active(model, y0.shape[0])
        na = act.shape[0]
        c = self._cache
        if (c is not None and c[0] is model and c[1] == t0 and c[3].shape[0] == na
                and np.array_equal(c[2], y0)):
            JA, JB, gk, state = c[3], c[4], c[5], c[6]
        else:
            JA = np.zeros((na, na))
            JB = np.zeros((na, na))
            gk = np.zeros(y0.shape[0])
            state = np.zeros(1, dtype=np.int64)
        out = np.empty((out_t.shape[0], y0.shape[0]))
        a, cc, m, e, alpha, gsum = ROS34PW2
        y, t, h, steps, rej, nrhs, njac, status, nfill = ros_run(
            model, ws, y0, t0, t1, step, force_t, force_f, self.rtol, atol, self.max_step,
            out_t, out, self.max_steps, act, JA, JB, gk, state, self.jac_reuse, a, cc, m, e,
            alpha, gsum, ROS34PW2_GAMMA, float(ROS34PW2_ORDER))
        self.n_jac += njac
        self._cache = (model, t1, y.copy(), JA, JB, gk, state) if status == 0 else None
        return Advance(y, out[:nfill], h, steps, rej, nrhs, status)


def _active(model: tuple[np.ndarray, ...], n_state: int) -> np.ndarray:
    """Indices of the coordinates that move (the others are frozen by the model's flags)."""
    if n_state != k.NY:
        raise ValueError(f"y0: expected {k.NY} states, got {n_state}")
    sp = model[0]
    active = np.ones(k.NQ, dtype=bool)
    active[k.QYK] = sp[k.S_LIFTOFF] > 0.5
    active[k.QU1 : k.QV2 + 1] = sp[k.S_FLEX] > 0.5
    return np.flatnonzero(active).astype(np.int64)
