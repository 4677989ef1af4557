"""Notes on how far the ranking holds: stability across the window and the trials."""
from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from rig.analysis import fit as ft
from rig.analysis.diagnose.results import Candidate


def stability_notes(first: Sequence[Candidate], base_resid: np.ndarray, test: ft.Data
                    ) -> list[str]:
    """A warning when the candidates' order at the top changes between the early and late
    half of the window, or between held-out trials (each candidate alone)."""
    cands = [c for c in first if not c.error and c.test_resid is not None
             and c.test_resid.shape == base_resid.shape and c.removal > 0]
    if len(cands) < 2:
        return []
    segs = test.segments()
    trial_of = test.segment_trials()
    groups: dict[str, np.ndarray] = {}
    start = 0
    for n, tr in zip(segs, trial_of, strict=True):
        idx = np.arange(start, start + n)
        for key, part in (("early half of the window", idx[: n // 2]),
                          ("late half of the window", idx[n // 2:]),
                          (f"trial {tr}", idx)):
            groups[key] = np.r_[groups.get(key, np.zeros(0, int)), part]
        start += n
    if len(set(trial_of)) < 2:
        groups = {k: v for k, v in groups.items() if not k.startswith("trial")}
    tops = {}
    for key, idx in groups.items():
        e0 = float(np.sum(base_resid[idx] ** 2))
        if e0 <= 0:
            continue
        best = max(cands, key=lambda c: -float(np.sum(np.asarray(c.test_resid)[idx] ** 2)))
        tops[key] = best.name
    if len(set(tops.values())) <= 1:
        return []
    return ["warning: the ranking depends on the window or trial (first alone: "
            + "; ".join(f"{k}: {v}" for k, v in tops.items())
            + "); check the verdict on another window (--duration) or more trials"]
