"""Where a model fails against measurements, and which library effect is missing.

(1) The base model is compared with the trial and each channel's residual in
each phase gets a signature (rig.analysis.signature). (2) Every effect of the
library not already in the model is a candidate: it is added with its default
values, its parameters marked ``fitted`` are fitted within their bounds on the
training samples (a coarse one-at-a-time scan across the bounds, then scipy
least squares), and the fitted model is scored on the held-out samples (other
trials when there are several, else alternate 2 ms blocks of the one trial).
Before scoring, each trial's prediction may shift as a whole by up to
``align_s`` (0.5 ms): the input's noise moves a blow by a few tenths of a ms
from trial to trial, and no effect should get credit for that. Candidates are
ranked by the share of the held-out error they remove (mean over channels of
the mean square residual over the channel's range squared). An improvement is
significant when it removes at least ``min_gain`` of that error and, on some
channel, a mean square of at least ``min_noise_gain`` times the channel's
noise variance (the removed part stands clear of the noise). A candidate that
switches on another candidate (``Effect.implies``) ranks after it unless it
removes ``min_gain`` of the error that one leaves. Candidates are fitted in
parallel, one process per core.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from rig.analysis import compare as cp
from rig.analysis import fit as ft
from rig.analysis import signature as sg
from rig.analysis.measurement import Measurement
from rig.model.action import ActionModel
from rig.model.effects import BUILTIN, Effect


@dataclass
class Candidate:
    """One library effect added to the model, fitted and scored on held-out data."""

    name: str
    summary: str
    values: dict[str, float]
    sigma: dict[str, float]
    units: dict[str, str]
    removal: float                      # share of the held-out error removed (all channels)
    channel_removal: dict[str, float]   # per channel
    noise_gain: float                   # largest held-out mean square removed / noise variance
    significant: bool
    test_error: dict[str, float] = field(default_factory=dict)  # held-out MS / range^2
    nfev: int = 0
    error: str = ""                     # why the candidate could not be evaluated
    note: str = ""                      # how it ranks against an effect it implies

    def describe(self) -> str:
        if self.error:
            return f"{self.name}: not evaluated ({self.error})"
        vals = ", ".join(
            f"{k} = {v:.4g} +- {self.sigma.get(k, math.nan):.2g} {self.units.get(k, '')}".rstrip()
            for k, v in self.values.items()) or "no fitted parameter"
        sig = "significant" if self.significant else "not significant"
        return (f"{self.name}: removes {self.removal * 100:.1f} % of the held-out error "
                f"({sig}; {self.noise_gain:.1f} x noise variance); {vals}"
                + (f"; {self.note}" if self.note else ""))


def rank(candidates: list[Candidate], implies: Mapping[str, Sequence[str]],
         min_gain: float) -> list[Candidate]:
    """Candidates by held-out error removed, significant ones first; a candidate that
    switches on another candidate (``implies``) goes after it unless it removes at least
    ``min_gain`` of the error that one leaves (the simpler explanation wins a tie)."""
    out = sorted(candidates, key=lambda c: (not c.significant, -c.removal))
    by_name = {c.name: c for c in out if not c.error}
    for a in list(out):
        for b_name in implies.get(a.name, ()):
            b = by_name.get(b_name)
            if b is None or a.error:
                continue
            left = 1.0 - b.removal
            extra = (a.removal - b.removal) / left if left > 0 else 0.0
            a.note = (f"includes {b_name}; removes {extra * 100:.1f} % of the error "
                      f"{b_name} leaves")
            ia, ib = out.index(a), out.index(b)
            if extra < min_gain and ia < ib:
                out.insert(ib, out.pop(ia))
    return out


@dataclass
class Diagnosis:
    comparison: cp.Comparison
    signatures: list[sg.Signature]
    base_error: dict[str, float]        # held-out mean square / range^2 per channel
    candidates: list[Candidate]
    split: str
    min_gain: float
    min_noise_gain: float
    wall_s: float = 0.0
    notes: list[str] = field(default_factory=list)

    def removal_on(self, candidate: Candidate, channels: Sequence[str]) -> float:
        """Share of the held-out error the candidate removes on these channels together."""
        names = [c for c in channels if c in self.base_error and c in candidate.test_error]
        if not names:
            raise ValueError(f"channels: none of {list(channels)} was compared "
                             f"(compared: {sorted(self.base_error)})")
        base = sum(self.base_error[c] for c in names)
        return 1 - sum(candidate.test_error[c] for c in names) / base if base > 0 else 0.0

    @property
    def best(self) -> Candidate | None:
        """The top-ranked candidate if its improvement is significant."""
        return self.candidates[0] if self.candidates and self.candidates[0].significant else None

    def verdict(self) -> str:
        best = self.best
        if best is not None:
            return f"missing effect: {best.describe()}"
        sig = "; ".join(s.text() for s in self.signatures[:3])
        return ("no library effect explains the residual: no candidate removes a significant "
                f"share of the held-out error. Residual signature: {sig}")

    def report_lines(self) -> list[str]:
        comp = self.comparison
        mc = comp.models[0]
        lines = [f"{comp.measurement.label}: model {mc.label}, input {comp.input}; held-out: "
                 f"{self.split}", "where it fails (normalized RMS residual):"]
        for ch, v in sg.worst_channels(comp, mc):
            lines.append(f"  {ch:<18} {v * 100:6.2f} %")
        lines.append("largest residuals by channel and phase:")
        for s in self.signatures[:6]:
            lines.append("  " + s.text())
        lines.append("candidates (ranked by held-out error removed):")
        for i, c in enumerate(self.candidates, 1):
            lines.append(f"  {i}. {c.describe()}")
        lines.append(self.verdict())
        return lines + self.notes


_CTX: dict[str, Any] = {}


def candidates_for(base: ActionModel, names: Sequence[str] | None = None,
                   extra: Sequence[type[Effect]] = ()) -> list[type[Effect]]:
    """Library effects not in the model (or the named ones), plus extra classes."""
    have = set(base.effect_names)
    if names is None:
        pool = [cls for n, cls in BUILTIN.items() if n not in have and cls.diagnosable]
    else:
        pool = []
        for n in names:
            if n not in BUILTIN:
                raise ValueError(f"candidates: {n!r} is not in the effect library "
                                 f"({sorted(BUILTIN)})")
            if n in have:
                raise ValueError(f"candidates: {n!r} is already in the model")
            pool.append(BUILTIN[n])
    pool += [c for c in extra if c.name not in have and c not in pool]
    return pool


def evaluate_candidate(cls: type[Effect], base: ActionModel, train: ft.Data, test: ft.Data,
                       base_test: Mapping[str, tuple[float, float]], max_nfev: int,
                       min_gain: float, min_noise_gain: float, scan: int = 4) -> Candidate:
    """Add ``cls`` to the model, fit its fitted parameters on ``train``, score on ``test``."""
    specs = [f"{cls.name}.{p.name}" for p in cls.parameters if p.fitted]
    units = {p.name: p.units for p in cls.parameters}
    try:
        if specs:
            res = ft.fit(base, train, specs, [cls], jobs=1, max_nfev=max_nfev, scan=scan)
            values = {t.key: res.values[t.label] for t in res.targets}
            sigma = {t.key: res.sigma[t.label] for t in res.targets}
            targets, tvals, nfev = res.targets, res.values, res.nfev
        else:
            values, sigma, targets, tvals, nfev = {}, {}, [], {}, 0
        model = ft.rebuild(base, [cls], tvals, targets, test.measurements[0].rate)
        cand = test.channel_ms(test.simulate(model))
    except (ValueError, RuntimeError, FloatingPointError, np.linalg.LinAlgError) as exc:
        return Candidate(cls.name, cls.summary, {}, {}, units, -math.inf, {}, 0.0, False,
                         error=f"{type(exc).__name__}: {exc}")
    e_base = float(np.mean([v[0] for v in base_test.values()]))
    e_cand = float(np.mean([cand[c][0] for c in base_test]))
    removal = 1 - e_cand / e_base if e_base > 0 else 0.0
    ch_rem = {c: (1 - cand[c][0] / base_test[c][0]) if base_test[c][0] > 0 else 0.0
              for c in base_test}
    gain = max(base_test[c][1] - cand[c][1] for c in base_test)
    return Candidate(cls.name, cls.summary, values, sigma, units, removal, ch_rem, gain,
                     removal >= min_gain and gain >= min_noise_gain,
                     {c: cand[c][0] for c in base_test}, nfev)


def _worker(i: int) -> Candidate:
    c = _CTX["diagnose"]
    return evaluate_candidate(c["classes"][i], c["base"], c["train"], c["test"],
                              c["base_test"], c["max_nfev"], c["min_gain"],
                              c["min_noise_gain"], c["scan"])


def diagnose(base: ActionModel, measurements: Sequence[Measurement], *, input: str = "force",
             duration: float | None = None, channels: Sequence[str] | None = None,
             candidates: Sequence[str] | None = None, extra: Sequence[type[Effect]] = (),
             jobs: int | None = None, max_nfev: int = 10, scan: int = 4, min_gain: float = 0.2,
             min_noise_gain: float = 3.0, label: str = "model", align_s: float = 5e-4,
             progress: Callable[[float, float, str], None] | None = None) -> Diagnosis:
    """Signatures of the base model's residual and the ranked candidate effects."""
    import time as _time

    if not measurements:
        raise ValueError("measurements: expected at least one trial")
    wall0 = _time.perf_counter()
    data = ft.Data.build(measurements, input, duration, channels, align_s=align_s)
    train_m, test_m = ft.split_masks(data)
    train, test = data.subset(train_m), data.subset(test_m)
    split = (f"{len(measurements)} trials: fit on even, score on odd" if len(measurements) > 1
             else "one trial: fit on even 2 ms blocks, score on odd ones")
    base = ft.rebuild(base, rate=measurements[0].rate)
    comp = cp.compare(measurements[0], [(label, base)], input, duration, channels)
    sigs = sg.signatures(comp, comp.models[0], align_s)
    base_test = test.channel_ms(test.simulate(base))
    classes = candidates_for(base, candidates, extra)
    total = len(classes)
    if progress:
        progress(0, total, "fitting candidates")
    out: list[Candidate] = []
    pool = ft.make_pool(min(jobs, total) if jobs is not None else min(total, 64)) \
        if total > 1 else None
    _CTX["diagnose"] = {"classes": classes, "base": base, "train": train, "test": test,
                        "base_test": base_test, "max_nfev": max_nfev, "scan": scan,
                        "min_gain": min_gain,
                        "min_noise_gain": min_noise_gain}
    try:
        if pool is None:
            for i, cls in enumerate(classes):
                out.append(_worker(i))
                if progress:
                    progress(i + 1, total, cls.name)
        else:
            futs = {pool.submit(_worker, i): cls.name for i, cls in enumerate(classes)}
            for n, f in enumerate(as_completed(futs), 1):
                out.append(f.result())
                if progress:
                    progress(n, total, futs[f])
    finally:
        _CTX.pop("diagnose", None)
        if pool is not None:
            pool.shutdown()
    out = rank(out, {cls.name: cls.implies for cls in classes}, min_gain)
    tau = sg.common_shift(comp, comp.models[0], align_s)
    notes = [f"(signatures taken after shifting the model by {tau * 1e3:+.2f} ms as a whole; "
             f"at most +-{align_s * 1e3:.1f} ms)"]
    if not comp.models[0].ok:
        notes.append(f"the base model's simulation failed: {comp.models[0].result.message}")
    return Diagnosis(comp, sigs, {c: v[0] for c, v in base_test.items()}, out, split,
                     min_gain, min_noise_gain, _time.perf_counter() - wall0, notes)


