"""`rig simulate`: one blow of the model under a force profile, into a run file."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from rig.inputs import profiles
from rig.model.action import ActionModel, SimResult
from rig.recordings import runfile


def build_model(model_file: Path | None, effects: Sequence[str] = (),
                params_file: Path | None = None, integrator: str | None = None,
                output_rate: float | None = None) -> ActionModel:
    """The model from a model YAML, extra effects, a parameter file and options."""
    model = ActionModel.from_yaml(model_file, effects=effects, integrator=integrator)
    if params_file is not None or output_rate is not None:
        params = model.params  # the model's own tree (after its model YAML), parsed once
        if params_file is not None:
            params.update_from_file(params_file)  # only what the file names; `default` restores
        model = ActionModel(params, model.effects, model.integrator, output_rate=output_rate)
    return model


def simulate(profile_file: Path, out: Path, model: ActionModel, *,
             duration: float | None = None, force_limit: float = profiles.DEFAULT_FORCE_LIMIT_N,
             on_stage: Callable[[str], None] | None = None,
             progress: Callable[[float, float], None] | None = None) -> SimResult:
    """Simulate the profile and write the run file ``out``."""
    profile = profiles.load(profile_file, force_limit=force_limit, kinds=profiles.KINDS)
    if on_stage:
        on_stage("finding the rest state")
    model.rest_state()
    if on_stage:
        on_stage("simulating")
    result = model.simulate(profile, duration, progress=progress)
    runfile.write_result(out, result, kind="simulated")
    return result
