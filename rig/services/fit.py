"""`rig fit`: fit model or effect parameters to one or many runs."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from rig.analysis import fit as ft
from rig.analysis import measurement as ms
from rig.errors import InputError
from rig.model import modelfile
from rig.model.action import ActionModel
from rig.model.effects import make


def fit(runs: Sequence[Path], model_file: Path | None, params: Sequence[str], *,
        input: str = "force", duration: float | None = None,
        channels: Sequence[str] | None = None, jobs: int | None = None,
        max_nfev: int = 40, write: Path | None = None, scheduler: str | None = None,
        progress: Callable[[float, float, str], None] | None = None) -> ft.FitResult:
    """Fit ``params`` on every trial of every run; the Jacobian's columns run on local
    processes (one per core) or the Dask cluster at ``scheduler`` (else
    ``$RIG_SCHEDULER``)."""
    from rig.analysis.executor import executor_for

    if not runs:
        raise InputError("runs: expected at least one run file")
    model = ActionModel.from_yaml(model_file)
    meas = [m for r in runs for m in ms.load(r, None, input)]  # motion: no force needed
    data = ft.Data.build(meas, input, duration, channels)
    with executor_for(jobs, scheduler) as ex:
        res = ft.fit(model, data, params, executor=ex, max_nfev=max_nfev, progress=progress,
                     input_noise_draws=ft.INPUT_NOISE_DRAWS)
    if write is not None:
        write_model(model_file, res, write)
    return res


def write_model(model_file: Path | None, res: ft.FitResult, out: Path) -> Path:
    """The model YAML with the fitted values: effect values in ``effects``, model parameters
    as overrides in ``parameters`` (a parameter file reference is kept as is and must then
    not be combined with fitted model parameters)."""
    base, base_dir = modelfile.read(model_file)
    out_dir = Path(out).resolve().parent
    listed = base.get("effects") or []
    # each listed effect's own name (a user effect is listed as path.py:Class or
    # module:Class, its name is the class's ``name``)
    names = [make(e, base_dir).name for e in listed]
    data = modelfile.rebased(base, base_dir, out_dir)
    effects = list(data.get("effects") or [])
    for t in res.targets:
        v = float(res.values[t.label])
        if t.effect is None:
            params = data.get("parameters")
            if isinstance(params, str):
                raise InputError(f"write: {model_file} names a parameter file; add {t.label} "
                                 f"= {v:.6g} to it by hand")
            tree = data.setdefault("parameters", {})
            node = tree
            parts = t.key.split(".")
            for part in parts[:-1]:
                key: Any = int(part) if part.isdigit() else part
                node = node.setdefault(key, {})
            last: Any = int(parts[-1]) if parts[-1].isdigit() else parts[-1]
            node[last] = v
            continue
        for i, e in enumerate(effects):
            name = next(iter(e)) if isinstance(e, dict) else e
            if names[i] == t.effect:
                vals = dict(e[name] or {}) if isinstance(e, dict) else {}
                vals[t.key] = v
                effects[i] = {name: vals}
                break
    data["effects"] = effects
    return modelfile.write(data, out)
