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

from rig.errors import InputError
from rig.model import kernel as k
from rig.model.integrators import Advance, _compiled_only, _hermite, force_at, link_standalone_rhs


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
ROS_A, ROS_C, ROS_M, ROS_E, ROS_ALPHA, ROS_GSUM = _transformed(_ALPHA, _GAMMA, _B, _BHAT)
ROS_GAMMA = _G

# Dormand-Prince 5(4) (the same pair as DormandPrince), for the explicit steps
DP_C = np.array([0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0])
DP_A = np.zeros((6, 6))
DP_A[1, 0] = 1 / 5
DP_A[2, :2] = 3 / 40, 9 / 40
DP_A[3, :3] = 44 / 45, -56 / 15, 32 / 9
DP_A[4, :4] = 19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729
DP_A[5, :5] = 9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656
DP_B = np.array([35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84])
DP_E = np.array([71 / 57600, 0.0, -71 / 16695, 71 / 1920, -17253 / 339200, 22 / 525, -1 / 40])


@njit(**k.HOT)
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


@njit(**k.HOT)
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


@njit(**k.HOT)
def _force_slope(t, force_t, force_f, hint):
    """d(key force)/dt just after t (zero outside the knots); hint[1] caches the last
    segment (a table of 6001 knots, an effect's transformed input, was scanned from its
    start at every implicit step)."""
    n = force_t.shape[0]
    if n < 2 or t < force_t[0] or t >= force_t[n - 1]:
        return 0.0
    i = hint[1]
    if i < 0 or i > n - 2:
        i = 0
    while i < n - 2 and force_t[i + 1] <= t:
        i += 1
    while i > 0 and force_t[i] > t:
        i -= 1
    hint[1] = i
    span = force_t[i + 1] - force_t[i]
    if span <= 0.0:
        return 0.0
    return (force_f[i + 1] - force_f[i]) / span


@njit(**k.HOT)
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
            d = 1.5e-8 * max(abs(yj), 1e-3 if half == 0 else 0.1)
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


@njit(**k.HOT)
def _spectral_radius(JA, JB, na, v, w):
    """|lambda|max of J = [[0, I], [JA, JB]] by 24 power iterations (works for pairs)."""
    for i in range(2 * na):
        v[i] = 1.0
    logsum = 0.0
    cnt = 0
    for it in range(24):
        nrm = 0.0
        for i in range(na):
            acc = 0.0
            for j in range(na):
                acc += JA[i, j] * v[j] + JB[i, j] * v[na + j]
            w[i] = v[na + i]
            w[na + i] = acc
        for i in range(2 * na):
            nrm += w[i] * w[i]
        nrm = math.sqrt(nrm)
        if nrm == 0.0 or not math.isfinite(nrm):
            return 0.0
        if it >= 8:
            logsum += math.log(nrm)
            cnt += 1
        for i in range(2 * na):
            v[i] = w[i] / nrm
    return math.exp(logsum / cnt)


@njit(**k.HOT)
def axial_advance(h, u0, v0, s0, s1, w2, beta):
    """Exact step of the one-way coupled axial coordinate over h.

    u'' + beta w2 u' + w2 u = w2 s(t), with the quasi-static strain s linear from s0 to s1
    over the step (first-order hold): the particular solution s(t) - beta s' plus the free
    oscillation (under-, critically or over-damped) of the difference. Returns u, u' at h.
    """
    c = beta * w2
    b = (s1 - s0) / h
    e0 = u0 - (s0 - c * b / w2)
    e0d = v0 - b
    sig = 0.5 * c
    d2 = w2 - sig * sig
    if d2 > 0.0:
        wd = math.sqrt(d2)
        cw = math.cos(wd * h)
        sw = math.sin(wd * h) / wd
    elif d2 < 0.0:
        wd = math.sqrt(-d2)
        cw = math.cosh(wd * h)
        sw = math.sinh(wd * h) / wd
    else:
        cw = 1.0
        sw = h
    ex = math.exp(-sig * h)
    u = s1 - c * b / w2 + ex * ((cw + sig * sw) * e0 + sw * e0d)
    v = b + ex * (-w2 * sw * e0 + (cw - sig * sw) * e0d)
    return u, v


# state slots kept between calls
ST_AGE, ST_MODE, ST_HEXP, ST_STIFF, ST_SLOW = range(5)


