"""The base model file with the chosen effects and their fitted values appended, and the
chosen base-parameter scales written as parameter overrides."""
from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from rig.analysis import stats
from rig.analysis.diagnose.results import Candidate, Diagnosis
from rig.errors import InputError
from rig.model import base_params as bp
from rig.model import modelfile
from rig.model.action import ActionModel


def write_model(base_yaml: Path | None, diagnosis: Diagnosis | Candidate, out: Path,
                refs: Mapping[str, str] | None = None) -> Path:
    """The base model YAML with the chosen effects and their jointly fitted values appended
    (rounded to their uncertainty), a chosen base-parameter scale as the scaled values of its
    parameters in ``parameters`` (the base model's values times the scale rounded to its
    uncertainty); a user effect is written as ``path.py:Class`` (relative
    to ``out``) or ``module:Class`` so the file loads as written."""
    if isinstance(diagnosis, Diagnosis):
        final = diagnosis.final
        refs = {**diagnosis.refs, **(refs or {})}
        if final is None:
            raise InputError("write: no effect was chosen; nothing to write")
        names = diagnosis.chosen_names
        gain = diagnosis.total_removal()
    else:
        final, names, gain = diagnosis, list(diagnosis.effects or (diagnosis.name,)), \
            diagnosis.removal
    refs = dict(refs or {})
    base, base_dir = modelfile.read(base_yaml)
    out = Path(out)
    out_dir = out.resolve().parent
    data = modelfile.rebased(base, base_dir, out_dir)
    effects = list(data.get("effects") or [])
    scaled = [n for n in names if bp.is_base(n)]
    if scaled:
        _write_scales(data, base_yaml, final, scaled)
    for n in names:
        if bp.is_base(n):
            continue
        vals = {k.split(".", 1)[1]: stats.round_to(float(v), final.sigma.get(k, math.nan))
                for k, v in final.values.items() if k.startswith(n + ".")}
        if len(names) == 1 and not vals and final.values and all(
                "." not in k for k in final.values):
            vals = {k: float(v) for k, v in final.values.items()}
        ref = refs.get(n, n)
        target, sep, cls = ref.rpartition(":")
        if sep and target.endswith(".py"):
            ref = f"{modelfile.relative(Path(target), out_dir)}:{cls}"
        effects.append({ref: vals} if vals else ref)
    data["effects"] = effects
    desc = str(data.get("description", "")).strip()
    data["description"] = (desc + "\n" if desc else "") + (
        f"rig diagnose added {' + '.join(names)} (held-out error "
        + (f"removed {gain * 100:.1f} %)" if gain >= 0 else "worse)"))
    return modelfile.write(data, out)


def _write_scales(data: dict[str, Any], base_yaml: Path | None, final: Candidate,
                  names: list[str]) -> None:
    """Each base-parameter scale in ``names`` as parameter overrides in ``data`` (in place):
    the base model's value of every path it scales, times the scale as written."""
    if isinstance(data.get("parameters"), str):
        raise InputError(f"write: {base_yaml} names a parameter file; a base-parameter scale "
                         f"({', '.join(names)}) can only be written as overrides: give the "
                         "model its parameters as a mapping")
    params = ActionModel.from_yaml(base_yaml).params
    tree = data.setdefault("parameters", {})
    for n in names:
        key = f"{n}.scale"
        scale = stats.round_to(float(final.values[key]), final.sigma.get(key, math.nan))
        for path in bp.CANDIDATES[n].group.paths:
            node = tree
            parts = path.split(".")
            for part in parts[:-1]:
                node = node.setdefault(int(part) if part.isdigit() else part, {})
            node[parts[-1]] = float(f"{float(params.get(path)) * scale:.6g}")
