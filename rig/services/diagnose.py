"""`rig diagnose`: where a model fails against a run and which effects are missing."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from rig.analysis import diagnose as dg
from rig.analysis import measurement as ms
from rig.analysis import report
from rig.model.action import ActionModel
from rig.model.effects import make


def diagnose(run: Path, model_file: Path | None, *, input: str = "force",
             duration: float | None = None, trials: Sequence[int] | None = None,
             channels: Sequence[str] | None = None, candidates: Sequence[str] | None = None,
             extra: Sequence[str] = (), jobs: int | None = None, single: bool = False,
             backward: bool = False,
             write: Path | None = None, report_path: Path | None = None,
             progress: Callable[[float, float, str], None] | None = None) -> dg.Diagnosis:
    """Diagnose the model (the rigid base model if none) against the run's trials."""
    model = ActionModel.from_yaml(model_file)
    extra_classes = [type(make(e, Path.cwd())) for e in extra]
    refs = {}
    for spec, cls in zip(extra, extra_classes, strict=True):
        target, _, name = spec.rpartition(":")
        refs[cls.name] = (f"{Path(target).resolve()}:{name}" if target.endswith(".py")
                          else spec)
    meas = ms.load(run, list(trials) if trials else None)
    label = Path(model_file).stem if model_file is not None else "base model"
    diag = dg.diagnose(model, meas, input=input, duration=duration, channels=channels,
                       candidates=candidates, extra=extra_classes, jobs=jobs, label=label,
                       single=single, backward=backward, progress=progress)
    diag.refs = refs
    if write is not None and diag.best is not None:  # nothing to write without a winner
        dg.write_model(model_file, diag, write)
    if report_path is not None:
        report.write(diag.comparison, report_path, title=f"rig diagnose: {Path(run).name}",
                     diagnosis=diag)
    return diag
