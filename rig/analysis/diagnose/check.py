"""The model as it would be written, checked on the held-out data before it is claimed."""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from rig.analysis import fit as ft
from rig.analysis import stats
from rig.analysis.diagnose.common import _set_model
from rig.analysis.diagnose.results import Candidate, WorseTrial
from rig.analysis.diagnose.search import model_p
from rig.model.action import ActionModel
from rig.model.effects import Effect


def written_values(final: Candidate) -> dict[str, float]:
    """The final set's values as ``write_model`` writes them (rounded to their
    uncertainty)."""
    return {k: stats.round_to(float(v), final.sigma.get(k, math.nan))
            for k, v in final.values.items()}


def written_removal(final: Candidate, base: ActionModel, by_name: Mapping[str, type[Effect]],
                    test: ft.Data, base_ms: Mapping[str, float]) -> float | None:
    """The share of the base model's held-out error (``base_ms``: mean square over range
    squared per channel, averaged over channels) that the final set removes at its values
    as written; negative when the written model predicts the held-out data worse than the
    base. The scores a set was judged by are those of the round's fit; the final refits,
    restarts and the rounding that follow are scored here. None when a simulation
    fails."""
    names = final.effects or (final.name,)
    try:
        model = _set_model(base, by_name, names, written_values(final),
                           test.measurements[0].rate)
        got = test.channel_ms(test.simulate(model))
    except (ValueError, RuntimeError, FloatingPointError, np.linalg.LinAlgError):
        return None
    chans = [c for c in base_ms if c in got]
    e0 = float(np.mean([base_ms[c] for c in chans]))
    e1 = float(np.mean([got[c][0] for c in chans]))
    return 1.0 - e1 / e0 if e0 > 0 else 0.0


def worse_trial(final: Candidate, base: ActionModel, by_name: Mapping[str, type[Effect]],
                data: ft.Data, held_out: Sequence[int], alpha: float, noise: bool = True
                ) -> WorseTrial | None:
    """The trial of the run -- fitted on or held out -- that the model as it would be written
    predicts worse than the base model, significantly (``search.model_p``: the held-out
    noise-model test asked the other way round, or with ``noise`` False the HAC test, at
    ``alpha`` over the number of trials), the most significant one; None when there is
    none. A set of true effects at their values fits every blow at least as well as the
    base, within the noise; a set that trades one blow's fit for the others' stands in for
    something else (measured, issue 39, wide benchmark development seed 160: felt
    hysteresis, a 100 Hz load-cell filter and friction at the key front outside the
    library; back check + shank + lift-off removed 79 % of the held-out blow's error and
    made the 8 N held blow it was fitted on 22 times worse, and two blows the diagnosis
    never saw 4.7 and 8 times worse). A trial whose simulation fails is skipped."""
    names = final.effects or (final.name,)
    n = len(data.measurements)
    try:
        model = _set_model(base, by_name, names, written_values(final),
                           data.measurements[0].rate)
    except (ValueError, RuntimeError, FloatingPointError, np.linalg.LinAlgError):
        return None
    worst: WorseTrial | None = None
    for i in range(n):
        one = data.subset([np.full(t.shape, j == i) for j, t in enumerate(data.time)])
        try:
            r_written = one.residuals(one.simulate(model))
            r_base = one.residuals(one.simulate(base))
            ms_written, ms_base = float(np.mean(r_written ** 2)), float(np.mean(r_base ** 2))
            if not ms_written > ms_base:
                continue
            p = model_p(model, one, r_written, r_base, noise)
        except (ValueError, RuntimeError, FloatingPointError, np.linalg.LinAlgError):
            continue
        if p <= alpha / n and (worst is None or p < worst.p_value):
            worst = WorseTrial(i, data.measurements[i].label, 1.0 - ms_written / ms_base, p,
                               i in held_out)
    return worst
