"""The best tracking any feedforward can reach on a drive model (issue 18): an offline bound.

What no learner can beat, noise-free, with the loop's limits (``motor_torque.Limiter``:
demand in [0, max_force], change per cycle <= max_rate x dt, from 0 before the trial):
the minimax error max_j |r_j - max(y_j, 0)| over every demand sequence on the 500 Hz
grid, ``y`` the lifted drive model (``rig.control.plant.DriveModel``, whose rise/fall
mode follows the demand's direction: rising after an increase, falling after a
decrease, else as before).

* ``fixed_modes``: the mode sequence given; the model is then linear, the problem a
  linear programme (HiGHS). The mode constraints (an increase where rising, a decrease
  where falling; a switch needs a change of at least ``SWITCH_STEP_N`` in its
  direction) make the demand found play those modes exactly.
* ``planned``: a local search over mode schedules that fall over intervals (each
  release, found from the reference's falling runs, and where it brakes): the start
  and end of each falling interval moved by a coordinate search, an interval cut in
  two by a rise (up to ``max_falls`` intervals), one ``fixed_modes`` programme per
  schedule tried (memoised). What the learner plans with (``rig.control.ilc``):
  releases that follow the profile or brake on their way down and at their end (at
  most twice as many falling intervals as the profile has releases, each switch a
  reversal of ``switch_n``), not the modes switched every cycle.
* ``best_demand``: the modes free as well: a mixed-integer linear programme (the
  state at each cycle, each mode's transition bounded by big-M constraints on a
  binary per cycle), optionally with at most ``max_switches`` mode changes; solved to
  a time limit, so the demand found is achievable (its error by simulation) and
  ``dual_bound_n`` is what no demand can beat.

The key force reads 0 while the model's state is below zero (the drive pushes only),
so an error constraint's lower side applies only where r_j exceeds the error allowed
(found by iterating the bound). SI units: forces N, rates N/s.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import Bounds, LinearConstraint, linprog, milp
from scipy.sparse import coo_matrix, csr_matrix, hstack, identity, vstack

from rig.control import plant
from rig.errors import InputError
from rig.inputs.config import Limits

SWITCH_STEP_N = 1e-3   # the smallest demand change a mode switch is counted with (N)


@dataclass(frozen=True)
class Bound:
    max_error_n: float        # the demand's maximum key-force error, by simulation (N)
    demand: np.ndarray        # the demand sequence (N per cycle)
    rising: np.ndarray        # its modes (True: the rising model)
    dual_bound_n: float = 0.0  # no demand has a smaller maximum error (N)
    optimal: bool = True
    falls: tuple[tuple[int, int], ...] = field(default=())   # planned's schedule
    programmes: int = 0        # planned: the fixed-mode programmes solved

    @property
    def switches(self) -> int:
        return int(np.sum(self.rising[1:] != self.rising[:-1]) + (not self.rising[0]))


def _key_errors(model: plant.DriveModel, r: np.ndarray, d: np.ndarray, hz: float
                ) -> np.ndarray:
    """|r_j - max(y_j, 0)| at each cycle (N): the key force feels only a pushing drive."""
    return np.abs(np.asarray(r, float) - np.maximum(model.simulate(d, hz), 0.0))


def key_error(model: plant.DriveModel, r: np.ndarray, d: np.ndarray, hz: float) -> float:
    """max_j |r_j - max(y_j, 0)|: the key force's largest error for demand ``d`` (N)."""
    return float(_key_errors(model, r, d, hz).max())


def timing_spread(model: plant.DriveModel, d: np.ndarray, hz: float, jitter_s: float
                  ) -> np.ndarray:
    """The standard deviation of the force at each cycle (N) when each write of demand
    ``d`` comes at a time that varies by ``jitter_s`` (its standard deviation, s,
    independent from cycle to cycle): a write late by delta holds the previous demand
    delta longer, a pulse of -(d_k - d_{k-1}) over delta, whose response is about
    (delta hz) times the lifted model's column k (the response to one cycle's demand);
    so s_j^2 = (jitter_s hz)^2 sum_k G_jk^2 (d_k - d_{k-1})^2."""
    d = np.asarray(d, float)
    G = model.lifted(model.modes(d), hz)
    step = np.diff(np.r_[0.0, d])
    return jitter_s * hz * np.sqrt((G ** 2) @ (step ** 2))


