"""Helpers the search, the restarts and the final fit share: a set's effect instances
and model, what moves the input, fit correlations."""
from __future__ import annotations

from collections.abc import Mapping, Sequence

from rig.analysis import fit as ft
from rig.analysis.diagnose.results import Candidate
from rig.model.action import ActionModel
from rig.model.effects import Effect

SAME_MINIMUM = 1e-3           # a restart's minimum this close in training cost is the first's


def _instance(c: Candidate, cls: type[Effect]) -> Effect:
    pre = cls.name + "."
    return cls(**{k[len(pre):]: v for k, v in c.values.items() if k.startswith(pre)})


def _instances(kinds: Sequence[type[Effect]], values: Mapping[str, float]) -> list[Effect]:
    """Instances of ``kinds`` at ``values`` (keyed ``effect.param``)."""
    return [cls(**{k[len(cls.name) + 1:]: v for k, v in values.items()
                   if k.startswith(cls.name + ".")}) for cls in kinds]


def _set_model(base: ActionModel, by_name: Mapping[str, type[Effect]], names: Sequence[str],
               values: Mapping[str, float], rate: float) -> ActionModel:
    """The base model with the effects ``names`` at ``values`` (keyed ``effect.param``)."""
    add = _instances([by_name[n] for n in names], values)
    return ft.rebuild(base, add, dict(values), [ft.target(base, k, add) for k in values], rate)


def _moves_input(cls: type[Effect]) -> bool:
    """Whether the effect transforms the input force (a lag or a filter in time)."""
    return cls.transform_input is not Effect.transform_input


def _pair_corr(res: ft.FitResult) -> dict[tuple[str, str], float]:
    if res.corr is None:
        return {}
    return {(a.label, b.label): float(res.corr[i, j]) for i, a in enumerate(res.targets)
            for j, b in enumerate(res.targets) if i < j}
