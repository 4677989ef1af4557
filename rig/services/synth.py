"""`rig synth`: a measurement-like run file from a truth model the analysis does not see."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from rig.analysis import synth as sy
from rig.inputs import config as rig_config
from rig.inputs import profiles
from rig.model.action import ActionModel


def synth(model_file: Path, profile_files: Sequence[Path], out: Path, *, seed: int = 0,
          trials: int = 1, duration: float | None = None, rig: Path | None = None,
          load_cell_filter: bool = False, noise_scale: float = 1.0,
          record_truth: bool = False) -> list[sy.SynthTrial]:
    """Synthesize ``trials`` blows of each profile through the simulated rig's chain."""
    truth = ActionModel.from_yaml(model_file)
    profs = [profiles.load(p) for p in profile_files]
    cfg = rig_config.load(rig) if rig is not None else None
    return sy.synth(truth, profs, out, cfg=cfg, seed=seed, trials=trials, duration=duration,
                    load_cell_filter=load_cell_filter, noise_scale=noise_scale,
                    record_truth=record_truth, truth_source=str(model_file))
