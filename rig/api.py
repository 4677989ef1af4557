"""rig's Python API: run files, simulations and diagnoses in a notebook or script.

    import rig
    run = rig.load("runs/forte.h5")           # every trial, any kind of run file
    ds = run.trials[0].to_xarray()            # time (and contact) as coordinates
    df = run.trials[0].to_dataframe()         # pandas, indexed by time (s)
    run.trials[0].plot(window=(0.05, 0.09))   # Plotly figure, events marked
    sim = rig.simulate("profiles/forte.yaml", effects=["compliant_string"])
    sim.summary(); sim.to_xarray()
    diag = rig.diagnose("runs/forte.h5", candidates=["compliant_string", "backcheck_law"])
    print("\\n".join(diag.report_lines()))

The same work as the CLI commands (``rig info``/``rig plot``, ``rig simulate``,
``rig diagnose``), through rig.services; SI units throughout.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rig.errors import InputError, refuse_existing
from rig.recordings import runfile


@dataclass
class Trial(runfile.Trial):
    """One trial of a run file or one simulated blow: channels, units, events, commands;
    ``to_xarray()``, ``to_dataframe()`` (from rig.recordings.runfile.Trial) and ``plot()``."""

    result: Any = None  # the SimResult of rig.simulate (summary(), events, stats)

    def plot(self, channels: Sequence[str] | None = None,
             window: tuple[float, float] | None = None, title: str = "") -> Any:
        """A Plotly figure of ``channels`` (default: the piano maker's first six) over
        ``window`` (s), the trial's events marked; in a notebook it shows itself."""
        from rig.analysis import quicklook

        return quicklook.figure(self, channels, window, title)

    def summary(self) -> dict[str, float]:
        """Strike time and speed, string contact, let-off distance (simulated blows)."""
        if self.result is None:
            raise InputError("summary: only a simulated blow (rig.simulate) has one")
        return dict(self.result.summary())


@dataclass
class Run(runfile.Run):
    """A run file's root attributes, metadata and trials (``rig.load``)."""

    trials: list[Trial]  # type: ignore[assignment]


def load(path: str | Path) -> Run:
    """Read a run file (simulated, synthetic or measured; any status)."""
    r = runfile.read(path)
    return Run(r.path, r.attrs, r.metadata, [Trial(**vars(t)) for t in r.trials])


def simulate(profile: str | Path, *, model: str | Path | None = None,
             effects: Sequence[str] = (), params: str | Path | None = None,
             duration: float | None = None, out: str | Path | None = None,
             force: bool = False) -> Trial:
    """Simulate one blow of the model (the rigid base model plus ``effects``, library names
    or ``file.py:Class``) under a force profile; ``out`` also writes the run file (never
    over an existing file unless ``force``)."""
    from rig.inputs import profiles
    from rig.model.action import CHANNEL_DOCS
    from rig.services import simulate as svc

    m = svc.build_model(Path(model) if model else None, list(effects),
                        Path(params) if params else None)
    if out is not None:
        refuse_existing(Path(out), force)
        res = svc.simulate(Path(profile), Path(out), m, duration=duration)
    else:
        res = m.simulate(profiles.load(Path(profile), kinds=profiles.KINDS), duration)
    ch = {"time": res.time, **{k: v for k, v in res.channels.items() if k != "time"}}
    cols = {k: np.asarray(res.contact_ids) for k, v in ch.items() if np.ndim(v) == 2}
    return Trial(ch, dict(res.units), cols, dict(res.events), {},
                 {"status": "complete" if res.success else f"aborted: {res.message}"},
                 {k: v for k, v in CHANNEL_DOCS.items() if k in ch}, result=res)


def diagnose(run: str | Path, *, model: str | Path | None = None, **options: Any) -> Any:
    """Which effects the model misses in the run (rig.analysis.diagnose.Diagnosis); options
    as ``rig diagnose``'s: input, duration, trials, channels, candidates, extra, jobs,
    single, backward, base_params, scheduler, write, report_path."""
    from rig.services import diagnose as svc

    return svc.diagnose(Path(run), Path(model) if model else None, **options)