def timed_error(model: plant.DriveModel, r: np.ndarray, d: np.ndarray, hz: float,
                jitter_s: float) -> float:
    """``key_error`` with the writes' timing: max_j |r_j - max(y_j, 0)| + 3 s_j (N), s
    from ``timing_spread`` (3 sigma: what the timing reaches at a cycle in about one
    trial of several hundred). Equal to ``key_error`` for exact timing."""
    e = _key_errors(model, r, d, hz)
    if jitter_s > 0:
        e = e + 3.0 * timing_spread(model, d, hz, jitter_s)
    return float(e.max())


def fixed_modes(model: plant.DriveModel, reference: np.ndarray, rising: np.ndarray,
                limits: Limits, control_hz: float, *, smooth: float = 0.0,
                switch_n: float = SWITCH_STEP_N) -> Bound:
    """The minimax demand for the mode sequence ``rising`` (a linear programme); each
    switch of the modes a change of the demand of at least ``switch_n`` in its direction.

    ``smooth`` > 0: of the demands within (1 + smooth) x that maximum error, the one
    with the least mean error and, within (1 + smooth) x that, the least total variation
    (two more programmes): the minimax demand is not unique where the error is below
    its maximum, and the solver's vertex can swing from limit to limit there."""
    r = np.asarray(reference, float)
    rising = np.asarray(rising, bool)
    n = r.size
    if rising.shape != r.shape:
        raise InputError(f"modes: expected {n} points, got {rising.size}")
    G = model.lifted(rising, control_hz)
    step = limits.max_rate_n_per_s / control_hz
    D = np.eye(n) - np.eye(n, k=-1)          # d_j - d_{j-1}, d_{-1} = 0
    one, z = np.ones((n, 1)), np.zeros((n, 1))
    two_modes = model.rise != model.fall
    prev = np.r_[True, rising[:-1]]
    sgn = np.where(rising, -1.0, 1.0)         # rising: -(d_j - d_{j-1}) <= -switch
    switch = -np.where(rising != prev, switch_n, 0.0)

    def lp(lower: np.ndarray) -> tuple[float, np.ndarray | None]:
        rows = [np.hstack([G, -one]), np.hstack([-G[lower], -one[lower]]),
                np.hstack([D, z]), np.hstack([-D, z])]
        rhs = [r, -r[lower], np.full(n, step), np.full(n, step)]
        if two_modes:
            rows.append(np.hstack([sgn[:, None] * D, z]))
            rhs.append(switch)
        res = linprog(np.r_[np.zeros(n), 1.0], A_ub=np.vstack(rows), b_ub=np.concatenate(rhs),
                      bounds=[(0.0, limits.max_force_n)] * n + [(0.0, None)], method="highs")
        return (float(res.x[-1]), res.x[:n]) if res.status == 0 else (np.inf, None)

    t = 0.0
    d: np.ndarray | None = None
    for _ in range(20):   # the lower sides where r_j > t, t the bound: a fixed point
        lower = r > t + 1e-9
        t_new, d = lp(lower)
        if d is None or np.array_equal(r > t_new + 1e-9, lower):
            t = t_new
            break
        t = t_new
    if d is None:
        raise InputError("fixed_modes: no demand plays this mode sequence within the limits")
    if smooth > 0:
        calm = _calmest(G, r, lower, (1.0 + smooth) * t + 1e-9, smooth, step,
                        switch if two_modes else None, sgn, limits.max_force_n)
        d = d if calm is None else calm
    d = _clean(d, rising, limits, control_hz)
    return Bound(key_error(model, r, d, control_hz), d, rising, t)


