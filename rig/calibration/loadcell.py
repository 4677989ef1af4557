"""Load-cell calibration with known masses: fit, spec figures, uncertainty budget (k = 2).

The operator hangs known masses on the key top, loading up to the largest and
then unloading (more cycles allowed; a rise after unloading starts a new
cycle). At each point the bridge is averaged for ``average_s`` after
``settle_s``. The reference force is m g. Fitted: F = c0 + c1 x (x in mV/V;
c1 in N per mV/V) or a polynomial in x on request. Stored for the runtime,
in the sensor table's conventions (rig.sensors.table): sensitivity = 1e-3 / c1
(V/V)/N and offset = -c0 / c1 * 1e-3 V/V (from the straight line, also for a polynomial fit).

Spec figures (% of full scale, against the best straight line): hysteresis
= largest unloading-minus-loading difference at one mass; non-linearity =
largest deviation of the mean (loading, unloading) reading from the line;
non-repeatability = largest spread between cycles at one mass and direction
(needs two cycles). Uncertainty budget (standard uncertainties, then k = 2):
the fit's statistics (residual scatter, covariance of c0, c1), reference
masses and local g (rectangular half-widths from the settings), and, for a
force read through the line, half the hysteresis and the non-linearity
(rectangular). The scale's relative uncertainty is the fit's combined with
masses and g; the zero offset's is the fit's (a scale error does not move it).
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rig.calibration.settings import LoadCellCal
from rig.daq import Bench, bridge_range
from rig.errors import InputError
from rig.inputs.config import RigConfig


@dataclass(frozen=True)
class LoadPoint:
    """One calibration point: mass (kg), direction, averaged bridge reading (V/V)."""

    index: int
    mass_kg: float
    direction: str          # "load" or "unload"
    cycle: int
    ratio_v_per_v: float
    std_v_per_v: float      # of the samples averaged (nan for a CSV reading)
    samples: int
    peak_abs_v_per_v: float


def parse_mass(text: str | float, where: str = "mass") -> float:
    """A mass in kg from user input; ValueError naming the field for text or a negative."""
    try:
        m = float(text)
    except (TypeError, ValueError):
        raise InputError(f"{where}: expected a number in kg, got {text!r}") from None
    if not math.isfinite(m) or m < 0:
        raise InputError(f"{where}: expected a mass >= 0 kg, got {text!r}")
    return m


def directions(masses: Sequence[float]) -> list[tuple[str, int]]:
    """(direction, cycle) of each point: loading while masses rise, unloading while they fall."""
    out: list[tuple[str, int]] = []
    d, cycle = "load", 0
    for i, m in enumerate(masses):
        if i:
            prev = masses[i - 1]
            if m == prev:
                raise InputError(f"points[{i + 1}] mass: {m:g} kg repeats point {i}; change the "
                                 f"mass between points")
            if d == "load" and m < prev:
                d = "unload"
            elif d == "unload" and m > prev:
                d, cycle = "load", cycle + 1
        out.append((d, cycle))
    return out


def read_csv(path: Path) -> list[tuple[float, float | None]]:
    """CSV of points: column ``mass_kg`` and optionally ``reading_mv_per_v`` (else the bench
    reads each point); returns (mass kg, reading V/V or None) in file order."""
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise InputError(f"{p}: cannot read the points file ({exc.strerror})") from None
    rows = list(csv.DictReader(line for line in text.splitlines()
                               if line.strip() and not line.lstrip().startswith("#")))
    if not rows or "mass_kg" not in rows[0]:
        raise InputError(f"{p}: expected a header with mass_kg (and optionally "
                         f"reading_mv_per_v)")
    out: list[tuple[float, float | None]] = []
    for i, row in enumerate(rows, start=1):
        m = parse_mass((row.get("mass_kg") or "").strip(), f"{p.name}: row {i} mass_kg")
        r = (row.get("reading_mv_per_v") or "").strip()
        if r:
            try:
                reading: float | None = float(r) * 1e-3
            except ValueError:
                raise InputError(f"{p.name}: row {i} reading_mv_per_v: expected a number in "
                                 f"mV/V, got {r!r}") from None
        else:
            reading = None
        out.append((m, reading))
    return out


def measure(bench: Bench, mass_kg: float, s: LoadCellCal,
            live: Callable[[float], None] | None = None) -> tuple[float, float, int, float]:
    """Average the bridge with ``mass_kg`` on: (mean V/V, std V/V, samples, largest |V/V|)."""
    bench.apply_mass(mass_kg, s.gravity_m_s2)
    n_settle = int(round(s.settle_s * bench.rate_hz))
    r = bench.read_bridge("load_cell", s.settle_s + s.average_s, live)
    avg = r[n_settle:] if r.size > n_settle + 1 else r
    return float(avg.mean()), float(avg.std(ddof=1)), int(avg.size), float(np.abs(r).max())


def make_points(masses: Sequence[float], readings: Sequence[tuple[float, float, int, float]]
                ) -> list[LoadPoint]:
    dirs = directions(masses)
    return [LoadPoint(i + 1, float(m), d, c, *rd)
            for i, (m, (d, c), rd) in enumerate(zip(masses, dirs, readings, strict=True))]


def validate(points: Sequence[LoadPoint], cfg: RigConfig, s: LoadCellCal) -> None:
    """Refuse bad data with one line: too few points, no unloading, saturation,
    non-monotonic readings, too small a span."""
    fs = cfg.channels.load_cell.full_scale_n
    distinct = sorted({p.mass_kg for p in points})
    if len(distinct) < s.min_points:
        raise InputError(f"points: too few: {len(distinct)} distinct masses, at least "
                         f"{s.min_points} needed (loading then unloading across the range)")
    if not any(p.direction == "unload" for p in points):
        raise InputError("points: no unloading points: after the largest mass, take the "
                         "masses off again one by one (hysteresis needs them)")
    rng = bridge_range(cfg, "load_cell")
    for p in points:
        if p.peak_abs_v_per_v >= s.saturation_fraction * rng:
            raise InputError(f"points[{p.index}] ({p.mass_kg:g} kg): the bridge is saturated "
                             f"({p.peak_abs_v_per_v * 1e3:.3f} mV/V against the channel's "
                             f"+-{rng * 1e3:g} mV/V range): use smaller masses or a wider "
                             f"input_range_mv_per_v")
    for a, b in zip(points, points[1:], strict=False):
        if a.direction != b.direction or a.cycle != b.cycle:
            continue
        rising = b.mass_kg > a.mass_kg
        if (b.ratio_v_per_v > a.ratio_v_per_v) != rising:
            raise InputError(
                f"points[{b.index}] ({b.mass_kg:g} kg, {b.direction}): non-monotonic reading: "
                f"{b.ratio_v_per_v * 1e3:.5f} mV/V is not {'above' if rising else 'below'} "
                f"point {a.index}'s {a.ratio_v_per_v * 1e3:.5f} mV/V at {a.mass_kg:g} kg "
                f"(wrong mass entered, a mass touching something, or a loose cell?)")
    span = (distinct[-1] - distinct[0]) * s.gravity_m_s2
    if span < s.min_span_fraction * fs:
        raise InputError(f"points: the masses span {span:.1f} N, less than "
                         f"{s.min_span_fraction * 100:g} % of the {fs:g} N full scale")


def _lstsq(x: np.ndarray, f: np.ndarray, degree: int) -> tuple[np.ndarray, np.ndarray, float]:
    """Coefficients (c0, c1, ...), their covariance, residual std (N)."""
    a = np.vander(x, degree + 1, increasing=True)
    coef, *_ = np.linalg.lstsq(a, f, rcond=None)
    res = f - a @ coef
    dof = max(1, x.size - (degree + 1))
    s2 = float(res @ res) / dof
    cov = s2 * np.linalg.inv(a.T @ a)
    return coef, cov, math.sqrt(s2)


@dataclass
class LoadCellResult:
    points: list[LoadPoint]
    degree: int
    fit: dict[str, Any]
    figures: dict[str, Any]
    uncertainty: dict[str, Any]
    checks: dict[str, Any]

    def raw_points(self) -> list[dict[str, Any]]:
        return [asdict(p) for p in self.points]


def analyse(points: Sequence[LoadPoint], cfg: RigConfig, s: LoadCellCal,
            degree: int = 1) -> LoadCellResult:
    """Validate, fit and assess the points (nothing is written here)."""
    if degree < 1 or degree > 3:
        raise InputError(f"degree: expected 1 (linear, the default) to 3, got {degree}")
    validate(points, cfg, s)
    fs = cfg.channels.load_cell.full_scale_n
    g = s.gravity_m_s2
    x = np.array([p.ratio_v_per_v for p in points]) * 1e3          # mV/V
    f = np.array([p.mass_kg for p in points]) * g                   # N
    if x.size < degree + 2:
        raise InputError(f"points: too few for a degree-{degree} fit: {x.size}")
    coef, cov, s_res = _lstsq(x, f, 1)
    c0, c1 = float(coef[0]), float(coef[1])
    if not c1 > 0:
        raise InputError(f"points: the fitted scale is {c1:.4g} N per mV/V: the bridge reads "
                         f"less under more mass (wired backwards?)")
    chosen, chosen_cov, chosen_s = (coef, cov, s_res) if degree == 1 else _lstsq(x, f, degree)
    residuals = f - np.vander(x, degree + 1, increasing=True) @ chosen

    # spec figures against the straight line
    by_mass: dict[float, dict[str, list[float]]] = {}
    for p in points:
        by_mass.setdefault(p.mass_kg, {}).setdefault(p.direction, []).append(p.ratio_v_per_v)
    hyst = nonlin = 0.0
    spread = None
    for m, d in by_mass.items():
        means = {k: float(np.mean(v)) for k, v in d.items()}
        if "load" in means and "unload" in means:
            hyst = max(hyst, abs(means["unload"] - means["load"]) * 1e3 * c1)
        xm = float(np.mean(list(means.values()))) * 1e3
        nonlin = max(nonlin, abs(c0 + c1 * xm - m * g))
        for v in d.values():
            if len(v) > 1:
                spread = max(spread or 0.0, (max(v) - min(v)) * 1e3 * c1)
    noise_n = float(np.nanmean([p.std_v_per_v for p in points])) * 1e3 * c1 \
        if any(math.isfinite(p.std_v_per_v) for p in points) else math.nan
    pct = 100.0 / fs
    figures: dict[str, Any] = {
        "full_scale_n": fs,
        "sensitivity_mv_per_v_per_n": 1.0 / c1,
        "scale_n_per_mv_per_v": c1,
        "zero_offset_mv_per_v": -c0 / c1,
        "rated_output_at_full_scale_mv_per_v": fs / c1,
        "hysteresis_pct_fs": hyst * pct,
        "nonlinearity_pct_fs": nonlin * pct,
        "nonrepeatability_pct_fs": None if spread is None else spread * pct,
        "residual_std_n": s_res,
        "max_abs_residual_n": float(np.max(np.abs(residuals))),
        "sample_noise_n_1sigma": noise_n,
    }

    # uncertainty budget (standard uncertainties), k = 2
    u_b_rel = math.hypot(s.mass_rel_halfwidth, s.gravity_rel_halfwidth) / math.sqrt(3)
    u_c1_stat = math.sqrt(cov[1, 1])
    u_scale_rel = math.hypot(u_c1_stat / c1, u_b_rel)
    jac = np.array([-1.0 / c1, c0 / c1 ** 2])
    u_r0 = math.sqrt(float(jac @ cov @ jac)) * 1e-3                 # V/V

    def u_force(force: float) -> dict[str, float]:
        xf = (force - c0) / c1
        v = np.array([1.0, xf])
        parts = {"fit_statistics_n": math.sqrt(float(v @ cov @ v)),
                 "masses_and_gravity_n": abs(force) * u_b_rel,
                 "hysteresis_n": hyst / 2 / math.sqrt(3),
                 "nonlinearity_n": nonlin / math.sqrt(3)}
        u = math.sqrt(sum(p * p for p in parts.values()))
        return {**parts, "combined_n": u, "expanded_n": 2 * u}

    f_max = float(f.max())
    at_fs, at_max = u_force(fs), u_force(f_max)
    single = 2 * math.hypot(at_fs["combined_n"], noise_n if math.isfinite(noise_n) else 0.0)
    sens = 1e-3 / c1
    uncertainty = {
        "coverage_factor": 2,
        "sensitivity_v_per_v_per_n": 2 * u_scale_rel * sens,
        "sensitivity_relative": 2 * u_scale_rel,
        "offset_v_per_v": 2 * u_r0,
        "budget_relative_standard": {"fit_statistics": u_c1_stat / c1,
                                     "reference_masses": s.mass_rel_halfwidth / math.sqrt(3),
                                     "local_gravity": s.gravity_rel_halfwidth / math.sqrt(3)},
        "force_at_full_scale": at_fs,
        "force_at_largest_point": {**at_max, "force_n": f_max},
        "single_sample_expanded_n": single,
        "spec_error_bound_n": 0.006 * fs,
    }
    spec_nl = s.spec_nonlinearity_hysteresis_pct_fs
    checks = {
        "hysteresis_within_spec": figures["hysteresis_pct_fs"] <= spec_nl,
        "nonlinearity_within_spec": figures["nonlinearity_pct_fs"] <= spec_nl,
        "nonrepeatability_within_spec": None if spread is None else
        figures["nonrepeatability_pct_fs"] <= s.spec_nonrepeatability_pct_fs,
        "expanded_uncertainty_within_spec_bound": at_fs["expanded_n"] <= 0.006 * fs,
        "spec_pct_fs": {"nonlinearity_hysteresis": spec_nl,
                        "nonrepeatability": s.spec_nonrepeatability_pct_fs},
    }
    fit = {"model": "linear" if degree == 1 else f"polynomial degree {degree}",
           "sensitivity": sens, "offset": -c0 / c1 * 1e-3,
           "scale_n_per_mv_per_v": c1, "intercept_n": c0,
           "coefficients_n_per_mv_per_v_power": [float(c) for c in chosen],
           "coefficient_covariance": chosen_cov.tolist(),
           "residual_std_n": chosen_s,
           "residuals_n": residuals.tolist(),
           "gravity_m_s2": g}
    return LoadCellResult(list(points), degree, fit, figures, uncertainty, checks)


UNITS = {"raw": "V/V", "calibrated": "N", "sensitivity": "(V/V)/N", "offset": "V/V",
         "mass": "kg", "force": "N", "ratio": "V/V", "percent": "% of full scale"}
