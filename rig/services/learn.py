"""`rig run PROFILE --learn N`: learn the feedforward across N trials.

    report = learn(Path("profiles/forte.yaml"), cfg, 5, on_line=print)

Each learning trial is one `rig run` (rig.services.run.run, one run file per trial,
``<out stem>-learnK.h5``) playing the current table through the loop's
``learned`` hook; after it, the load cell's force at each loop cycle (the acquisition's
record on the card's clock, ``load_cell_at_cycles``; not the possibly late sample the
loop read, ``commands/measured_force``) and the demand written (``commands/demand``)
update the
table (rig.control.ilc.Learner: a Newton-type update through the identified drive
model, with the loop's controller in it, no finer than the load cell's noise). The
first table is what `rig run` would have played: the newest learned record for
this profile if there is one (learning goes on from it), else the motor
calibration's compensation or the 8 ms advance. The learning gain and lead come
from the motor calibration record when one is in use, else the documented
defaults (rig.control.ilc); the update's candidate models are the motor
calibration's dynamic model and the thesis's single and rise/fall models. The kept
table (ilc.kept_trial): of the trials whose load-cell RMS error is within the noise
spread of the lowest, the one with the lowest maximum error; a trial worse than it
beyond the spread is not a starting point (the update restarts from the kept table,
half the step). Learning stops early (keeping that trial) when the error grows;
Ctrl-C, or a trial that ends aborted, stops it too and keeps what was learned so far.
The kept table is written as a learned-feedforward record (rig.control.records) that later
`rig run PROFILE` uses.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rig.calibration import motor as motor_cal
from rig.calibration import records as cal_records
from rig.control import ilc, plant
from rig.control import records as learned_records
from rig.errors import InputError
from rig.inputs import profiles
from rig.inputs.config import RigConfig
from rig.loop import backends
from rig.recordings import runfile
from rig.services import run as run_svc


@dataclass
class LearnReport:
    record: dict[str, Any] | None
    record_path: Path | None
    history: list[dict[str, float]]
    runs: list[Path] = field(default_factory=list)
    stopped: str | None = None


def grid(profile: profiles.Profile, control_hz: float) -> np.ndarray:
    """The loop's trial times (s) over the profile: as many cycles as `rig run` plays."""
    n = int(np.ceil(profile.duration * control_hz - 1e-9)) + 1
    return np.arange(n) / control_hz


def measured_force(path: Path, n: int, column: str = "measured_force") -> np.ndarray:
    """The load cell (or another ``commands`` column, e.g. the ``demand`` written) at the
    first ``n`` loop cycles from the profile's start (N)."""
    tr = runfile.read(path).trials[0]
    t = tr.commands["time"]
    y = tr.commands[column][t >= -1e-9]
    if y.size < n:
        raise InputError(f"{path}: commands/{column}: {y.size} cycles, expected {n}")
    return np.asarray(y[:n], float)


def load_cell_at_cycles(path: Path, n: int) -> np.ndarray:
    """The load cell's force (N) at the first ``n`` loop cycles from the profile's start,
    from the acquisition's record on the card's sample clock (``channels/force``): at each
    cycle's tick, the newest sample before it (the last sample of the period before).

    This, not ``commands/measured_force``, is what the learner learns from and what its
    errors are of. ``measured_force`` is the sample the loop's controller was handed when
    it ran: the same one when the samples come in time (lock-step: equal to the last
    bit), but in real time a sample reaches the loop only when the acquisition has it
    (on the simulated rig, when the plant process has got through the period; it falls
    behind where the action model is dear, around the hammer's strike), and then the
    loop reads the sample a period older. On forte's release (0.75 N per ms) one period
    late is 1.5 N, 5 % of the peak, that is not in the force on the key (measured,
    seed 101 on a loaded machine: the loop read a late sample in 7-14 of 301 cycles of
    a trial, its maximum error 3.3-7.2 % where the recorded force's was 2.1-2.3 %, the
    same as lock-step's). Learned, it is an error the next trial does not repeat."""
    tr = runfile.read(path).trials[0]
    if "force" not in tr.channels:
        raise InputError(f"{path}: channels/force: no load-cell force recorded")
    ts = np.asarray(tr.time, float)
    y = np.asarray(tr.channels["force"], float)
    tc = np.asarray(tr.commands["time"], float)
    tc = tc[tc >= -1e-9][:n]
    if tc.size < n:
        raise InputError(f"{path}: commands/time: {tc.size} cycles, expected {n}")
    half = 0.5 * float(np.median(np.diff(ts))) if ts.size > 1 else 0.0
    idx = np.searchsorted(ts, tc - half, side="right") - 1
    if ts.size < 2 or idx[0] < 0 or ts[-1] < tc[-1] - 3.0 * half:
        raise InputError(f"{path}: channels/force: the record does not cover the profile's "
                         f"{n} cycles")
    return y[idx]


def table(line: list[str]) -> str:
    return "  ".join(line)


UNCALIBRATED_LOAD_CELL = (
    "note: the load cell has no calibration record (data-sheet sensitivity, zero offset "
    "0): its true offset is in every force the learner reads and is learned into the "
    "table, and where the profile asks for 0 N a positive offset is an error no push can "
    "remove; run `rig calibrate loadcell` first")


def drive_models(cfg: RigConfig, motor: dict[str, Any] | None
                 ) -> tuple[plant.DriveModel, ...]:
    """The drive models the update inverts: the motor calibration's (``motor``: its record,
    if one is in use), the thesis's single and rise/fall models; each trial picks the one
    that explains it best, gain re-estimated. Each reads the force as the learner does
    (``load_cell_at_cycles``): the acquisition's sample before each tick, one sample
    period old (``plant.DriveModel.read_age_s``)."""
    age = 1.0 / cfg.rates.acquisition_hz
    return tuple(dataclasses.replace(m, read_age_s=age)
                 for m in [plant.from_motor_record(motor) if motor else None,
                           *plant.thesis_models()] if m is not None)