def _calmest(G: np.ndarray, r: np.ndarray, lower: np.ndarray, allowed: float, smooth: float,
             step: float, switch: np.ndarray | None, sgn: np.ndarray,
             max_force: float) -> np.ndarray | None:
    """Within error ``allowed`` everywhere: the least mean error, then (within 1 + smooth
    of it) the least total variation sum |d_j - d_{j-1}|. Variables [d, a, s]: a_j >=
    |error_j|, s_j >= |d_j - d_{j-1}|. None if the solver fails (the caller keeps its
    minimax demand)."""
    n = r.size
    Gs = csr_matrix(G)
    Gl = csr_matrix(G[lower])
    Il = identity(n, format="csr")[lower]
    Id = identity(n, format="csr")
    D = csr_matrix(np.eye(n) - np.eye(n, k=-1))
    Z = csr_matrix((n, n))
    Zl = csr_matrix((int(lower.sum()), n))
    rows = [hstack([Gs, Z, Z]), hstack([-Gl, Zl, Zl]),            # |error| <= allowed
            hstack([Gs, -Id, Z]), hstack([-Gl, -Il, Zl]),          # a >= |error|
            hstack([D, Z, -Id]), hstack([-D, Z, -Id]),              # s >= |diff|
            hstack([D, Z, Z]), hstack([-D, Z, Z])]                # the rate limit
    rhs = [r + allowed, -(r[lower] - allowed), r, -r[lower], np.zeros(n), np.zeros(n),
           np.full(n, step), np.full(n, step)]
    if switch is not None:
        rows.append(hstack([D.multiply(sgn[:, None]), Z, Z]))
        rhs.append(switch)
    A = vstack(rows, format="csr")
    b = np.concatenate(rhs)
    bounds = [(0.0, max_force)] * n + [(0.0, None)] * (2 * n)
    first = linprog(np.r_[np.zeros(n), np.ones(n), np.zeros(n)], A_ub=A, b_ub=b,
                    bounds=bounds, method="highs")
    if first.status != 0:
        return None
    mean_cap = (1.0 + smooth) * float(first.fun) + 1e-9
    A2 = vstack([A, csr_matrix(np.r_[np.zeros(n), np.ones(n), np.zeros(n)][None, :])],
                format="csr")
    second = linprog(np.r_[np.zeros(2 * n), np.ones(n)], A_ub=A2, b_ub=np.r_[b, mean_cap],
                     bounds=bounds, method="highs")
    return np.asarray(second.x[:n]) if second.status == 0 else np.asarray(first.x[:n])


def _clean(d: np.ndarray, rising: np.ndarray, limits: Limits, control_hz: float) -> np.ndarray:
    """The solver's demand without changes below its tolerance (which would switch the
    modes where the solution keeps them) or beyond the rate limit by its tolerance."""
    step = limits.max_rate_n_per_s / control_hz
    diff = np.clip(np.diff(np.r_[0.0, np.clip(d, 0.0, limits.max_force_n)]), -step, step)
    prev = np.r_[True, rising[:-1]]
    small = np.abs(diff) < 0.1 * SWITCH_STEP_N
    diff[small & (rising == prev)] = 0.0
    return np.clip(np.cumsum(diff), 0.0, limits.max_force_n)


def falling_runs(reference: np.ndarray, lead: int) -> tuple[tuple[int, int], ...]:
    """Where a demand tracking ``reference`` plays the falling model: each run of cycles
    over which the reference falls, from ``lead`` cycles before it (the drive lags) to
    ``2 lead`` after it (the fall's tail), overlapping runs merged; [start, end) pairs."""
    r = np.asarray(reference, float)
    n = r.size
    falls: list[list[int]] = []
    j = 0
    down = np.diff(r) < 0
    while j < down.size:
        if not down[j]:
            j += 1
            continue
        k = j
        while k < down.size and down[k]:
            k += 1
        a, b = max(j + 1 - lead, 1), min(k + 1 + 2 * lead, n)
        if falls and a <= falls[-1][1]:
            falls[-1][1] = max(falls[-1][1], b)
        else:
            falls.append([a, b])
        j = k
    return tuple((a, b) for a, b in falls)


def schedule(n: int, falls: Sequence[tuple[int, int]]) -> np.ndarray:
    """The mode sequence (True: rising) that falls over each [start, end) of ``falls``."""
    rising = np.ones(n, bool)
    for a, b in falls:
        rising[a:b] = False
    return rising


def _neighbours(falls: tuple[tuple[int, int], ...], s: int, n: int, split: bool = False
                ) -> list[tuple[tuple[int, int], ...]]:
    """The schedules with one end of one falling interval moved by s cycles, and with an
    interval run on to the next one (no rise between them) or to the end (no brake);
    ``split``: also each interval cut by a one-cycle rise every s cycles inside it (a
    release that brakes on its way down)."""
    out: list[tuple[tuple[int, int], ...]] = []
    for i, (a, b) in enumerate(falls):
        if split:
            out.extend(falls[:i] + ((a, m), (m + 1, b)) + falls[i + 1:]
                       for m in range(a + s, b - s, s))
        lo = falls[i - 1][1] + 1 if i else 1
        hi = falls[i + 1][0] - 1 if i + 1 < len(falls) else n
        for na, nb in ((a - s, b), (a + s, b), (a, b - s), (a, b + s)):
            if lo <= na < nb <= hi:
                out.append(falls[:i] + ((na, nb),) + falls[i + 1:])
        if i + 1 < len(falls):
            out.append(falls[:i] + ((a, falls[i + 1][1]),) + falls[i + 2:])
        elif b < n:
            out.append(falls[:i] + ((a, n),))
    return out


