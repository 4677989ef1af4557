"""Measurement-like run files from a truth model the analysis does not see.

The chain is the simulated rig's (rig.sim_backend): the 500 Hz loop's demand
(the profile, advanced by the loop's ``advance_s``) drives the drive's
third-order process model at the acquisition rate; that force presses the key
of the truth model (its effects included); the truth's channels pass the sensor
models: the load cell (noise; with ``load_cell_filter=True`` also a 4-pole
filter, by default the hardware's 100 Hz, *on top of* the drive model, which
already contains that filter as the thesis identified it: the recorded force
then lags the key force as on the real rig, and the demand by ~4 ms more than
the thesis measured), the strain gauge (noise, when the truth has a flexible shank) and
the encoders (quantized counts). Channels are stored raw and calibrated with
the sensors' true calibration, like a calibrated measured run. The truth model
is recorded in the file only on request (``record_truth``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rig.errors import InputError
from rig.inputs import config as rig_config
from rig.inputs import profiles
from rig.inputs.config import RigConfig
from rig.model.action import ActionModel, SimResult
from rig.recordings import runfile
from rig.sensors import table as sensor_table
from rig.sim_backend.drive_model import DriveResponse
from rig.sim_backend.sensors import SensorSet

COMMAND_UNITS = {k: sensor_table.COMMAND_UNITS[k] for k in ("time", "demand")}
HARDWARE_FILTER_HZ = 100.0  # the SCXI-1520's filter


def default_rig(key_rotary: bool = True) -> RigConfig:
    """The built-in simulated rig, plus a rotary encoder on the key (key_angle) by default:
    the thesis's rig reads the key's rotation on a circular scale."""
    cfg = rig_config.builtin_sim()
    if not key_rotary:
        return cfg
    enc = cfg.channels.encoders["hammer"].model_copy(update={
        "counter": "Dev3/ctr3", "body": "key", "kind": "angular", "channel": "key_angle"})
    encs = {**cfg.channels.encoders, "key_rotary": enc}
    channels = cfg.channels.model_copy(update={"encoders": encs})
    return cfg.model_copy(update={"channels": channels})


@dataclass
class SynthTrial:
    """One synthesized trial: the truth's own result and the measurement-like channels."""

    truth: SimResult
    channels: dict[str, np.ndarray]
    units: dict[str, str]
    commands: dict[str, np.ndarray]


def demand(profile: profiles.Profile, cfg: RigConfig, duration: float) -> tuple[np.ndarray,
                                                                               np.ndarray]:
    """The loop's demand at the control ticks: the profile advanced by ``loop.advance_s``."""
    dt = 1.0 / cfg.rates.control_hz
    t = np.arange(0.0, duration + dt / 2, dt)
    return t, profile.at(t + cfg.loop.advance_s)


def synth_trial(truth: ActionModel, profile: profiles.Profile, cfg: RigConfig,
                rng_seed: int, duration: float | None = None, load_cell_filter: bool = False,
                noise_scale: float = 1.0) -> SynthTrial:
    """One trial of the truth model through the drive and sensor models."""
    if noise_scale < 0:
        raise InputError(f"noise_scale: expected >= 0, got {noise_scale}")
    dur = profile.duration if duration is None else float(duration)
    if not dur > 0:
        raise InputError(f"duration: expected a positive time in s, got {duration}")
    rate = cfg.rates.acquisition_hz
    n_per = cfg.rates.samples_per_cycle
    tc, dem = demand(profile, cfg, dur)
    drive = DriveResponse(1.0 / rate, cfg.sim.drive_model, cfg.sim.process_time_unit_s,
                          truth.params)
    force = np.concatenate([[0.0]] + [np.maximum(drive.step(float(u), n_per), 0.0)
                                      for u in dem])
    ts = np.arange(force.size) / rate
    keep = ts <= dur + 1e-12
    ts, force = ts[keep], force[keep]
    model = truth if abs(truth.output_rate - rate) < 1e-9 else ActionModel(
        truth.params, truth.effects, truth.integrator, output_rate=rate)
    res = model.simulate(profiles.Profile(ts, force, "drive force", "synth", "synth"), dur)
    if not res.success:
        raise RuntimeError(f"the truth model's simulation failed: {res.message}")
    sim = cfg.sim.model_copy(update={
        "load_cell_noise_n": cfg.sim.load_cell_noise_n * noise_scale,
        "strain_noise": cfg.sim.strain_noise * noise_scale,
        "load_cell_filter_hz": (cfg.sim.load_cell_filter_hz or HARDWARE_FILTER_HZ)
        if load_cell_filter else None})
    sensors = SensorSet.from_config(cfg.model_copy(update={"sim": sim}), seed=rng_seed)
    # the load cell reads the drive's force where the arm presses; effects of the truth that
    # transform the input (a lag, ...) act between it and the key
    true_ch = {**res.channels, "force": np.interp(res.time, ts, force)}
    ch: dict[str, np.ndarray] = {"time": res.time.copy()}
    units = {"time": "s"}
    for s in sensor_table.sensors(cfg):
        m = sensors[s.name]
        true = m.chain.truth(true_ch)
        if true is None:  # the truth lacks it (a rigid shank has no strain)
            continue
        if m.chain.counts_from_start:
            m.offset = float(true[0])
        raw = m.measure(true)
        # stored calibrated with the sensors' true calibration
        ch[s.raw], ch[s.channel] = raw, s.to_si(raw, m.sensitivity, m.offset)
        units[s.raw], units[s.channel] = s.raw_units, s.units
    return SynthTrial(res, ch, units, {"time": tc, "demand": dem})


def synth(truth: ActionModel, profile_list: Sequence[profiles.Profile], out: Path, *,
          cfg: RigConfig | None = None, seed: int = 0, trials: int = 1,
          duration: float | None = None, load_cell_filter: bool = False,
          noise_scale: float = 1.0, record_truth: bool = False,
          truth_source: str = "") -> list[SynthTrial]:
    """Write a synthetic run file: ``trials`` repetitions of each profile (fresh noise each)."""
    if trials < 1:
        raise InputError(f"trials: expected at least 1, got {trials}")
    if not profile_list:
        raise InputError("profile: expected at least one profile")
    cfg = cfg or default_rig()
    made: list[SynthTrial] = []
    meta: dict[str, Any] = {
        "profile": [p.to_metadata() for p in profile_list],
        "synth": {"seed": seed, "trials_per_profile": trials, "load_cell_filter": load_cell_filter,
                  "noise_scale": noise_scale, "rate_hz": cfg.rates.acquisition_hz,
                  "drive_model": cfg.sim.drive_model, "advance_s": cfg.loop.advance_s},
        "rig_config": cfg.model_dump(mode="json"),
    }
    if record_truth:
        d = truth.describe()
        meta["truth"] = {"source": truth_source, "effects": d["effects"]}
    docs = sensor_table.channel_docs(cfg)
    with runfile.RunWriter(out, "synthetic", meta) as w:
        k = 0
        for prof in profile_list:
            for _ in range(trials):
                st = synth_trial(truth, prof, cfg, seed * 1000 + k, duration, load_cell_filter,
                                 noise_scale)
                tw = w.trial()
                tw.append("channels", st.channels, st.units, docs)
                tw.append("commands", st.commands, COMMAND_UNITS, sensor_table.COMMAND_DOCS)
                tw.set_attrs(status="complete", t0=0.0, profile=prof.name)
                made.append(st)
                k += 1
    return made