@njit(**k.HOT)
def ros_run(model, ws, work, t0, t1, h0, force_t, force_f, rtol, atol, hmax, out_t, out_y,
            max_steps, act, JA, JB, gk, state, jac_reuse, refresh_age, switching, to_implicit,
            to_explicit, trace):
    """Adaptive steps from t0 to t1 with Hermite output at out_t.

    Rosenbrock-W (ROS34PW2) steps; with ``switching``, Dormand-Prince 5(4) steps
    wherever those are cheaper (accuracy, not stability, limits the step).
    JA, JB, gk hold the Jacobian on entry when state[ST_AGE] > 0 (it is then
    reused) and the latest one on exit. A one-way coupled axial shank coordinate
    (kernel.S_AXIAL_ONEWAY) is not part of the steps: it is advanced exactly over each
    accepted step (axial_advance) under the quasi-static strain at the step's ends, and
    left out of the error norm.

    ``work`` (``ros_work``): the state y (y0 on entry, y at the end on exit) and the
    scratch arrays. Allocation-free, so compiled without numba's reference counting.
    """
    y, f0, f1, fs, yt, ynew, r, U, K, S, piv, x, pv, pw, ftmp, ytmp, hint, ew = work
    a, c, m, e, alpha, gsum = ROS_A, ROS_C, ROS_M, ROS_E, ROS_ALPHA, ROS_GSUM
    gam = ROS_GAMMA
    n = y.shape[0]
    nq = k.NQ
    na = act.shape[0]
    s = m.shape[0]
    sp = model.sp
    axial = sp[k.S_FLEX] > 0.5 and sp[k.S_AXIAL_ONEWAY] > 0.5
    iu = k.QU1
    iv = nq + k.QU1
    w2 = sp[k.S_AXW2]
    beta = sp[k.S_BETA]
    n_err = 0  # the components in the error norm (ros_work's weights say which)
    for i in range(n):
        if ew[i] > 0.0:
            n_err += 1
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
    age = int(state[ST_AGE])
    implicit = state[ST_MODE] > 0.5 or not switching
    h_exp = state[ST_HEXP]
    stiff = int(state[ST_STIFF])
    slow = int(state[ST_SLOW])
    fresh = False
    while t < t1:
        if steps + rejected >= max_steps:
            status = -3
            break
        if implicit and (age <= 0 or age >= jac_reuse):
            n_rhs += jacobian(t, y, f0, fk, model, ws, act, JA, JB, gk, ytmp, ftmp)
            n_jac += 1
            age = 0
            fresh = True
            if switching:
                rho = _spectral_radius(JA, JB, na, pv, pw)
                h_exp = 3.0 / rho if rho > 0.0 else hmax
        last = False
        if t + h >= t1 - 1e-15:
            h_prop = h
            h = t1 - t
            last = True
        err = 0.0
        imax = -1
        finite = True
        hlamb = 0.0
        if implicit:
            order = 3.0
            # S = g^2 I - g B - A, g = 1/(h gamma)
            g = 1.0 / (h * gam)
            for ii in range(na):
                for jj in range(na):
                    S[ii, jj] = -g * JB[ii, jj] - JA[ii, jj]
                S[ii, ii] += g * g
            finite = _lu(S, piv, na)
            slope = _force_slope(t, force_t, force_f, hint)
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
            if finite:
                emax = -1.0
                for i in range(n):
                    acc = y[i]
                    ea = 0.0
                    for st in range(s):
                        acc += m[st] * U[st, i]
                        ea += e[st] * U[st, i]
                    ynew[i] = acc
                    sc = atol[i] + rtol * max(abs(y[i]), abs(acc))
                    err += ew[i] * (ea / sc) ** 2
                    if ew[i] * abs(ea / sc) > emax:
                        emax = abs(ea / sc)
                        imax = i
        else:
            order = 5.0
            for st in range(1, 6):
                for i in range(n):
                    acc = y[i]
                    for q in range(st):
                        acc += h * DP_A[st, q] * (f0[i] if q == 0 else K[q, i])
                    yt[i] = acc
                if axial:  # the stiff axial oscillator is not stepped (axial_advance is)
                    yt[iu] = y[iu]
                    yt[iv] = y[iv]
                ts = t + DP_C[st] * h
                k.rhs(ts, yt, force_at(ts, force_t, force_f, hint), model, ws, fs)
                for i in range(n):
                    K[st, i] = fs[i]
            for i in range(n):
                acc = f0[i] * DP_B[0]
                for q in range(1, 6):
                    acc += DP_B[q] * K[q, i]
                ynew[i] = y[i] + h * acc
            if axial:
                ynew[iu] = y[iu]
                ynew[iv] = y[iv]
            tn = t + h
            k.rhs(tn, ynew, force_at(tn, force_t, force_f, hint), model, ws, f1)
            n_rhs += 6
            stnum = 0.0
            stden = 0.0
            emax = -1.0
            for i in range(n):
                ea = f0[i] * DP_E[0] + DP_E[6] * f1[i]
                for q in range(1, 6):
                    ea += DP_E[q] * K[q, i]
                ea *= h
                sc = atol[i] + rtol * max(abs(y[i]), abs(ynew[i]))
                err += ew[i] * (ea / sc) ** 2
                if ew[i] * abs(ea / sc) > emax:
                    emax = abs(ea / sc)
                    imax = i
                if not math.isfinite(ynew[i]):
                    finite = False
                # Hairer's stiffness test: last two stages share t + h
                stnum += ew[i] * (f1[i] - K[5, i]) ** 2
                stden += ew[i] * (ynew[i] - yt[i]) ** 2
            if stden > 0.0:
                hlamb = h * math.sqrt(stnum / stden)
        if finite:
            err = math.sqrt(err / n_err)
            if not math.isfinite(err):
                finite = False
        nt = steps + rejected
        if nt < trace.shape[0]:
            trace[nt, 0] = t
            trace[nt, 1] = h
            trace[nt, 2] = err
            trace[nt, 3] = imax
            trace[nt, 4] = age if implicit else -1.0
        if not finite:
            if h <= hmin:
                status = -2
                break
            h *= 0.1
            rejected += 1
            if implicit and not fresh:
                age = 0
            continue
        if err <= 1.0:
            tn = t1 if last else t + h
            fk1 = force_at(tn, force_t, force_f, hint)
            if implicit:
                k.rhs(tn, ynew, fk1, model, ws, f1)
                n_rhs += 1
            if axial:
                # the quasi-static strain at both ends from u1'' = w2 (s - u1 - beta u1')
                s0 = f0[iv] / w2 + y[iu] + beta * y[iv]
                s1 = f1[iv] / w2 + ynew[iu] + beta * ynew[iv]
                un, vn = axial_advance(tn - t, y[iu], y[iv], s0, s1, w2, beta)
                ynew[iu] = un
                ynew[iv] = vn
                f1[iu] = vn
                f1[iv] = w2 * (s1 - un - beta * vn)
            while j < n_out and out_t[j] <= tn:
                _hermite(t, tn - t, y, f0, ynew, f1, out_t[j], out_y, j)
                j += 1
            t = tn
            fk = fk1
            for i in range(n):
                y[i] = ynew[i]
                f0[i] = f1[i]
            steps += 1
            if implicit:
                age += 1
            fresh = False
            # PI controller (Gustafsson) for an error of order h^order
            fac = 0.9 * err ** (-0.7 / order) * err_old ** (0.4 / order) if err > 0.0 else 5.0
            fac = min(5.0, max(0.2, fac))
            err_old = max(err, 1e-4)
            h = min(h * fac, hmax)
            if last:
                h = min(max(h, h_prop), hmax)
            if switching:
                if implicit:
                    # explicit steps are cheaper once accuracy holds the step this low
                    slow = slow + 1 if h < to_explicit * h_exp else 0
                    if slow >= 3:
                        implicit = False
                        slow = 0
                        stiff = 0
                        h = min(h, h_exp)
                        err_old = 1e-4
                else:
                    if hlamb > 3.25:
                        stiff += 1
                    elif stiff > 0:
                        stiff -= 1
                    if stiff >= to_implicit:
                        implicit = True
                        stiff = 0
                        age = 0
                        h_exp = h
                        h = min(2.0 * h, hmax)
                        err_old = 1e-4
        else:
            h *= max(0.2, 0.9 * err ** (-1.0 / order))
            rejected += 1
            if implicit and age >= refresh_age:
                age = 0  # a stale Jacobian may be the cause: refresh before retrying
            if h < hmin:
                status = -1
                break
    state[ST_AGE] = age
    state[ST_MODE] = 1.0 if implicit else 0.0
    state[ST_HEXP] = h_exp
    state[ST_STIFF] = stiff
    state[ST_SLOW] = slow
    return t, h, steps, rejected, n_rhs, n_jac, status, j


