"""What a model leaves on held-out trials, against the noise floor a right model leaves.

A right model's held-out residual is not zero: it holds the sensors' noise and the
model's response to the noise of the measured force that drives it (the model integrates
that noise into the motion: where the back check holds the hammer, the load cell's 0.2 N
of noise moves the catch by as much as a small missing effect). ``remainder`` draws that
floor (``stats.noise_floor_draws``: white output noise of each channel's level plus the
model's own linear response to the input's noise, ``fit.input_noise_responses`` with
antithetic draws) and tests the residual's mean square against it (``stats.floor_test``,
a scaled chi-square). Diagnose uses it twice: with no effect chosen, to tell "no library
effect explains the residual" (it stands above the floor) from "no missing effect can be
shown" (it does not); with a set chosen, to say whether what the set leaves is noise or
physics no candidate explains -- and where, by channel and phase, in units of the floor.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rig.analysis import compare as cp
from rig.analysis import fit as ft
from rig.analysis import signature as sg
from rig.analysis import stats
from rig.analysis.measurement import Measurement
from rig.model.action import ActionModel
from rig.model.effects import Signature

FLOOR_PAIRS = 24  # antithetic draws of the input's noise (two simulations each)
MIN_PLACE_RATIO = 2.0  # a channel's phase is tested alone where its RMS is this many floors
MIN_BLOCK = 8  # samples (4 ms at 2 kHz): shorter phases are not tested on their own


@dataclass
class Place:
    """One channel in one phase of a held-out trial: the residual's signature, its RMS over
    the noise floor's RMS there, and the chance that noise alone reaches its mean square."""

    signature: sg.ResidualSignature
    floor_ratio: float
    p: float
    trial: int = 0
    label: str = ""   # the trial's name when several trials are held out
    acts: str = ""    # a chosen effect whose signature covers this channel and phase

    def text(self) -> str:
        s = self.signature
        kind = (f"oscillation at {s.frequency_hz:.0f} Hz" if s.kind == "oscillation"
                and math.isfinite(s.frequency_hz) else
                f"lag ({s.lag_s * 1e3:+.2f} ms)" if s.kind == "lag" and math.isfinite(s.lag_s)
                else s.kind)
        if s.kind != "oscillation" and math.isfinite(s.frequency_hz):
            kind += f" (oscillation {s.osc_share:.0%} at {s.frequency_hz:.0f} Hz)"
        where = f" of {self.label}" if self.label else ""
        return (f"{s.channel} in {s.phase}{where}: {kind}, {s.nrms * 100:.2f} % of range "
                f"({self.floor_ratio:.1f} x the noise floor)")


@dataclass
class Remainder:
    """A model's held-out residual against its noise floor (``remainder``)."""

    of: str                      # "base model" or the chosen set's names joined by " + "
    ratio: float                 # mean square over the floor's mean square, all held out
    p: float                     # the chance that noise alone reaches it anywhere (Bonferroni)
    alpha: float
    channels: dict[str, float]   # per channel: RMS over the floor's RMS
    places: list[Place] = field(default_factory=list)  # significant, largest ratio first
    tests: int = 1               # the whole and each channel's phases: Bonferroni's count

    @property
    def significant(self) -> bool:
        return self.p <= self.alpha

    def head(self) -> str:
        """'mean square 3.7 times the noise floor's, p = 2e-05'."""
        return f"mean square {self.ratio:.2g} times the noise floor's, p = {self.p:.2g}"

    def acting(self, n: int = 3) -> list[Place]:
        """Of the first ``n`` places, those where a chosen effect acts."""
        return [p for p in self.places[:n] if p.acts]

    def where(self, n: int = 3) -> str:
        """The places that stand above the floor, or the channels when none does alone."""
        if self.places:
            return "; ".join(p.text() for p in self.places[:n])
        top = sorted(self.channels.items(), key=lambda kv: -kv[1])[:n]
        return ", ".join(f"{c} {r:.1f} x the noise floor" for c, r in top)

    def as_dict(self) -> dict[str, Any]:
        return {"of": self.of, "ratio": _num(self.ratio), "p_value": _num(self.p),
                "alpha": self.alpha, "significant": self.significant, "tests": self.tests,
                "channels": {c: _num(r) for c, r in self.channels.items()},
                "places": [{"trial": p.trial, "acts": p.acts, "channel": p.signature.channel,
                            "phase": p.signature.phase, "kind": p.signature.kind,
                            "nrms": _num(p.signature.nrms),
                            "frequency_hz": _num(p.signature.frequency_hz),
                            "floor_ratio": _num(p.floor_ratio), "p_value": _num(p.p)}
                           for p in self.places]}


