"""The model as it would be written, checked on the held-out data before it is claimed."""
from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from rig.analysis import fit as ft
from rig.analysis import stats
from rig.analysis.diagnose.common import _set_model
from rig.analysis.diagnose.results import Candidate
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