def learn(profile_path: Path, cfg: RigConfig, n: int, *, out: Path | None = None,
          lockstep: bool = False, factor: float = ilc.DEFAULT_LEARNING_FACTOR,
          on_line: Callable[[str], None] | None = None,
          use_learned: bool = True) -> LearnReport:
    say = on_line or (lambda s: None)
    if n < 1:
        raise InputError(f"--learn: expected at least 1 trial, got {n}")
    profile = profiles.load(profile_path, force_limit=cfg.limits.max_force_n)
    hz = cfg.rates.control_hz
    cals = cal_records.lookup(cfg)
    full_records = cal_records.embedded(cals, cfg)
    if cals["load_cell"].nominal:
        say(UNCALIBRATED_LOAD_CELL)
    t = grid(profile, hz)
    reference = np.array([profile.at(x) for x in t])
    prior = learned_records.find(cfg, profile, full_records) if use_learned else None
    if prior is not None:
        ff, _ = learned_records.demand_source(prior[0])
        say(f"learning from the learned feedforward {prior[1]}")
    else:
        ff, _ = motor_cal.demand_source(cfg, full_records)
    initial = np.array([ff(profile, x) for x in t])
    motor = motor_cal.record_in_use(full_records)
    filt = (ilc.LearningFilter.from_record(motor, hz, factor) if motor is not None
            else ilc.LearningFilter.default(hz, cfg.loop.advance_s, factor))
    noise = backends.load_cell_noise_n(cfg)
    models = drive_models(cfg, motor)
    age = models[0].read_age_s
    # the learner's own copy of the loop's controller (none for open_loop: the feedforward
    # is the demand, and the learner may plan it, ilc.Learner.plans)
    controller = (None if cfg.loop.controller == "open_loop"
                  else run_svc.load_controller(cfg.loop.controller))
    if controller is not None and hasattr(controller, "design_from"):   # as rig run does
        controller.design_from(motor, hz, cfg.limits.max_force_n)
    learner = ilc.Learner.start(reference, initial, filt, cfg.limits, hz, noise_n=noise,
                                models=models, controller=controller, step=factor)
    method = ("model-based (Newton-type, noise-aware"
              + (", minimax plan" if learner.plans else "") + ")" if learner.model_based
              else f"P-type (more than {ilc.MAX_MODEL_POINTS} cycles)")
    filt_meta = {"method": method, "models": [m.name for m in models], "read_age_s": age,
                 "controller": cfg.loop.controller, "step": factor,
                 "noise_n": noise, "gain_n_per_n": filt.gain, "lead_cycles": filt.lead,
                 "q_cutoff_hz": filt.q_cutoff_hz, "source": filt.source}
    if learner.model_based:
        say(f"learning {profile.name} over up to {n} trials; {method} update through "
            f"{', '.join(m.name for m in models)} (reading the load cell "
            f"{age * 1e3:g} ms before each tick); load-cell noise {noise:.3f} N; "
            f"controller {cfg.loop.controller}")
    else:
        say(f"learning {profile.name} over up to {n} trials; P-type learning filter: gain "
            f"{filt.gain:.3f} N/N, lead {filt.lead} cycles, Q {filt.q_cutoff_hz:g} Hz, "
            f"{filt.source}")
    out = Path(out) if out is not None else run_svc.default_path(cfg, profile)
    runs: list[Path] = []
    stopped: str | None = None
    say(table(["trial", "max error %", "RMS error %", "run file"]))
    try:
        for k in range(n):
            path = out.with_name(f"{out.stem}-learn{k + 1}{out.suffix or '.h5'}")
            candidate = learned_records.build(
                cfg, profile, full_records, learner.u, list(learner.history),
                learner.history[-1] if learner.history else {}, filt_meta,
                f"learning trial {k + 1} of {n}")
            rep = run_svc.run(profile_path, backends.trial_rig(cfg, k + 1), out=path,
                              lockstep=lockstep, learned=candidate)
            runs.append(rep.path)
            if not rep.complete:
                stopped = f"trial {k + 1} {rep.status}; kept what was learned before it"
                break
            err = learner.update(load_cell_at_cycles(rep.path, t.size),
                                 measured_force(rep.path, t.size, "demand"),
                                 measured_force(rep.path, t.size, "lateness"))
            say(table([f"{k + 1:5d}", f"{err['max_pct']:11.2f}", f"{err['rms_pct']:11.2f}",
                       str(rep.path)]))
            say(f"       {learner.notes[-1]}")
            if learner.stopped:
                stopped = learner.stopped
                break
    except KeyboardInterrupt:
        stopped = "interrupted (Ctrl-C); kept what was learned so far"
    if stopped:
        say(f"learning stopped: {stopped}")
    if learner.best is None:
        say("nothing learned: no learning trial completed")
        return LearnReport(None, None, learner.history, runs, stopped)
    best_u, best = learner.result()
    rec = learned_records.build(cfg, profile, full_records, best_u, learner.history, best,
                                filt_meta, stopped, created=_dt.datetime.now(_dt.UTC))
    rpath = learned_records.write(cfg, rec)
    say(f"learned feedforward: trial {int(best['trial'])} (the lowest max error of the trials "
        f"whose RMS error is within the noise spread, {learner.spread_pct():.2f} %, of the "
        f"lowest), max error {best['max_pct']:.2f} %, RMS {best['rms_pct']:.2f} % of the peak; "
        f"record {rpath}")
    return LearnReport(rec, rpath, learner.history, runs, stopped)