def planned(model: plant.DriveModel, reference: np.ndarray, limits: Limits, control_hz: float,
            start: Sequence[tuple[int, int]], *, steps: Sequence[int] = (8, 4, 2, 1),
            smooth: float = 0.0, max_falls: int = 0, switch_n: float = SWITCH_STEP_N) -> Bound:
    """The best demand over the schedules near ``start`` (falling over each [start, end),
    rising elsewhere): a coordinate search moving one end of one interval by each of
    ``steps`` in turn (first improvement; a schedule no demand plays counts as infinite
    error); with fewer than ``max_falls`` intervals and moves of 8 cycles or more, also
    each interval cut by a rise (``_neighbours``); every mode switch a demand change of
    at least ``switch_n``; one ``fixed_modes`` programme per schedule, memoised; the best
    schedule's demand made calm by ``smooth`` (``fixed_modes``). A local optimum:
    ``best_demand`` is the global one, at minutes per profile."""
    r = np.asarray(reference, float)
    n = r.size
    solved: dict[tuple[tuple[int, int], ...], Bound | None] = {}   # None: no demand plays it

    def cost(falls: tuple[tuple[int, int], ...]) -> float:
        if falls not in solved:
            try:
                solved[falls] = fixed_modes(model, r, schedule(n, falls), limits, control_hz,
                                            switch_n=switch_n)
            except InputError:
                solved[falls] = None
        b = solved[falls]
        return np.inf if b is None else b.max_error_n

    best = tuple((int(a), int(b)) for a, b in start)
    if not all(1 <= a < b <= n for a, b in best):
        raise InputError(f"planned: falling intervals outside 1..{n}: {best}")
    if model.rise == model.fall:
        steps = ()          # one model: every schedule is the same programme
    c_best = cost(best)
    for s in steps:
        improved = True
        while improved:
            improved = False
            for cand in _neighbours(best, int(s), n, split=len(best) < max_falls and s >= 8):
                c = cost(cand)
                if c < c_best * (1.0 - 1e-9):
                    best, c_best, improved = cand, c, True
                    break
    if not np.isfinite(c_best):
        raise InputError("planned: no demand plays any schedule tried within the limits")
    out = solved[best]
    assert out is not None
    if smooth > 0:
        out = fixed_modes(model, r, schedule(n, best), limits, control_hz, smooth=smooth,
                          switch_n=switch_n)
    return Bound(out.max_error_n, out.demand, out.rising, out.dual_bound_n, False, best,
                 len(solved) + (smooth > 0))