def write_model(base_yaml: Path | None, candidate: Candidate, out: Path) -> Path:
    """The base model YAML with the candidate effect and its fitted values appended."""
    data: dict[str, Any] = {}
    base_dir = Path.cwd()
    if base_yaml is not None:
        loaded = yaml.safe_load(Path(base_yaml).read_text()) or {}
        if not isinstance(loaded, dict):
            raise ValueError(f"{base_yaml}: expected a model mapping")
        data = loaded
        base_dir = Path(base_yaml).resolve().parent
    out = Path(out)
    out_dir = out.resolve().parent
    if isinstance(data.get("parameters"), str):
        data["parameters"] = _rel(base_dir / data["parameters"], out_dir)
    effects = []
    for e in data.get("effects") or []:
        effects.append(_rebase_effect(e, base_dir, out_dir))
    effects.append({candidate.name: {k: float(v) for k, v in candidate.values.items()}}
                   if candidate.values else candidate.name)
    data["effects"] = effects
    desc = str(data.get("description", "")).strip()
    data["description"] = (desc + "\n" if desc else "") + (
        f"rig diagnose added {candidate.name} (held-out error removed "
        f"{candidate.removal * 100:.1f} %)")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(yaml.safe_dump(data, sort_keys=False))
    return out


def _rel(path: Path, start: Path) -> str:
    import os

    return os.path.relpath(path.resolve(), start)


def _rebase_effect(spec: Any, base_dir: Path, out_dir: Path) -> Any:
    name = next(iter(spec)) if isinstance(spec, dict) else spec
    if not isinstance(name, str) or ".py:" not in name:
        return spec
    file, _, cls = name.rpartition(":")
    new = f"{_rel(base_dir / file, out_dir)}:{cls}"
    return {new: spec[name]} if isinstance(spec, dict) else new
