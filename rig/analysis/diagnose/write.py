"""The base model file with the chosen effects and their fitted values appended."""
from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

from rig.analysis import stats
from rig.analysis.diagnose.results import Candidate, Diagnosis
from rig.errors import InputError
from rig.model import modelfile


def write_model(base_yaml: Path | None, diagnosis: Diagnosis | Candidate, out: Path,
                refs: Mapping[str, str] | None = None) -> Path:
    """The base model YAML with the chosen effects and their jointly fitted values appended
    (rounded to their uncertainty); a user effect is written as ``path.py:Class`` (relative
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
    for n in names:
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
