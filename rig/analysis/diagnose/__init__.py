"""Where a model fails against measurements, and which effects are missing.

(1) The base model is compared with the trial and each channel's residual in
each phase gets a signature (rig.analysis.signature). (2) Joint search (the
default): forward selection over the library's effects not in the model (and
``extra`` user effects). In each round every remaining candidate is added to
the effects chosen so far, the fitted parameters of ALL of them are refitted
together on the training samples (a coarse scan of the new candidate's
parameters across their bounds, then scipy least squares from the chosen
set's current values), and the result is scored on held-out samples (other
trials when there are several, else alternate 2 ms blocks of the one trial).
The best significant addition joins the set; the search stops when no
addition is significant (or at ``max_effects``). An optional backward pass
drops a chosen effect whose removal (with a joint refit of the rest) does not
make the held-out error significantly worse. The last accepted joint fit is
the final one: its values, uncertainties (HAC plus the input force's noise,
``fit.input_noise_cov``) and correlations are reported.
``single=True`` gives only the first round: each candidate alone against the
model, ranked.

With ``base_params=True`` (``rig diagnose --base``) the base-parameter candidates of
rig.model.base_params (a short list of scale factors on masses, inertias, felt stiffness and
damping, spring preloads and pivot friction, each named ``base:<path>``) enter the same
search; one ranked above a significant library effect goes after it unless the held-out test
shows it better (``rank``), one whose scale ends on its prior's bound is not significant
(``judge``), a chosen one takes one of the ``max_effects`` places, and the final refit of a
set holding one is taken without the whole-blow alignment. Off by default
(docs/workflow.md, docs/performance.md).

With ``weights="noise"`` every residual of the diagnosis (fits, scores, tests, the
remainder) is weighed by a noise model of the data under the base model
(``fit.noise_weights``: white output noise plus the model's response to the input force's
noise, the squared weights' median 1 in each trial's channel): where the force's noise
moves the prediction most (the key's return in a long window), a sample says least about
the model. The held-out noise-model tests then take both the weighted and the unweighted
statistic and double the smaller p (``stats.weighted_noise_model_test``): the weights treat
the force's noise as independent from sample to sample, while it moves a blow in a few
correlated directions, so a short effect at the strike or the catch keeps its power in the
unweighted statistic. The default, ``weights="none"``, weighs every sample alike: the
weighted default is measured (docs/performance.md) but not yet run through the whole
slow tier (docs/workflow.md).

A candidate counts as significant only when all hold:
- it lowers the training error and removes at least ``min_gain`` of the held-out
  error the current model leaves above its noise floor (mean over channels of the mean
  square residual over the channel's range squared, less what the output noise and the
  input force's noise through the model hold: ``search.channel_floor``), and on some
  channel a held-out mean square of at least ``min_noise_gain`` times the channel's noise
  variance;
- the held-out improvement passes a one-sided test of the mean difference of
  squared residuals at level ``alpha`` divided by the number of candidates in the
  round that can act on the data (Bonferroni: the whole round's false-alarm rate is at
  most ``alpha``; ``search.inert``: a candidate none of whose parameters moves the
  prediction is left out of the count and of the search).
  By default (``held_out_test="noise"``) its variance comes from a noise model
  of the held-out trials (white output noise plus the model's simulated response to
  the input force's noise), so another missing effect's misfit is not taken for
  noise, and each held-out trial's channel is weighed by the evidence it can hold
  (rig.analysis.stats.segment_noise_test: its expected gain over its noise variance),
  so a blow whose timing the force's noise moves does not swamp a quiet channel that
  shows the change; ``"hac"`` (and any input other
  than the measured force) takes it from the residuals instead
  (stats.improvement_test, Diebold-Mariano type, Newey-West within each trial's
  channel);
- a parameter that has an "off" value (EffectParameter.off) is not within
  ``z_off`` (1.96) standard errors of it for every such parameter: an effect
  whose own parameters are indistinguishable from "off" explains nothing. An
  effect that switches on another candidate (``Effect.implies``) must pass this
  on its own parameters, or it is not named: the effect it implies is;
- (the best candidate only, then the next) from the second round on, the set without
  it, at the values fitted with it, is significantly worse (``_without_newcomer``): a
  joint refit that only fits the chosen effects better is theirs, and the round is
  fitted again from those values. The final set, after its restarts, is asked the same
  of each effect at ``alpha`` (``_unneeded``): the one least needed is dropped; when
  each is needed at the final values, it is asked again with the others refitted
  without it.

The held-out test both ways (``core.diagnose``). With several blows the usual side fits the
strongest blow and scores the others, where an effect the strong blow shows may barely act:
its search runs at ``USUAL_SHARE`` (0.8) of ``alpha``; when it chooses nothing, the search
runs again with the sides swapped at the rest of the level, and its choice is taken only
when each effect its first step added, alone in the usual side's first round, passes every
check there but the level (when no candidate there passes them, the swapped side is not
searched). The two searches' false alarms together stay within ``alpha``;
one trial, or repeats of one blow, get one search at ``alpha``.

Before scoring, each trial's prediction may shift as a whole by up to
``align_s`` (0.5 ms): the input's noise moves a blow by a few tenths of a ms
from trial to trial, and no effect should get credit for that. Candidates of a
round are fitted in parallel, one process per core.

The package: ``results`` (Candidate, Diagnosis, their text), ``search`` (rounds,
judgement, the pick, the needed-effect tests, convergence, backward check),
``restarts`` (restarts, box starts, valleys), ``notes`` (stability across window and
trials), ``core`` (``diagnose``), ``write`` (``write_model``). Every name is exported here;
setting a module constant or function here (a test's monkeypatch) sets it in the
submodules that use it.
"""