def _num(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def floor_draws(model: ActionModel, test: ft.Data, r: np.ndarray) -> np.ndarray:
    """Draws of what ``model``'s held-out residual ``r`` on ``test`` holds when the model is
    right: the output noise and the input force's noise through the model
    (``stats.noise_floor_draws`` with ``FLOOR_PAIRS`` antithetic responses)."""
    return stats.noise_floor_draws(test.noise_vector(), ft.input_noise_responses(
        model, test, r0=r, draws=FLOOR_PAIRS, antithetic=True))


def remainder(model: ActionModel, test: ft.Data, measurements: Sequence[Measurement], *,
              of: str, alpha: float = 0.05, align_s: float = 0.0,
              channels: Sequence[str] | None = None,
              acts: Mapping[str, Signature] | None = None,
              draws: np.ndarray | None = None) -> Remainder | None:
    """Test ``model``'s residual on the held-out data ``test`` against its noise floor
    (``measurements``: the trials ``test`` was built from), over the whole and over each
    channel in each phase of each held-out trial (a missing effect is often local: an
    encoder mount ringing after the strike stands 13 times the floor's mean square in the
    check phase of one channel and is lost in the whole), Bonferroni over those tests; a
    phase counts only where its RMS is at least ``MIN_PLACE_RATIO`` floors. ``acts``: the
    chosen effects' signatures (a place they cover is marked with the effect's name).
    ``draws``: the floor's draws for this model and residual when the caller has them
    (``floor_draws``). None when the model's simulation fails on them."""
    preds = test.simulate(model)
    r = test.residuals(preds)
    if r.size == 0 or np.any(r == ft.FAILED_PENALTY):
        return None
    floor = floor_draws(model, test, r) if draws is None else np.asarray(draws, float)
    ratio, p_all = stats.floor_test(r, floor)
    segs, names = test.segments(), test.segment_channels()
    trial_of = test.segment_trials()
    starts = np.r_[0, np.cumsum(segs)[:-1]].astype(int)
    by_channel: dict[str, tuple[float, float]] = {}
    for s, n, c in zip(starts, segs, names, strict=True):
        a, b = by_channel.get(c, (0.0, 0.0))
        by_channel[c] = (a + float(np.sum(r[s:s + n] ** 2)),
                         b + float(np.mean(np.sum(floor[:, s:s + n] ** 2, axis=1))))
    per_channel = {c: math.sqrt(a / b) if b > 0 else math.inf for c, (a, b) in
                   by_channel.items()}
    held = sorted(set(trial_of))
    blocks: list[tuple[float, Place]] = []
    for i in held:
        comp = cp.compare(measurements[i], [("model", model)], test.input, test.window(i),
                          channels)
        sigs = {(s.channel, s.phase): s for s in sg.signatures(comp, comp.models[0], align_s)}
        t = test.time[i][test.masks[i]]
        for j, (c, tr) in enumerate(zip(names, trial_of, strict=True)):
            if tr != i:
                continue
            for ph, a, b in comp.phases:
                sel = int(starts[j]) + np.flatnonzero((t >= a) & (t < b))
                if sel.size < MIN_BLOCK or (c, ph) not in sigs:
                    continue
                q, pb = stats.floor_test(r[sel], floor[:, sel])
                label = measurements[i].label if len(held) > 1 else ""
                who = next((name for name, es in (acts or {}).items()
                            if c in es.channels and ph in es.phases), "")
                blocks.append((pb, Place(sigs[(c, ph)], math.sqrt(q), pb, i, label, who)))
    tests = 1 + len(blocks)
    # a place counts when it stands clear of the floor (MIN_PLACE_RATIO) and its test passes
    # Bonferroni's level: the draws' variance is itself uncertain in a short phase, and a
    # tail probability of 1e-3 from 24 draws is not one to trust alone (with nothing hidden
    # a whippen's check phase stood 1.8 x the floor's RMS at p = 0.002, 17 tests)
    clear = [(pb, pl) for pb, pl in blocks if pl.floor_ratio >= MIN_PLACE_RATIO]
    p = min(1.0, tests * min([p_all, *(pb for pb, _ in clear)]))
    places = sorted((pl for pb, pl in clear if pb * tests <= alpha),
                    key=lambda pl: -pl.floor_ratio)
    return Remainder(of, ratio, p, alpha, per_channel, places, tests)
