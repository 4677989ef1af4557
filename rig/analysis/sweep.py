"""Parameter sweeps: a design over parameter ranges, one blow per row, metrics, Sobol indices.

    axes = [Axis.parse("contacts.12.D=0.1:0.5"), Axis.parse("springs.jack_torque=0.003:0.005")]
    study = action_study(model, profile, axes, duration=0.1)
    res = run_sweep(study, axes, "sobol", 64, Path("sweep.h5"), executor_for(jobs=2))
    table = sensitivity(Path("sweep.h5"))

The blow is pluggable: a ``Study`` names its metrics (with units) and a function
``fn(shared, x) -> tuple of metric values`` that an executor runs for every design
row, with ``shared`` (the model and the profile) sent once per worker. The same
path runs the Ishigami test function (``ishigami_study``), whose Sobol indices are
known exactly.

The file is written as rows arrive (with its ``done`` flag; flushed every 0.5 s and on exit), so an
interrupted sweep keeps every finished blow and ``resume=True`` runs only the rest.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from rig.analysis.executor import Executor
from rig.errors import InputError

DESIGNS = ("grid", "lhs", "sobol")
FORMAT = "rig-sweep-1"
FLUSH_S = 0.5  # rows reach the disk at least this often (and on any exit)


@dataclass(frozen=True)
class Axis:
    """One swept parameter: a model path (``contacts.12.D``) or ``effect.param``."""

    name: str
    lo: float
    hi: float
    units: str = ""

    @classmethod
    def parse(cls, spec: str) -> Axis:
        name, sep, bounds = spec.partition("=")
        name = name.strip()
        try:
            lo_s, hi_s = bounds.split(":")
            lo, hi = float(lo_s), float(hi_s)
        except ValueError:
            raise InputError(f"param: {spec!r}: expected NAME=LOW:HIGH") from None
        if not name or not sep or not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise InputError(f"param: {spec!r}: expected NAME=LOW:HIGH with finite LOW < HIGH")
        return cls(name, lo, hi)


@dataclass(frozen=True)
class Metric:
    name: str
    units: str
    doc: str


@dataclass
class Study:
    """What one design row computes: ``fn(shared, x)`` -> one value per metric."""

    fn: Callable[[Any, np.ndarray], Sequence[float]]
    metrics: list[Metric]
    shared: Any = None
    identity: dict[str, Any] = field(default_factory=dict)  # what a resume must match


# ---- the action's blow --------------------------------------------------------------------
ACTION_METRICS = [
    Metric("strike_s", "s", "hammer meets the string, from the profile's start"),
    Metric("hammer_speed_m_s", "m/s", "hammer-head speed just before the string"),
    Metric("toe_meets_button_s", "s", "jack toe meets the let-off button"),
    Metric("let_off_s", "s", "let-off: the jack escapes (leaves the knuckle)"),
    Metric("let_off_distance_m", "m", "hammer to string when the jack escapes"),
    Metric("check_s", "s", "back check catches the hammer tail"),
    Metric("string_contact_s", "s", "time the hammer stays on the string"),
    Metric("keytop_force_let_off_N", "N", "force on the key top at let-off"),
    Metric("let_off_dip_m", "m", "key-top travel at let-off"),
    Metric("aftertouch_m", "m", "key-top travel from let-off to the key's front felt"),
    Metric("shank_strain_peak", "m/m", "largest |shank strain| (NaN without flexible_shank)"),
]


# the touch weights of the row's model (rig touch, docs/touch.md), with --touch
TOUCH_METRICS = [
    Metric("down_weight_g", "g", "down-weight at the key front, mid-stroke"),
    Metric("up_weight_g", "g", "up-weight at the key front, mid-stroke"),
    Metric("balance_weight_g", "g", "(down-weight + up-weight) / 2"),
    Metric("friction_g", "g", "(down-weight - up-weight) / 2"),
    Metric("down_weight_stroke_g", "g", "down-weight through the whole touch stroke"),
    Metric("up_weight_stroke_g", "g", "up-weight through the whole touch stroke"),
    Metric("strike_weight_g", "g", "hammer's weight at its strike point"),
    Metric("front_weight_g", "g", "key's own weight at the key front"),
    Metric("inertia_mass_g", "g", "mass felt at the key front when accelerating the key"),
]


def touch_metrics(model: Any) -> tuple[float, ...]:
    """The TOUCH_METRICS of ``model`` (NaN where its statics have no answer)."""
    from rig.model import touch

    try:
        fig = touch.measure(model, worked=False).figures  # (the worked key's: not a metric)
    except (ValueError, RuntimeError, FloatingPointError, np.linalg.LinAlgError):
        return (math.nan,) * len(TOUCH_METRICS)
    return tuple(float(fig[m.name.removesuffix("_g")]) for m in TOUCH_METRICS)


def blow_metrics(result: Any) -> tuple[float, ...]:
    """The ACTION_METRICS of one simulated blow (NaN where the event did not happen)."""
    ev = result.events
    nan = math.nan
    lo = ev.get("let_off", nan)
    kb = ev.get("key_bottom", nan)

    def at(ch: str, t: float) -> float:
        return result.at(ch, t) if math.isfinite(t) else nan

    strain = result.channels.get("shank_strain")
    peak = float(np.max(np.abs(strain))) if strain is not None and strain.size else nan
    return (ev.get("strike", nan), result.strike_speed, ev.get("toe_meets_button", nan), lo,
            float(getattr(result, "let_off_distance", nan)), ev.get("check", nan),
            ev.get("string_release", nan) - ev.get("strike", nan),
            at("force", lo), at("key_dip", lo), at("key_dip", kb) - at("key_dip", lo), peak)


def action_blow(shared: Any, x: np.ndarray) -> tuple[float, ...]:
    """One blow of ``shared = (model, profile, targets, duration)`` at parameter values x."""
    from rig.analysis import fit as ft

    model, profile, targets, duration, *options = shared
    with_touch = bool(options and options[0])
    values = {t.label: float(v) for t, v in zip(targets, x, strict=True)}
    touch = (math.nan,) * len(TOUCH_METRICS) if with_touch else ()
    try:
        m = ft.rebuild(model, (), values, targets)
    except (ValueError, RuntimeError, FloatingPointError, np.linalg.LinAlgError):
        return (math.nan,) * len(ACTION_METRICS) + touch
    if with_touch:
        touch = touch_metrics(m)
    try:
        result = m.simulate(profile, duration)
    except (ValueError, RuntimeError, FloatingPointError, np.linalg.LinAlgError):
        return (math.nan,) * len(ACTION_METRICS) + touch
    if not result.success:
        return (math.nan,) * len(ACTION_METRICS) + touch
    return blow_metrics(result) + touch


def action_study(model: Any, profile: Any, axes: Sequence[Axis], *,
                 duration: float | None = None, identity: dict[str, Any] | None = None,
                 touch: bool = False) -> Study:
    """The action's blow under ``profile`` with the axes' parameters set per row (and, with
    ``touch``, the row model's touch weights, TOUCH_METRICS)."""
    from rig.analysis import fit as ft

    targets = []
    for a in axes:
        t = ft.target(model, f"{a.name}={a.lo!r}:{a.hi!r}")
        # a sweep sets exactly the row's value (a fit target clips into its own bounds)
        t.lo, t.hi = a.lo, a.hi
        targets.append(t)
    model.rest_state()
    effects = repr([(e.name, sorted(e.values.items())) for e in model.effects])
    ident = {"model": hashlib.sha256(model.parameters_yaml.encode()
                                      + effects.encode()).hexdigest(),
             "duration": duration, **(identity or {})}
    if touch:
        ident["touch"] = True
        return Study(action_blow, [*ACTION_METRICS, *TOUCH_METRICS],
                     (model, profile, targets, duration, True), ident)
    return Study(action_blow, list(ACTION_METRICS), (model, profile, targets, duration), ident)


# ---- a test function with known indices ---------------------------------------------------
def ishigami(shared: Any, x: np.ndarray) -> tuple[float]:
    """Ishigami: sin x1 + a sin^2 x2 + b x3^4 sin x1 (shared = (a, b))."""
    a, b = shared if shared is not None else (7.0, 0.1)
    return (math.sin(x[0]) + a * math.sin(x[1]) ** 2 + b * x[2] ** 4 * math.sin(x[0]),)


def ishigami_study(a: float = 7.0, b: float = 0.1) -> Study:
    return Study(ishigami, [Metric("y", "1", "Ishigami function")], (a, b),
                 {"function": "ishigami", "a": a, "b": b})


def ishigami_axes() -> list[Axis]:
    return [Axis(f"x{i}", -math.pi, math.pi) for i in (1, 2, 3)]


# ---- designs ------------------------------------------------------------------------------
def _problem(axes: Sequence[Axis]) -> dict[str, Any]:
    return {"num_vars": len(axes), "names": [a.name for a in axes],
            "bounds": [[a.lo, a.hi] for a in axes]}


def make_design(kind: str, axes: Sequence[Axis], samples: int, seed: int = 0) -> np.ndarray:
    """Rows of parameter values: grid (samples per axis), lhs (samples rows) or sobol
    (Saltelli's scheme, samples * (k + 2) rows; samples a power of 2)."""
    if kind not in DESIGNS:
        raise InputError(f"design: expected one of {', '.join(DESIGNS)}, got {kind!r}")
    if not axes:
        raise InputError("param: expected at least one NAME=LOW:HIGH")
    if samples < 2:
        raise InputError(f"samples: expected at least 2, got {samples}")
    lo = np.array([a.lo for a in axes])
    hi = np.array([a.hi for a in axes])
    if kind == "grid":
        pts = [np.linspace(a.lo, a.hi, samples) for a in axes]
        return np.stack([g.ravel() for g in np.meshgrid(*pts, indexing="ij")], axis=1)
    if kind == "lhs":
        from scipy.stats import qmc

        return lo + qmc.LatinHypercube(d=len(axes), seed=seed).random(samples) * (hi - lo)
    if samples & (samples - 1):
        raise InputError(f"samples: the sobol design needs a power of 2, got {samples}")
    from SALib.sample import sobol as sobol_sample

    return np.asarray(sobol_sample.sample(_problem(axes), samples, calc_second_order=False,
                                          scramble=True, seed=seed))


# ---- the run file -------------------------------------------------------------------------
@dataclass
class SweepResult:
    path: Path
    rows: int
    computed: int          # rows evaluated by this call
    reused: int            # rows found already done (resume)
    wall_s: float


def _identity(study: Study, axes: Sequence[Axis], kind: str, samples: int, seed: int) -> str:
    return json.dumps({"format": FORMAT, "design": kind, "samples": samples, "seed": seed,
                       "params": [[a.name, a.lo, a.hi] for a in axes],
                       "metrics": [m.name for m in study.metrics], **study.identity},
                      sort_keys=True, default=str)


def _create(path: Path, study: Study, axes: Sequence[Axis], kind: str, samples: int,
            seed: int, X: np.ndarray, ident: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with h5py.File(path, "w") as f:
        f.attrs.update(format=FORMAT, design=kind, samples=samples, seed=seed, identity=ident,
                       status="running", params=[a.name for a in axes],
                       metrics=[m.name for m in study.metrics])
        t = f.create_group("table")
        t.attrs["rows"] = X.shape[0]
        d = t.create_dataset("row", data=np.arange(X.shape[0], dtype=np.int64))
        d.attrs.update(units="1", doc="design row index (the task id)")
        for j, a in enumerate(axes):
            d = t.create_dataset(a.name, data=X[:, j])
            d.attrs.update(units=a.units or "model units (see docs/model.md)", kind="param",
                           low=a.lo, high=a.hi)
        for m in study.metrics:
            d = t.create_dataset(m.name, data=np.full(X.shape[0], np.nan))
            d.attrs.update(units=m.units, doc=m.doc, kind="metric")
        d = t.create_dataset("done", data=np.zeros(X.shape[0], dtype=np.uint8))
        d.attrs.update(units="1", doc="1 once the row's metrics are written")


def run_sweep(study: Study, axes: Sequence[Axis], kind: str, samples: int, out: Path,
              executor: Executor, *, seed: int = 0, resume: bool = False, force: bool = False,
              batch: int = 1,
              progress: Callable[[int, int, float], None] | None = None,
              stop: Callable[[], bool] | None = None) -> SweepResult:
    """Evaluate every design row not yet done and write it to ``out`` as it arrives.

    ``batch`` rows go to a worker as one task (fewer round trips when a blow is short
    compared with a task's overhead; see benchmarks/sweep.py). ``stop()`` is asked after
    every result: True ends the sweep there (KeyboardInterrupt, the file marked
    interrupted with every result so far)."""
    out = Path(out)
    if batch < 1:
        raise InputError(f"batch: expected at least 1, got {batch}")
    X = make_design(kind, axes, samples, seed)
    ident = _identity(study, axes, kind, samples, seed)
    if out.exists() and resume:
        try:
            with h5py.File(out, "r") as f:
                old = str(f.attrs.get("identity", ""))
        except OSError:
            raise InputError(f"out: {out} is not a sweep file (cannot --resume it)") from None
        if old != ident:
            raise InputError(f"out: {out} holds a different sweep (design, parameters, model "
                             "or profile differ); use another --out or --force")
    elif out.exists() and not force:
        raise InputError(f"out: {out} exists; use --resume to continue it or --force to "
                         "replace it")
    else:
        _create(out, study, axes, kind, samples, seed, X, ident)
    t0 = time.perf_counter()
    with h5py.File(out, "r+") as f:
        t = f["table"]
        done = t["done"][:].astype(bool)
        todo = np.flatnonzero(~done)
        reused = int(done.sum())
        f.attrs["status"] = "running"
        f.flush()
        n = 0
        flushed = time.perf_counter()
        pending: dict[int, Sequence[float]] = {}

        def write_pending() -> None:
            if not pending:
                return
            rows = np.array(sorted(pending))
            vals = np.array([[float(v) for v in pending[int(i)]] for i in rows])
            for c, m in enumerate(study.metrics):
                t[m.name][rows] = vals[:, c]
            t["done"][rows] = 1
            pending.clear()
            f.flush()

        status = "interrupted"
        try:
            if batch > 1:
                groups = [todo[k:k + batch] for k in range(0, len(todo), batch)]
                results = executor.map(_batch_call, [X[g] for g in groups],
                                       shared=(study.fn, study.shared))
            else:
                groups = [todo[k:k + 1] for k in range(len(todo))]
                results = ((j, [v]) for j, v in executor.map(
                    study.fn, [X[i] for i in todo], shared=study.shared))
            for j, batch_values in results:
                for i, values in zip(groups[j], batch_values, strict=True):
                    if len(values) != len(study.metrics):
                        raise InputError(f"the blow returned {len(values)} values for "
                                         f"{len(study.metrics)} metrics")
                    pending[int(i)] = values
                    n += 1
                if time.perf_counter() - flushed >= FLUSH_S:
                    write_pending()
                    flushed = time.perf_counter()
                if progress is not None:
                    el = time.perf_counter() - t0
                    progress(reused + n, X.shape[0], el / n * (len(todo) - n))
                if stop is not None and stop() and n < len(todo):
                    raise KeyboardInterrupt
            status = "complete"
        finally:
            write_pending()
            f.attrs["status"] = status
            f.attrs["evaluated_last_run"] = n
            f.flush()
    return SweepResult(out, X.shape[0], n, reused, time.perf_counter() - t0)


def _batch_call(shared: Any, xs: np.ndarray) -> list[Sequence[float]]:
    fn, inner = shared
    return [fn(inner, x) for x in xs]


def load_table(path: Path) -> dict[str, np.ndarray]:
    with h5py.File(path, "r") as f:
        return {k: v[:] for k, v in f["table"].items()}


# ---- sensitivity --------------------------------------------------------------------------
@dataclass
class Sensitivity:
    params: list[str]
    metrics: list[str]
    S1: np.ndarray          # (metric, param)
    S1_conf: np.ndarray     # 95 % bootstrap half-width
    ST: np.ndarray
    ST_conf: np.ndarray

    def lines(self) -> list[str]:
        w = max(len(p) for p in self.params)
        out = []
        for i, m in enumerate(self.metrics):
            out.append(f"{m}:  {'S1':>16}  {'ST':>16}")
            for j, p in enumerate(self.params):
                out.append(f"  {p:<{w}}  {self.S1[i, j]:7.3f} +- {self.S1_conf[i, j]:5.3f}"
                           f"  {self.ST[i, j]:7.3f} +- {self.ST_conf[i, j]:5.3f}")
        return out


def sensitivity(path: Path, seed: int = 0) -> Sensitivity:
    """Sobol first- and total-order indices (SALib, Saltelli/Jansen estimators) of every
    metric; the file must hold a complete sobol design. A metric with NaN rows (a blow
    that failed or an event that did not happen) gets NaN indices."""
    from SALib.analyze import sobol as sobol_analyze

    with h5py.File(path, "r") as f:
        if f.attrs.get("design") != "sobol":
            raise InputError(f"{path}: Sobol indices need a sobol design "
                             f"(this one is {f.attrs.get('design')})")
        params = [str(p) for p in f.attrs["params"]]
        metrics = [str(m) for m in f.attrs["metrics"]]
        t = f["table"]
        if not t["done"][:].all():
            raise InputError(f"{path}: the sweep is not complete; run it again with --resume")
        bounds = [[float(t[p].attrs["low"]), float(t[p].attrs["high"])] for p in params]
        Y = {m: t[m][:] for m in metrics}
    problem = {"num_vars": len(params), "names": params, "bounds": bounds}
    k = len(params)
    shape = (len(metrics), k)
    S1, S1c, ST, STc = (np.full(shape, np.nan) for _ in range(4))
    for i, m in enumerate(metrics):
        y = Y[m]
        if not np.all(np.isfinite(y)):
            continue
        if np.ptp(y) == 0:  # no parameter moves this metric at all
            S1[i] = S1c[i] = ST[i] = STc[i] = 0.0
            continue
        r = sobol_analyze.analyze(problem, y, calc_second_order=False, seed=seed)
        S1[i], S1c[i], ST[i], STc[i] = r["S1"], r["S1_conf"], r["ST"], r["ST_conf"]
    return Sensitivity(params, metrics, S1, S1c, ST, STc)


def write_sensitivity(path: Path, s: Sensitivity) -> None:
    """Store the indices in the sweep file's /sensitivity group."""
    with h5py.File(path, "r+") as f:
        if "sensitivity" in f:
            del f["sensitivity"]
        g = f.create_group("sensitivity")
        g.attrs.update(params=s.params, metrics=s.metrics,
                       doc="Sobol indices, rows: metrics, columns: params; *_conf: 95 % "
                           "bootstrap half-widths")
        for name, a in (("S1", s.S1), ("S1_conf", s.S1_conf), ("ST", s.ST),
                        ("ST_conf", s.ST_conf)):
            g.create_dataset(name, data=a).attrs["units"] = "1"


def write_report(path: Path, s: Sensitivity, title: str) -> None:
    """An HTML page: the index table and a bar chart per metric (matplotlib PNG, inline)."""
    import base64
    import html
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = []
    for i, m in enumerate(s.metrics):
        for j, p in enumerate(s.params):
            rows.append(f"<tr><td>{html.escape(m)}</td><td>{html.escape(p)}</td>"
                        f"<td>{s.S1[i, j]:.3f} &plusmn; {s.S1_conf[i, j]:.3f}</td>"
                        f"<td>{s.ST[i, j]:.3f} &plusmn; {s.ST_conf[i, j]:.3f}</td></tr>")
    n = len(s.metrics)
    fig, axs = plt.subplots(n, 1, figsize=(7, 1.2 + 1.6 * n), squeeze=False)
    xs = np.arange(len(s.params))
    for i, m in enumerate(s.metrics):
        ax = axs[i, 0]
        ax.bar(xs - 0.2, s.S1[i], 0.4, yerr=s.S1_conf[i], label="S1")
        ax.bar(xs + 0.2, s.ST[i], 0.4, yerr=s.ST_conf[i], label="ST")
        ax.set_title(m, fontsize=9)
        ax.set_xticks(xs, s.params, fontsize=8)
        ax.set_ylim(-0.05, 1.05)
    axs[0, 0].legend(fontsize=8)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80)
    plt.close(fig)
    png = base64.b64encode(buf.getvalue()).decode()
    Path(path).write_text(
        f"<!doctype html><meta charset='utf-8'><title>{html.escape(title)}</title>"
        f"<h1>{html.escape(title)}</h1><p>Sobol first-order (S1) and total-order (ST) "
        f"indices, 95 % bootstrap half-widths.</p><table border='1'><tr><th>metric</th>"
        f"<th>parameter</th><th>S1</th><th>ST</th></tr>{''.join(rows)}</table>"
        f"<img alt='Sobol indices' src='data:image/png;base64,{png}'>\n")