def best_demand(model: plant.DriveModel, reference: np.ndarray, limits: Limits,
                control_hz: float, *, max_switches: int | None = None,
                time_limit_s: float = 60.0, error_hint_n: float = 0.0,
                switch_step_n: float = SWITCH_STEP_N) -> Bound:
    """The minimax demand with the modes free (a mixed-integer programme, HiGHS, to
    ``time_limit_s``). ``switch_step_n``: the smallest demand change a mode switch is made
    with (larger: only reversals of that size). ``error_hint_n``: the error expected; the
    lower side of the error constraint is kept only where r_j exceeds it (0: everywhere
    r_j > 0, which can only make the bound larger). The force at each tick: a model with a
    ``read_age_s`` is refused (its read between ticks is not in this programme)."""
    if model.read_age_s:
        raise InputError(f"best_demand: {model.name} reads {model.read_age_s * 1e3:g} ms "
                         "before the tick; this programme models the force at the tick")
    r = np.asarray(reference, float)
    n = r.size
    dt = 1.0 / control_hz
    S = np.diag([1.0, dt, dt * dt])        # the state in N, N per cycle, N per cycle^2
    Si = np.linalg.inv(S)
    mats = [(S @ A @ Si, S @ B) for A, B in (model.rise.discrete(dt), model.fall.discrete(dt))]
    step = limits.max_rate_n_per_s * dt
    xb = np.array([2.0, 1.0, 1.0]) * (2.0 * limits.max_force_n)   # generous state bounds
    M = 3.0 * xb
    nx = 3 * (n - 1)                       # x_1 .. x_{n-1} (x_0 = 0), d_0 .. d_{n-1},
    it = nx + 2 * n                        # b_0 .. b_{n-1} (1: rising), t, s_0 .. s_{n-1}
    nv = it + 1 + n
    rows: list[int] = []
    cols: list[int] = []
    vals: list[float] = []
    lo: list[float] = []
    hi: list[float] = []

    def add(c: dict[int, float], low: float, high: float) -> None:
        k = len(lo)
        for col, v in c.items():
            rows.append(k)
            cols.append(col)
            vals.append(v)
        lo.append(low)
        hi.append(high)

    def ix(j: int, k: int) -> int:
        return 3 * (j - 1) + k

    for j in range(n - 1):
        for m, (A, B) in enumerate(mats):   # m = 0: rising (b = 1), 1: falling (b = 0)
            for k in range(3):
                c = {ix(j + 1, k): 1.0, nx + j: -float(B[k])}
                if j >= 1:
                    for q in range(3):
                        c[ix(j, q)] = c.get(ix(j, q), 0.0) - float(A[k, q])
                b = nx + n + j
                if m == 0:   # |x_{j+1} - A_r x_j - B_r d_j| <= M (1 - b)
                    add({**c, b: M[k]}, -np.inf, M[k])
                    add({**c, b: -M[k]}, -M[k], np.inf)
                else:        # |x_{j+1} - A_f x_j - B_f d_j| <= M b
                    add({**c, b: -M[k]}, -np.inf, 0.0)
                    add({**c, b: M[k]}, 0.0, np.inf)
    eps = switch_step_n
    for j in range(n):
        c = {nx + j: 1.0}
        if j:
            c[nx + j - 1] = -1.0
        add(c, -step, step)                 # the rate limit
        b, bp = nx + n + j, nx + n + j - 1
        # modes: diff >= -step (1 - b_j) + eps (b_j - b_{j-1}),
        #        diff <= step b_j - eps (b_{j-1} - b_j)   (b_{-1} = 1: starts rising)
        if j:
            add({**c, b: -step - eps, bp: eps}, -step, np.inf)
            add({**c, b: -step - eps, bp: eps}, -np.inf, 0.0)
            add({nx + 2 * n + 1 + j: 1.0, b: -1.0, bp: 1.0}, 0.0, np.inf)   # s_j >= |b_j -
            add({nx + 2 * n + 1 + j: 1.0, b: 1.0, bp: -1.0}, 0.0, np.inf)   # b_{j-1}|
        else:
            add({**c, b: -step - eps}, -step - eps, np.inf)
            add({**c, b: -step - eps}, -np.inf, -eps)
            add({nx + 2 * n + 1: 1.0, b: 1.0}, 1.0, np.inf)
        if j >= 1:                          # the error at cycle j
            add({ix(j, 0): 1.0, it: -1.0}, -np.inf, float(r[j]))
            if r[j] > error_hint_n:
                add({ix(j, 0): 1.0, it: 1.0}, float(r[j]), np.inf)
        elif r[0] > error_hint_n:
            add({it: 1.0}, float(r[0]), np.inf)
    if max_switches is not None:
        add({nx + 2 * n + 1 + j: 1.0 for j in range(n)}, 0.0, float(max_switches))
    A = coo_matrix((vals, (rows, cols)), shape=(len(lo), nv)).tocsr()
    lb = np.r_[np.tile(-xb, n - 1), np.zeros(2 * n), 0.0, np.zeros(n)]
    ub = np.r_[np.tile(xb, n - 1), np.full(n, limits.max_force_n), np.ones(n), np.inf,
               np.ones(n)]
    integrality = np.r_[np.zeros(nx + n), np.ones(n), 0.0, np.zeros(n)]
    cost = np.zeros(nv)
    cost[it] = 1.0
    res = milp(cost, constraints=LinearConstraint(A, np.array(lo), np.array(hi)),
               integrality=integrality, bounds=Bounds(lb, ub),
               options={"time_limit": time_limit_s, "mip_rel_gap": 1e-4})
    if res.x is None:
        raise InputError(f"best_demand: no demand found ({res.message})")
    rising = np.round(res.x[nx + n: nx + 2 * n]).astype(bool)
    d = _clean(res.x[nx: nx + n], rising, limits, control_hz)
    dual = float(getattr(res, "mip_dual_bound", 0.0) or 0.0)
    return Bound(key_error(model, r, d, control_hz), d, model.modes(d), max(dual, 0.0),
                 res.status == 0)