from __future__ import annotations

import sys
import types
from typing import Any

from rig.analysis import fit as ft
from rig.analysis.diagnose import common, core, notes, restarts, results, search, write
from rig.analysis.diagnose.check import worse_trial
from rig.analysis.diagnose.common import (
    SAME_MINIMUM,
    _instance,
    _instances,
    _moves_input,
    _pair_corr,
    _set_model,
)
from rig.analysis.diagnose.core import USUAL_SHARE, _one_way, diagnose
from rig.analysis.diagnose.notes import stability_notes
from rig.analysis.diagnose.restarts import (
    BOX_STARTS_PER_PARAM,
    SIMEX_DRAWS,
    VALLEY_BISECTIONS,
    VALLEY_CORR,
    VALLEY_NOISE_DRAWS,
    VALLEY_PARTNER_NFEV,
    VALLEY_STARTS,
    Minimum,
    _box_starts,
    _Line,
    _noise_free_gap,
    _restarts,
    _set_effects,
    _valley_pairs,
    _valleys,
)
from rig.analysis.diagnose.results import Candidate, Diagnosis, WorseTrial, _unit, rank
from rig.analysis.diagnose.search import (
    INERT_WHY,
    MAX_READOPT,
    State,
    _add_input_noise,
    _backward,
    _converge,
    _evaluate,
    _noise_draws,
    _off_z,
    _pick,
    _round,
    _unneeded,
    _without,
    _without_newcomer,
    candidates_for,
    evaluate_candidate,
    held_out_p,
    inert,
    judge,
)
from rig.analysis.diagnose.write import write_model

__all__ = [
    "BOX_STARTS_PER_PARAM", "INERT_WHY", "USUAL_SHARE", "_one_way", "MAX_READOPT",
    "SAME_MINIMUM", "SIMEX_DRAWS",
    "VALLEY_BISECTIONS", "VALLEY_CORR", "VALLEY_NOISE_DRAWS", "VALLEY_PARTNER_NFEV",
    "VALLEY_STARTS", "Candidate", "Diagnosis", "Minimum", "State", "_Line", "_add_input_noise",
    "_backward", "_box_starts", "_converge", "_evaluate", "_instance", "_instances",
    "_moves_input", "_noise_draws", "_noise_free_gap", "_off_z", "_pair_corr", "_pick",
    "_restarts", "_round", "_set_effects", "_set_model", "_unit", "_unneeded", "_valley_pairs",
    "_valleys", "_without", "_without_newcomer", "candidates_for", "diagnose",
    "evaluate_candidate", "ft", "held_out_p", "inert", "judge", "rank",
    "stability_notes", "worse_trial", "WorseTrial", "write_model",
]

_PARTS = (common, results, search, restarts, notes, core, write)


class _Package(types.ModuleType):
    """Setting a name on the package sets it in every part that holds it too (a test's
    ``monkeypatch.setattr(dg, "VALLEY_STARTS", ())`` reaches the restarts that read it)."""

    def __setattr__(self, name: str, value: Any) -> None:
        super().__setattr__(name, value)
        for part in _PARTS:
            if name in vars(part):
                setattr(part, name, value)


sys.modules[__name__].__class__ = _Package
