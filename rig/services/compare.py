"""`rig compare`: models against a measured run, a table and an HTML report."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from rig.analysis import compare as cp
from rig.analysis import measurement as ms
from rig.analysis import report
from rig.model.action import ActionModel


def load_models(model_files: Sequence[Path], effects: Sequence[str] = ()
                ) -> list[tuple[str, ActionModel]]:
    """(label, model) for each model YAML (the rigid base model if none is given)."""
    if not model_files:
        return [("base model", ActionModel.from_yaml(None, effects=effects))]
    out: list[tuple[str, ActionModel]] = []
    for f in model_files:
        label = Path(f).stem
        if any(label == x for x, _ in out):
            label = str(f)
        out.append((label, ActionModel.from_yaml(f, effects=effects)))
    return out


def compare(run: Path, model_files: Sequence[Path], *, input: str = "force",
            duration: float | None = None, trials: Sequence[int] | None = None,
            channels: Sequence[str] | None = None,
            report_path: Path | None = None) -> list[cp.Comparison]:
    """Compare every model with each selected trial (the first by default)."""
    models = load_models(model_files)
    meas = ms.load(run, list(trials) if trials else [0], input=input)
    comps = [cp.compare(m, models, input, duration, channels) for m in meas]
    if report_path is not None:  # every requested trial
        files: list[str | None] = [str(f) for f in model_files] or [None]
        prov = report.Provenance.of(run, [(lb, f, m) for (lb, m), f in
                                          zip(models, files, strict=True)])
        report.write(comps, report_path, title=f"rig compare: {Path(run).name}",
                     provenance=prov, channels=channels)
    return comps
