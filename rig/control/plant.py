"""The learner's model of the drive chain, lifted to the loop's trial grid (issue 18).

A trial is N loop cycles; at cycle j the loop reads the load cell (y_j), then writes the
demand d_j, held until the next cycle. The drive (thesis Appendix D, Eq. D.1, the
100 Hz load-cell filter inside it)

    G(s) = K / ((1 + 2 zeta Tw s + (Tw s)^2)(1 + Tp3 s))

discretised exactly for the 2 ms hold gives x_{j+1} = A x_j + B d_j, y_j = x_j[0]: y is
strictly causal in d (y_j depends on d_0 .. d_{j-1}). A ``DriveModel`` has one such
model for rising and one for falling demands (the thesis's increasing- and
decreasing-demand models, Figs. D.11-D.16; the state, force and its derivatives,
carries over at a switch); for ``single`` the two are the same. Its mode at cycle j
follows the demand: rising after d_j > d_{j-1}, falling after d_j < d_{j-1}, else as
before. With the modes of a given demand fixed, the model is linear time-varying and
``jacobian(d)`` is its exact N x N (strictly lower-triangular) lifted matrix: the
local linearisation the learning update inverts (Newton-type ILC).

``fit(models, d, y)`` picks, per trial, the candidate that best explains what the
load cell measured for the demand played, with its gain re-estimated by least squares
(y ~ c model(d)): a drive that drifts or differs from the calibration is followed from
trial to trial.

``closed_loop(G, F, C, free)``: with a linear controller in the loop, d = F u - C y (u
the feedforward table), the map u -> y is (I + G C)^-1 G F (the process sensitivity;
G's columns zeroed where the limiter clipped the demand);
``rig.control.feedback.LoadCellPI.lifted`` gives its F and C.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from rig import motor_torque
from rig.errors import InputError
from rig.inputs.params import Parameters
from rig.motor_torque import ProcessModel, RiseFall


@dataclass(frozen=True)
class DriveModel(RiseFall):
    """The drive's rising/falling process models (rig.motor_torque.RiseFall, Eq. D.1) as
    the learner plans with them: simulated on the trial grid, lifted, linearised.

    ``read_age_s``: how long before each cycle's tick the force the loop reads was
    sampled (0 <= age <= one cycle). The loop at tick j has the acquisition's samples up
    to the one before the tick (the tick's own is being taken), one acquisition period
    old: 0.5 ms at 2 kHz (``rig.services.learn.load_cell_at_cycles``, what the learner
    learns from). Then y_j is the force at t_j - age, part of the way through the hold of
    d_{j-1}: y_j = [A(T - age) x_{j-1} + B(T - age) d_{j-1}]_0. Left out, the model
    misses age x the force's rate (measured on the simulated rig, seeds 201-210 in
    lock-step: -0.19 N on forte's 375 N/s rise, +0.38 N on its 750 N/s release, in every
    trial), and the learned release kept about half of it (-0.15 to -0.20 N over the ramp)."""

    read_age_s: float = 0.0

    def _read_matrices(self, dt: float) -> tuple[tuple[np.ndarray, np.ndarray],
                                                  tuple[np.ndarray, np.ndarray]] | None:
        """(A, B) of the hold's part before the read, rising and falling; None: no age."""
        age = self.read_age_s
        if age == 0.0:
            return None
        if not 0.0 < age <= dt * (1 + 1e-9):
            raise InputError(f"read_age_s: expected 0 to one cycle ({dt * 1e3:g} ms), got "
                             f"{age * 1e3:g} ms")
        part = max(dt - age, 0.0)
        pr = self.rise.discrete(part)
        return pr, (pr if self.fall == self.rise else self.fall.discrete(part))

    def simulate(self, d: np.ndarray, control_hz: float) -> np.ndarray:
        """y_j: the force read at cycle j, before demand d_j is written (N); the drive
        pushes only (y >= 0; its state goes on below zero, as the simulated drive's)."""
        return self.simulate_loop(np.asarray(d, float), control_hz)[0]

    def simulate_loop(self, u: np.ndarray, control_hz: float, controller: Any = None,
                      gain: float = 1.0, max_demand: float = np.inf,
                      reference: np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(y, d, free): the force read at each cycle, the demand written (the controller's
        output, if any, ``controller(t, u_j, y_j)`` as in the loop, clipped to
        0..max_demand as the loop's limiter does) and where that clip did not act;
        ``gain`` scales the drive's K; ``reference``: the profile, given to the controller
        as ``target_n`` each cycle as the loop does."""
        u = np.asarray(u, float)
        dt = 1.0 / control_hz
        ar, br = self.rise.discrete(dt)
        af, bf = (ar, br) if self.fall == self.rise else self.fall.discrete(dt)
        read = self._read_matrices(dt)
        if controller is not None:
            controller.reset()
        x = np.zeros(3)
        x_before, d_before = np.zeros(3), 0.0   # the state and demand of the cycle before
        y = np.empty(u.size)
        d = np.empty(u.size)
        free = np.ones(u.size, bool)
        rising, last = True, 0.0
        for j in range(u.size):
            if read is None:
                y[j] = max(x[0], 0.0)
            else:   # read part of the way through the last hold (rising: its mode)
                pa, pb = read[0] if rising else read[1]
                y[j] = max(float(pa[0] @ x_before + pb[0] * (gain * d_before)), 0.0)
            if reference is not None and hasattr(controller, "target_n"):
                controller.target_n = float(reference[j])
            pre = float(u[j]) if controller is None else float(controller(j * dt, u[j], y[j]))
            d[j] = min(max(pre, 0.0), max_demand)
            free[j] = d[j] == pre
            if d[j] > last:
                rising = True
            elif d[j] < last:
                rising = False
            last = float(d[j])
            x_before, d_before = x, float(d[j])
            x = (ar @ x + br * (gain * d[j])) if rising else (af @ x + bf * (gain * d[j]))
        return y, d, free

    def lifted(self, rising: np.ndarray, control_hz: float) -> np.ndarray:
        """y = G d for the mode sequence ``rising`` (N x N, strictly lower triangular; the
        state below zero kept, as the model's)."""
        rising = np.asarray(rising, bool)
        dt = 1.0 / control_hz
        ar, br = self.rise.discrete(dt)
        af, bf = (ar, br) if self.fall == self.rise else self.fall.discrete(dt)
        read = self._read_matrices(dt)
        n = rising.size
        G = np.zeros((n, n))
        X = np.zeros((3, n))   # column i: d x_j / d d_i
        for j in range(n - 1):
            A, B = (ar, br) if rising[j] else (af, bf)
            if read is not None:   # y_{j+1}: part of the way through cycle j's hold
                pa, pb = read[0] if rising[j] else read[1]
                G[j + 1, :j] = pa[0] @ X[:, :j]
                G[j + 1, j] = pb[0]
            X[:, :j] = A @ X[:, :j]
            X[:, j] = B
            if read is None:
                G[j + 1, : j + 1] = X[0, : j + 1]
        return G

    def jacobian(self, d: np.ndarray, control_hz: float) -> np.ndarray:
        """dy/dd at demand d (N x N, strictly lower triangular), its modes held fixed; zero
        rows where the force is clipped at 0."""
        d = np.asarray(d, float)
        G = self.lifted(self._modes(d), control_hz)
        G[G @ d <= 0] = 0.0
        return G


def thesis_models(params: Parameters | None = None) -> tuple[DriveModel, DriveModel]:
    """The thesis's single model and its rising/falling pair (Appendix D;
    rig.motor_torque.thesis_models)."""
    single, risefall = motor_torque.thesis_models(params)
    return (DriveModel(single.name, single.rise, single.fall),
            DriveModel(risefall.name, risefall.rise, risefall.fall))


def from_motor_record(rec: Mapping[str, object]) -> DriveModel | None:
    """The dynamic model a motor calibration record identified (rig calibrate motor)."""
    fit = rec.get("fit")
    dyn = fit.get("dynamic_model") if isinstance(fit, Mapping) else None
    if not isinstance(dyn, Mapping):
        return None
    try:
        m = ProcessModel(float(dyn["K"]), float(dyn["Tw_s"]), float(dyn["zeta"]),
                         float(dyn["Tp3_s"]))
    except (KeyError, TypeError, ValueError, InputError):
        return None
    return DriveModel(f"motor calibration {rec.get('content_hash', '?')}", m, m)


@dataclass(frozen=True)
class Fit:
    model: DriveModel
    gain: float          # the measured force / the model's, least squares
    rms_residual_n: float
    output_norm: float = 1.0   # ||model output|| (N): the gain's uncertainty scale

    def gain_sigma(self, noise_n: float) -> float:
        """The gain estimate's standard deviation under white load-cell noise."""
        return noise_n / max(self.output_norm, 1e-9)


def fit(models: Sequence[DriveModel], demand: np.ndarray, measured: np.ndarray,
        control_hz: float) -> Fit:
    """The candidate (gain re-estimated) that best explains the measured force."""
    if not models:
        raise InputError("fit: expected at least one drive model")
    y = np.asarray(measured, float)
    best: Fit | None = None
    for m in models:
        yh = m.simulate(demand, control_hz)
        den = float(yh @ yh)
        c = float(yh @ y) / den if den > 0 else 1.0
        c = min(max(c, 0.2), 5.0)   # a gain outside 0.2..5 is not the drive: keep it bounded
        rms = float(np.sqrt(np.mean((y - c * yh) ** 2)))
        if best is None or rms < best.rms_residual_n:
            best = Fit(m, c, rms, float(np.sqrt(den)))
    assert best is not None
    return best


def refine(f: Fit, demand: np.ndarray, measured: np.ndarray, control_hz: float) -> Fit:
    """The fitted model's dynamics (Tw, zeta, Tp3 of each mode) identified from this trial
    (least squares on their logarithms, within x0.5..x2 of the candidate's, the gain by
    least squares inside), when that explains the trial better: a learner whose models
    are off (a drive slower or faster than the thesis's) still inverts the drive it has."""
    from scipy.optimize import least_squares

    y = np.asarray(measured, float)
    d = np.asarray(demand, float)
    same = f.model.fall == f.model.rise
    base = [f.model.rise] if same else [f.model.rise, f.model.fall]

    def build(z: np.ndarray) -> DriveModel:
        ms = [ProcessModel(b.K, b.Tw * float(np.exp(z[3 * i])),
                           b.zeta * float(np.exp(z[3 * i + 1])),
                           b.Tp3 * float(np.exp(z[3 * i + 2]))) for i, b in enumerate(base)]
        name = f.model.name.removesuffix(" (identified)") + " (identified)"
        return dataclasses.replace(f.model, name=name, rise=ms[0],
                                   fall=ms[0] if same else ms[1])

    def resid(z: np.ndarray) -> np.ndarray:
        yh = build(z).simulate(d, control_hz)
        den = float(yh @ yh)
        c = float(yh @ y) / den if den > 0 else 1.0
        return np.asarray(y - c * yh)

    z0 = np.zeros(3 * len(base))
    try:
        sol = least_squares(resid, z0, bounds=(np.full(z0.size, -np.log(2.0)),
                                               np.full(z0.size, np.log(2.0))),
                            diff_step=1e-3, max_nfev=40 * z0.size)
    except (ValueError, InputError):
        return f
    cand = fit([build(sol.x)], d, y, control_hz)
    return cand if cand.rms_residual_n < f.rms_residual_n else f


def closed_loop(G: np.ndarray, F: np.ndarray, C: np.ndarray,
                free: np.ndarray | None = None) -> np.ndarray:
    """u -> y with the controller d = M (F u - C y) around plant y = G d:
    (I + G M C)^-1 G M F, M = diag(free) (0 where the limiter clipped the demand)."""
    n = G.shape[0]
    GM = G if free is None else G * np.asarray(free, float)[None, :]
    return np.asarray(np.linalg.solve(np.eye(n) + GM @ C, GM @ F))