def ros_work(y0: np.ndarray, na: int, model: k.Model) -> tuple[np.ndarray, ...]:
    """ros_run's work arrays: the state (a copy of y0), stage and scratch vectors, the
    LU's matrix and pivots, the force table's search hints (force_at's, the slope's),
    the error norm's weights."""
    n = y0.shape[0]
    ew = np.ones(n)  # a one-way coupled axial pair is not stepped: out of the error norm
    if model.sp[k.S_FLEX] > 0.5 and model.sp[k.S_AXIAL_ONEWAY] > 0.5:
        ew[k.QU1] = 0.0
        ew[k.NQ + k.QU1] = 0.0
    # the Dahl option's bristle coordinates that do not move are out of it too (as before
    # they existed)
    moving = k.bristle_coords(model.cl, model.jf)
    for c in range(k.QZ + 1, k.NQ):
        if c not in moving:
            ew[c] = 0.0
            ew[k.NQ + c] = 0.0
    return (np.array(y0, dtype=float, copy=True), np.empty(n), np.empty(n), np.empty(n),
            np.empty(n), np.empty(n), np.empty(n), np.zeros((ROS_M.shape[0], n)),
            np.zeros((6, n)), np.empty((na, na)), np.zeros(na, dtype=np.int64), np.empty(na),
            np.empty(2 * na), np.empty(2 * na), np.empty(n), np.empty(n),
            np.zeros(2, dtype=np.int64), ew)


