"""`rig sweep`: a design of blows over parameter ranges, their metrics, Sobol indices."""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from pathlib import Path

from rig.analysis import sweep as sw
from rig.analysis.executor import executor_for
from rig.errors import InputError
from rig.inputs import profiles
from rig.model.action import ActionModel


def sweep(model_file: Path | None, profile_file: Path, params: Sequence[str], out: Path, *,
          design: str = "sobol", samples: int = 64, seed: int = 0,
          duration: float | None = None, scheduler: str | None = None,
          jobs: int | None = None, resume: bool = False, force: bool = False,
          report: Path | None = None, batch: int = 1, touch: bool = False,
          progress: Callable[[int, int, float], None] | None = None,
          stop: Callable[[], bool] | None = None) -> tuple[sw.SweepResult, sw.Sensitivity | None]:
    """Run (or finish) the sweep into ``out``; Sobol indices for a sobol design. With
    ``touch`` every row also reports its model's touch weights (rig touch)."""
    axes = [sw.Axis.parse(p) for p in params]
    if len({a.name for a in axes}) != len(axes):
        raise InputError("param: each parameter may appear once")
    sw.make_design(design, axes, samples, seed)  # bad design input fails before any work
    if report is not None and Path(report).exists() and not force:
        raise InputError(f"report: {report} exists; use --force to replace it")
    if report is not None and design != "sobol":
        raise InputError("report: Sobol indices need --design sobol")
    model = ActionModel.from_yaml(model_file)
    profile = profiles.load(profile_file)
    ident = {"profile": hashlib.sha256(Path(profile_file).read_bytes()).hexdigest()}
    study = sw.action_study(model, profile, axes, duration=duration, identity=ident,
                             touch=touch)
    with executor_for(jobs, scheduler) as ex:
        res = sw.run_sweep(study, axes, design, samples, out, ex, seed=seed, resume=resume,
                           force=force, batch=batch, progress=progress,
                           stop=stop)
    sens = None
    if design == "sobol":
        sens = sw.sensitivity(out, seed)
        sw.write_sensitivity(out, sens)
        if report is not None:
            sw.write_report(report, sens, f"rig sweep: {Path(out).name}")
    return res, sens
