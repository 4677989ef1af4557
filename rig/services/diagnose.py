"""`rig diagnose`: where a model fails against a run and which effects are missing."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from rig.analysis import compare as cp
from rig.analysis import diagnose as dg
from rig.analysis import fit as ft
from rig.analysis import measurement as ms
from rig.analysis import report
from rig.model import base_params as bp
from rig.model.action import ActionModel
from rig.model.effects import BUILTIN, Effect, make


def diagnose(run: Path, model_file: Path | None, *, input: str = "force",
             duration: float | None = None, trials: Sequence[int] | None = None,
             channels: Sequence[str] | None = None, candidates: Sequence[str] | None = None,
             extra: Sequence[str] = (), jobs: int | None = None, single: bool = False,
             backward: bool = False, base_params: bool = False, scheduler: str | None = None,
             write: Path | None = None, report_path: Path | None = None,
             progress: Callable[[float, float, str], None] | None = None) -> dg.Diagnosis:
    """Diagnose the model (the rigid base model if none) against the run's trials; the
    candidates' fits run on local processes or the Dask cluster at ``scheduler`` (else
    ``$RIG_SCHEDULER``)."""
    from rig.analysis.executor import executor_for

    model = ActionModel.from_yaml(model_file)
    extra_classes = [type(make(e, Path.cwd())) for e in extra]
    refs = {}
    for spec, cls in zip(extra, extra_classes, strict=True):
        target, _, name = spec.rpartition(":")
        refs[cls.name] = (f"{Path(target).resolve()}:{name}" if target.endswith(".py")
                          else spec)
    meas = ms.load(run, list(trials) if trials else None, input)  # motion: no force needed
    label = Path(model_file).stem if model_file is not None else "base model"
    with executor_for(jobs, scheduler) as ex:
        diag = dg.diagnose(model, meas, input=input, duration=duration, channels=channels,
                           candidates=candidates, extra=extra_classes, jobs=jobs,
                           label=label, single=single, backward=backward, executor=ex,
                           progress=progress, base_params=base_params)
    diag.refs = refs
    if write is not None and diag.best is not None:  # nothing to write without a winner
        dg.write_model(model_file, diag, write)
    if report_path is not None:
        write_report(diag, model, model_file, label, meas, extra_classes, report_path,
                     run=run, input=input, duration=duration, channels=channels)
    return diag


def winner_model(diag: dg.Diagnosis, base: ActionModel, rate: float,
                 extra: Sequence[type[Effect]] = ()) -> ActionModel | None:
    """The base model with the diagnosis's chosen set of effects at their jointly fitted
    values (None when nothing was chosen)."""
    final = diag.final
    if final is None:
        return None
    classes = {**BUILTIN, **bp.CANDIDATES, **{c.name: c for c in extra}}
    effects = []
    for name in diag.chosen_names:
        pre = name + "."
        values = {k[len(pre):]: v for k, v in final.values.items() if k.startswith(pre)}
        effects.append(classes[name](**values))
    return ft.rebuild(base, effects, rate=rate)


def write_report(diag: dg.Diagnosis, model: ActionModel, model_file: Path | None, label: str,
                 meas: Sequence[ms.Measurement], extra: Sequence[type[Effect]], out: Path, *,
                 run: Path, input: str, duration: float | None,
                 channels: Sequence[str] | None) -> Path:
    """The diagnose report: every trial against the base model and base + winner."""
    rate = meas[0].rate
    base = ft.rebuild(model, rate=rate)
    models: list[tuple[str, ActionModel]] = [(label, base)]
    files: list[str | None] = [str(model_file) if model_file is not None else None]
    win = winner_model(diag, model, rate, extra)
    if win is not None:
        models.append((f"{label} + {' + '.join(diag.chosen_names)}", win))
        files.append("(rig diagnose: the chosen effects at their jointly fitted values)")
    comps = [diag.comparison if len(models) == 1 and i == 0 else
             cp.compare(m, models, input, duration, channels) for i, m in enumerate(meas)]
    held = list(diag.held_out_trials)
    prov = report.Provenance.of(run, [(lb, f, m) for (lb, m), f in
                                      zip(models, files, strict=True)])
    return report.write(comps, out, title=f"rig diagnose: {Path(run).name}", diagnosis=diag,
                        provenance=prov, held_out=held, channels=channels,
                        held_out_text="held out: the candidates were fitted on the other "
                                      "trials and scored on this one")