@dataclass
class Rosenbrock:
    """Adaptive Rosenbrock-W (ROS34PW2) with a reused finite-difference Jacobian, compiled.

    With ``switching`` (the default) it also takes Dormand-Prince steps while
    those are the cheaper ones, i.e. where accuracy rather than stiffness holds
    the step down (Hairer's stiffness test switches to the implicit steps; an
    implicit step below ``to_explicit`` times the explicit stability limit,
    estimated from the Jacobian's spectral radius, switches back).
    ``jac_reuse``: accepted steps one Jacobian may serve; a rejected step
    refreshes a Jacobian that served ``refresh_age`` steps or more.
    """

    rtol: float = 1e-6
    max_step: float = 1e-3
    max_steps: int = 5_000_000
    jac_reuse: int = 20
    refresh_age: int = 3
    switching: bool = True
    to_implicit: int = 10
    to_explicit: float = 0.6
    name: str = field(default="rosenbrock", init=False)
    n_jac: int = field(default=0, init=False)
    _cache: Any = field(default=None, init=False, repr=False)
    # diagnostics: give it rows to record (t, h, error, worst component, Jacobian age
    # or -1 for an explicit step) of each attempted step of the next call
    _trace: Any = field(default_factory=lambda: np.zeros((0, 5)), init=False, repr=False)

    def __post_init__(self) -> None:
        if not (0 < self.rtol < 1):
            raise InputError(f"rtol: expected a number in (0, 1), got {self.rtol}")
        if not self.max_step > 0:
            raise InputError(f"max_step: expected a positive time in s, got {self.max_step}")
        for name in ("max_steps", "jac_reuse", "refresh_age", "to_implicit"):
            if getattr(self, name) < 1:
                raise InputError(f"{name}: expected a positive count, got {getattr(self, name)}")
        if not self.to_explicit > 0:
            raise InputError(f"to_explicit: expected a positive ratio, got {self.to_explicit}")

    def advance(self, model, ws, y0, t0, t1, step, force_t, force_f, out_t, atol,
                extra_force=None):
        _compiled_only(self.name, extra_force)
        y0 = np.ascontiguousarray(y0, dtype=float)
        act = _active(model, y0.shape[0])
        link_standalone_rhs(model, ws, y0)
        na = act.shape[0]
        c = self._cache
        if (c is not None and c[0] is model and c[1] == t0 and c[3].shape[0] == na
                and np.array_equal(c[2], y0)):
            # this call continues the last one: keep its Jacobian and mode
            JA, JB, gk, state = c[3], c[4], c[5], c[6]
        else:
            JA = np.zeros((na, na))
            JB = np.zeros((na, na))
            gk = np.zeros(y0.shape[0])
            state = np.zeros(5)
            state[ST_MODE] = 1.0  # start implicit: the rest state is stiff
        out = np.empty((out_t.shape[0], y0.shape[0]))
        work = ros_work(y0, na, model)
        _t, h, steps, rej, nrhs, njac, status, nfill = ros_run(
            model, ws, work, t0, t1, step, force_t, force_f, self.rtol, atol, self.max_step,
            out_t, out, self.max_steps, act, JA, JB, gk, state, self.jac_reuse,
            self.refresh_age, self.switching, self.to_implicit, self.to_explicit, self._trace)
        y = work[0]
        self.n_jac += njac
        self._cache = (model, t1, y.copy(), JA, JB, gk, state) if status == 0 else None
        return Advance(y, out[:nfill], h, steps, rej, nrhs, status)


def _active(model: k.Model, n_state: int) -> np.ndarray:
    """Indices of the coordinates that move (the others are frozen by the model's flags)."""
    if n_state != k.NY:
        raise InputError(f"y0: expected {k.NY} states, got {n_state}")
    sp = model.sp
    active = np.ones(k.NQ, dtype=bool)
    active[k.QYK] = sp[k.S_LIFTOFF] > 0.5
    active[k.QU1 : k.QV2 + 1] = sp[k.S_FLEX] > 0.5
    active[k.QZ] = sp[k.S_BRISTLE] > 0.5
    active[k.QZ + 1 :] = False
    active[k.bristle_coords(model.cl, model.jf)] = True
    if sp[k.S_AXIAL_ONEWAY] > 0.5:
        active[k.QU1] = False  # advanced exactly by ros_run, not by the steps
    return np.flatnonzero(active).astype(np.int64)
