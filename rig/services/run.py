"""`rig run`: press the key with a force profile and record everything.

    report = run(Path("profiles/forte.yaml"), cfg, trials=3, on_line=print)

The run's process holds the 500 Hz torque loop; a separate acquisition
process (rig.loop.acquisition) owns the run file and streams the 2 kHz channels.
Order: validate the profile against the rig's limits (nothing moves if it is
refused) -> start the acquisition process -> zero the drive output (NI: read it
back) -> enable the drive -> arm the cards -> loop -> zero demand -> disable the
drive -> stop acquisition.
Each cycle: feedforward = profile(t + advance) -- or, when a motor calibration
record is in use, its inverse force map of profile(t + lag) -- controller hook
(may use the load cell), limits, volts, write, record the write's lateness. Ctrl-C, a drive fault, a
dead acquisition process or too many late cycles in a row set the demand to
zero in that same cycle, disable the drive and close the file ``aborted: ...``.

Its parts, by job: the controller hook in rig.loop.hook, the feedforward choice in
rig.calibration.motor.demand_source, the loop thread's OS set-up in rig.loop.scheduling
(``loop_cpu``, ``LoopScheduling``), the loop's records, the acquisition's end and the
file's recovery in rig.loop.recovery.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import errno
import math
import multiprocessing as mp
import os
import queue
import shutil
import signal
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rig import loadcell, motor_torque
from rig.analysis import events
from rig.calibration import motor as motor_cal
from rig.calibration import records as cal_records
from rig.calibration.settings import records_folder
from rig.daq import Daq
from rig.errors import InputError, RigError
from rig.inputs import profiles
from rig.inputs.config import RigConfig
from rig.loop import journal, recovery, scheduling
from rig.loop.acquisition import run_acquisition
from rig.loop.backends import check_drive_port, open_daq, open_drive_port, reader_calibration
from rig.loop.drive import Drive, DriveError, DriveMonitor
from rig.loop.hook import Controller, load_controller
from rig.model.vocabulary import EVENT_DOCS
from rig.recordings import runfile


def enable_at_zero(daq: Daq, drive: Drive, say: Callable[[str], None]) -> None:
    """The drive is enabled only after 0 V is on its input: the output is zeroed (and read
    back where the cards allow) first, since an analog output holds whatever a test panel
    or a failed session left on it."""
    volts = daq.zero_output()
    if volts is not None:
        say(f"drive output reads {volts:+.4f} V after writing 0 V: enabling the drive")
    drive.enable()


@dataclass
class CycleContext:
    """What a per-cycle hook sees (tests use it to inject faults)."""

    tick: int
    trial: int
    t: float
    acquisition_pid: int | None
    sim_drive: Any
    daq: Daq


@dataclass
class RunReport:
    path: Path
    status: str
    ticks: int
    lateness: dict[str, float]
    samples: int | None
    repeatability: dict[str, dict[str, float]] = field(default_factory=dict)

    @property
    def complete(self) -> bool:
        return self.status == "complete"


class _Abort(RigError):
    pass


class _Stopped(BaseException):
    """A stop signal (SIGINT, SIGTERM, SIGHUP) that arrived before the loop was running."""


STOP_SIGNALS: dict[int, str] = {
    signal.SIGINT: "interrupted (Ctrl-C)", signal.SIGTERM: "terminated (SIGTERM)",
    signal.SIGHUP: "hung up (SIGHUP: terminal closed)"}


def _install_stop_handlers(state: dict[str, Any]) -> dict[int, Any]:
    """SIGINT, SIGTERM and SIGHUP all stop the run the same way: in the loop they set the reason
    (that same cycle writes 0 V); before it they raise ``_Stopped`` so start-up ends at once.
    Only the main thread can install handlers; elsewhere (a test's thread) none are set."""
    def handler(signum: int, _frame: Any) -> None:
        why = STOP_SIGNALS.get(signum, f"signal {signum}")
        if state.get("reason") is None:
            state["reason"] = why
        if not state.get("in_loop"):
            raise _Stopped(why)

    old: dict[int, Any] = {}
    if threading.current_thread() is not threading.main_thread():
        return old
    for sig in STOP_SIGNALS:
        old[sig] = signal.signal(sig, handler)
    return old


def lateness_stats(lateness: np.ndarray, missed: np.ndarray, threshold: float) -> dict[str, float]:
    """Median, 99th percentile and maximum lateness (s), missed ticks and late cycles."""
    if lateness.size == 0:
        return {"cycles": 0.0, "median_s": math.nan, "p99_s": math.nan, "max_s": math.nan,
                "missed": 0.0, "late_cycles": 0.0}
    return {"cycles": float(lateness.size), "median_s": float(np.median(lateness)),
            "p99_s": float(np.percentile(lateness, 99)), "max_s": float(lateness.max()),
            "missed": float(missed.sum()), "late_cycles": float(np.sum(lateness > threshold))}


def repeatability(path: Path, channels: tuple[str, ...] = ("force", "shank_strain",
                                                           "hammer_angle", "key_dip")
                  ) -> dict[str, dict[str, float]]:
    """Trial-to-trial spread: RMS deviation of each trial from the mean trace, per channel."""
    run = runfile.read(path)
    trials = [t for t in run.trials if t.channels.get("time") is not None
              and t.channels["time"].size]
    if len(trials) < 2:
        return {}
    n = min(t.channels["time"].size for t in trials)
    out: dict[str, dict[str, float]] = {}
    for name in channels:
        if not all(name in t.channels for t in trials):
            continue
        traces = np.array([t.channels[name][:n] for t in trials])
        mean = traces.mean(axis=0)
        dev = np.sqrt(np.mean((traces - mean) ** 2, axis=1))
        span = float(np.ptp(mean)) or 1.0
        out[name] = {"rms_deviation": float(dev.max()), "range": float(np.ptp(mean)),
                     "relative": float(dev.max() / span)}
    return out


def tracking_error(path: Path, trial: int = 0, tail_s: float = 0.05) -> dict[str, float]:
    """How well the measured force followed the profile in a run file: maximum and RMS of
    |force(t) - profile(t)| from the profile's start to ``tail_s`` after its end, the
    maximum as % of the profile's peak (the thesis's tracking measure, unshifted)."""
    run_ = runfile.read(path)
    tr = run_.trials[trial]
    prof = run_.metadata["profile"]
    pt, pf = np.asarray(prof["time"], float), np.asarray(prof["force"], float)
    t, f = tr.channels["time"], tr.channels["force"]
    keep = (t >= 0) & (t <= pt[-1] + tail_s)
    err = np.abs(f[keep] - np.interp(t[keep], pt, pf))
    peak = float(pf.max())
    return {"max_error_pct": float(err.max() / peak * 100), "max_error_n": float(err.max()),
            "rms_error_n": float(np.sqrt(np.mean(err ** 2))), "peak_n": peak,
            "samples": int(keep.sum())}


FILE_OVERHEAD = 2 * 1024 * 1024  # bytes: metadata (config, profile, records) and HDF5 headers


def check_free_space(cfg: RigConfig, profile: profiles.Profile, trials: int,
                     folder: Path) -> int:
    """Refuse (one-line ValueError) a run whose file would not fit in ``folder``'s free space
    (the whole run's samples at ``bytes_per_sample``, twice: the file and its journal; the
    file's overhead and the margin the
    acquisition keeps free); the estimate in bytes."""
    from rig.loop.acquisition import SPACE_MARGIN, bytes_per_sample

    seconds = (cfg.loop.settle_s + profile.duration + cfg.loop.rest_s) * trials
    # the samples twice: in the run file and in its journal (rig.loop.journal)
    need = 2 * int(seconds * cfg.rates.acquisition_hz * bytes_per_sample(cfg)) \
        + FILE_OVERHEAD + SPACE_MARGIN
    probe = folder
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    free = shutil.disk_usage(probe).free
    if free < need:
        raise InputError(f"data_folder: {folder} has {free / 1e6:.1f} MB free; this run "
                         f"({trials} x {profile.name}, {seconds:.1f} s) needs about "
                         f"{need / 1e6:.1f} MB")
    return need


MAX_NAME = 200  # characters of a run file's name (file systems allow 255 bytes)


def _safe_name(name: str) -> str:
    """A profile name as a file-name part: only letters, digits, ``-``, ``_`` and ``.``
    (a name such as ``../../escaped`` becomes ``_.._escaped``: no separator survives, so the
    file stays in the data folder), cut to keep the whole name under ``MAX_NAME``."""
    clean = "".join(c if c.isalnum() or c in "-_." else "_" for c in name).strip(".") or "run"
    return clean[:MAX_NAME - 40]


def default_path(cfg: RigConfig, profile: profiles.Profile) -> Path:
    """``<data_folder>/<time>-<profile>.h5`` (the profile's name made safe); not created."""
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    return Path(cfg.data_folder) / f"{stamp}-{_safe_name(profile.name)}.h5"


def claim_path(cfg: RigConfig, profile: profiles.Profile, out: Path | None = None,
               *, force: bool = False) -> Path:
    """The run file's path, created empty and exclusively (O_CREAT | O_EXCL) so two runs never
    share a file: ``<data_folder>/<time>-<profile>.h5``, then ``...-2.h5``, ``-3`` ... when
    taken. ``out`` is the user's file: refused (one-line ValueError) when it exists unless
    ``force``, or when its name is too long."""
    try:
        return _claim(cfg, profile, out, force)
    except InputError:
        raise
    except OSError as exc:  # a read-only or unwritable folder, a file where a folder should be
        where = "--out" if out is not None else "data_folder"
        target = Path(out) if out is not None else Path(cfg.data_folder)
        raise InputError(f"{where}: cannot write {target}: "
                         f"{exc.strerror or exc}") from None


def _claim(cfg: RigConfig, profile: profiles.Profile, out: Path | None,
           force: bool) -> Path:
    if out is not None:
        path = Path(out)
        if path.is_dir():
            raise InputError(f"--out: {path} is a folder, expected a file (.h5)")
        if len(path.name) > MAX_NAME:
            raise InputError(f"--out: file name of {len(path.name)} characters is too long "
                             f"(at most {MAX_NAME})")
        if path.exists() and not force:
            raise InputError(f"--out: {path} exists; use --force to overwrite it")
        path.parent.mkdir(parents=True, exist_ok=True)
        if not force:
            _create_exclusive(path)
        else:  # (kept as it is until the run begins it; refused here when unwritable)
            os.close(os.open(path, os.O_WRONLY | os.O_CREAT, 0o644))
        return path
    first = default_path(cfg, profile)
    folder = first.parent
    folder.mkdir(parents=True, exist_ok=True)
    base = first.stem
    for n in range(1, 1000):
        path = folder / (f"{base}.h5" if n == 1 else f"{base}-{n}.h5")
        try:
            _create_exclusive(path)
        except FileExistsError:
            continue
        return path
    raise InputError(f"data_folder: no free run-file name for {base} in {folder}")


def _create_exclusive(path: Path) -> None:
    fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
    os.close(fd)


def learned_record(profile_path: Path, cfg: RigConfig) -> tuple[dict[str, Any], Path] | None:
    """The learned-feedforward record (rig.control.records) for this profile, rig and
    calibration, with its file; None when there is none (issue 18)."""
    from rig.control import records as learned_records

    prof = profiles.load(profile_path, force_limit=cfg.limits.max_force_n)
    return learned_records.find(cfg, prof, cal_records.embedded(cal_records.lookup(cfg), cfg))


def run(profile_path: Path | profiles.Profile, cfg: RigConfig, *, trials: int = 1,
        out: Path | None = None,
        lockstep: bool = False, controller: Controller | None = None,
        on_line: Callable[[str], None] | None = None,
        on_cycle: Callable[[CycleContext], None] | None = None,
        force: bool = False, learned: dict[str, Any] | None = None,
        on_trace: Callable[[str], None] | None = None) -> RunReport:
    """Run the profile ``trials`` times on the configured rig; write one run file.

    SIGINT, SIGTERM and SIGHUP stop it like Ctrl-C; any exception in the loop is an abort
    (its traceback goes to ``on_trace`` -- the CLI's stderr; default ``on_line`` -- and the
    file's ``abort_traceback`` metadata). A stop
    before the acquisition has started raises ``RunStopped`` (no run file is left).
    ``learned``: a learned-feedforward record (rig.control.records) whose table is the
    feedforward instead of the advance or the motor compensation. ``profile_path`` may be a
    built ``profiles.Profile`` (``rig measure touch``'s ramps), checked against the same
    limits."""
    say = on_line or (lambda s: None)
    journal.set_process("run")
    if trials < 1:
        raise InputError(f"trials: expected at least 1, got {trials}")
    if isinstance(profile_path, profiles.Profile):
        profile = profile_path
        if profile.peak > cfg.limits.max_force_n or profile.duration > cfg.limits.max_profile_s:
            raise InputError(f"profile: {profile.name} ({profile.peak:g} N, "
                             f"{profile.duration:g} s) is over the rig's limits.max_force_n or "
                             f"limits.max_profile_s")
    else:
        profile = profiles.load(profile_path, force_limit=cfg.limits.max_force_n,
                                max_duration=cfg.limits.max_profile_s)
    motor_torque.check_profile(profile, cfg.limits, cfg.loop.advance_s)
    check_drive_port(cfg)
    ctl = controller or load_controller(cfg.loop.controller)
    cals = cal_records.lookup(cfg)
    full_records = cal_records.embedded(cals, cfg)
    feedforward, compensation = motor_cal.demand_source(cfg, full_records)
    if hasattr(ctl, "design_from"):   # a controller designed from the drive model in use
        ctl.design_from(motor_cal.record_in_use(full_records), cfg.rates.control_hz,
                        cfg.limits.max_force_n)
    # ---- a learned feedforward table replaces the compensation ----
    if learned is not None:
        from rig.control import records as learned_records

        feedforward, compensation = learned_records.demand_source(learned)
    # ---- end of the learned feedforward ----
    stop_state: dict[str, Any] = {"reason": None, "in_loop": False}
    old_handlers = _install_stop_handlers(stop_state)
    try:
        check_free_space(cfg, profile, trials, Path(out).parent if out is not None
                         else Path(cfg.data_folder))
        path = claim_path(cfg, profile, out, force=force)
        try:
            return _run(profile, cfg, trials, path, lockstep, ctl, say, on_cycle, full_records,
                        cals, feedforward, compensation, stop_state, learned,
                        on_trace or say)
        except BaseException as exc:
            with contextlib.suppress(OSError):  # refused or stopped before the file was begun
                if path.is_file() and path.stat().st_size == 0:
                    path.unlink()
            if isinstance(exc, _Stopped):
                raise RunStopped(f"{exc} before the run started; no run file written") from None
            raise
    finally:
        for sig, old in old_handlers.items():
            signal.signal(sig, old)


class RunStopped(RigError, RuntimeError):
    """A stop signal arrived while the run was starting (nothing moved, no file kept)."""


def _run(profile: profiles.Profile, cfg: RigConfig, trials: int, path: Path, lockstep: bool,
         ctl: Controller, say: Callable[[str], None],
         on_cycle: Callable[[CycleContext], None] | None, full_records: list[dict[str, Any]],
         cals: Any, feedforward: Callable[[profiles.Profile, float], float],
         compensation: dict[str, Any], stop_state: dict[str, Any],
         learned: dict[str, Any] | None = None,
         trace: Callable[[str], None] | None = None) -> RunReport:
    hz = cfg.rates.control_hz
    dt = 1.0 / hz
    spc = cfg.rates.samples_per_cycle
    settle = int(round(cfg.loop.settle_s * hz))
    dur = int(math.ceil(profile.duration * hz - 1e-9)) + 1
    rest = int(round(cfg.loop.rest_s * hz))
    per_trial = settle + dur + rest
    total = per_trial * trials
    design = getattr(ctl, "design", None)   # how the controller was designed, if it says
    metadata: dict[str, Any] = {
        "rig_config": cfg.to_yaml(),
        "profile": {**profile.to_metadata(), "time": profile.time.tolist(),
                    "force": profile.force.tolist()},
        "calibrations": [r.to_dict() for r in cals.values()],
        "calibration_records": full_records,
        "run": {"trials": trials, "advance_s": compensation["lead_s"], "lockstep": lockstep,
                "compensation": compensation,
                "controller": getattr(ctl, "name", type(ctl).__name__),
                **({"controller_design": design} if isinstance(design, dict) else {}),
                "control_hz": hz, "acquisition_hz": cfg.rates.acquisition_hz,
                "backend": cfg.backend, "started": _dt.datetime.now(_dt.UTC).isoformat()},
    }
    bridge_spec = reader_calibration(cfg, full_records)
    metadata["run"]["bridges"] = {
        "lowpass_hz": {"load_cell": cfg.channels.load_cell.lowpass_hz,
                       "strain_gauge": cfg.channels.strain_gauge.lowpass_hz},
        **bridge_spec}
    if learned is not None:  # the learned-feedforward record in use, embedded whole
        metadata["learned_feedforward"] = learned
    touch_record = cal_records.newest_valid(records_folder(cfg), "touch", cfg)
    if touch_record is not None:  # the action's feel as last measured (rig measure touch)
        metadata["touch_record"] = touch_record[0]

    cpu = scheduling.loop_cpu(cfg, say)
    daq = open_daq(cfg, lockstep=lockstep, on_line=say)
    sim_drive = None
    ctx = mp.get_context("spawn")
    ctrl: Any = ctx.Queue()
    status_q: Any = ctx.Queue()
    proc: Any = None
    drive: Drive | None = None
    monitor: DriveMonitor | None = None
    rows = recovery.LoopRecords(trials, total, keep=int(recovery.KEEP_RECORDS_S * hz))
    reason: str | None = None
    last_tick = -1
    abort_tb: str | None = None
    sched = scheduling.LoopScheduling()
    disable_failed: str | None = None
    try:
        port, sim_drive = open_drive_port(cfg, daq)
        drive = Drive(cfg.drive, port)
        proc = ctx.Process(target=run_acquisition, name="rig-acquisition", args=(
            {**daq.reader_spec(), **bridge_spec}, cfg.model_dump(mode="json"),
            {k: r.to_dict() for k, r in cals.items()}, str(path), metadata, ctrl, status_q))
        say("starting the acquisition process ...")
        proc.start()
        _expect(status_q, proc, "ready", cfg.acquisition.start_timeout_s)
        say("enabling the drive and arming the acquisition ...")
        for k in range(trials):
            ctrl.put(("trial", k, k * per_trial * spc, (k * per_trial + settle) * spc))
        enable_at_zero(daq, drive, say)
        monitor = DriveMonitor(drive, cfg.drive.poll_period_s)
        monitor.start()
        daq.arm()
        ctrl.put(("go",))
        _expect(status_q, proc, "started", cfg.acquisition.start_timeout_s)
        say(f"running {profile.name} ({profile.duration:.3f} s, peak {profile.peak:g} N) x "
            f"{trials} on {cfg.backend} rig{' in lock-step' if daq_lockstep(daq) else ''}")

        stop_state["in_loop"] = True  # from here a stop signal sets the reason, never raises
        limiter = motor_torque.Limiter(cfg.limits, dt)
        scaling = motor_torque.TorqueScaling.from_config(cfg.drive_scaling,
                                                         cfg.channels.drive_output)
        lc = cals["load_cell"]
        streak = done = 0
        trial_now = -1
        # the real-time class only where there is a time to keep: a lock-step simulated rig
        # integrates the action in this thread as fast as it can, and at SCHED_FIFO it held a
        # core from the acquisition process that must drain its buffer ("the acquisition
        # process stopped reading" after 86 trials of a soak beside other real-time runs)
        sched.apply(cpu, 0 if daq_lockstep(daq) else cfg.loop.realtime_priority,
                    (monitor, sim_drive, ctrl), say, daq.helper_processes())
        while True:
            tick = daq.wait_for_tick()
            i = tick.index
            if i >= total:
                break
            k, local = divmod(i, per_trial)
            t = (local - settle) * dt
            late = tick.lateness_s > cfg.limits.late_threshold_s or tick.missed > 0
            streak = done + 1 if late else done   # the cycles before, and this one's wake-up
            if stop_state["reason"] is not None:
                reason = stop_state["reason"]
            elif monitor.fault:
                reason = monitor.fault
            elif not proc.is_alive():
                reason = f"the acquisition process died (exit code {proc.exitcode})"
            elif streak > cfg.limits.max_late_cycles_in_a_row:
                reason = (f"{streak} late cycles in a row (limit "
                          f"{cfg.limits.max_late_cycles_in_a_row}, lateness "
                          f"{tick.lateness_s * 1e3:.2f} ms)")
            if reason is not None:
                daq.write_volts(0.0)
                rows.add([t, i, 0.0, 0.0, 0.0, 0.0, 0.0, math.nan, tick.lateness_s,
                          tick.missed, k])
                last_tick = i
                break
            if k != trial_now:
                trial_now = k
                ctl.reset()
                limiter.reset(0.0)
                if k:
                    say(f"trial {k + 1} of {trials}")
            _, ratio = daq.feedback_ratio()
            measured = float(loadcell.to_newtons(ratio, lc.sensitivity, lc.offset))
            target = float(profile.at(t)) if t >= 0 else 0.0
            ff = feedforward(profile, t)
            if hasattr(ctl, "target_n"):   # a controller that compares with the profile
                ctl.target_n = target
            demand, limited = limiter(float(ctl(t, ff, measured)))
            volts = scaling.volts(demand)
            daq.write_volts(volts)
            last_tick = i
            lateness = daq.write_lateness(tick)   # at the write, on the rig's clock
            # late cycles in a row up to this one: a late wake-up, missed ticks or a late
            # write (the last is checked at the next cycle's top)
            done = done + 1 if late or lateness > cfg.limits.late_threshold_s else 0
            rows.add([t, i, target, ff, demand, volts, float(limited), measured,
                         lateness, tick.missed, k])
            if on_cycle is not None:
                on_cycle(CycleContext(i, k, t, proc.pid, sim_drive, daq))
            if rows.unsent() >= 50:
                rows.send(ctrl)
    except _Abort as exc:
        reason = str(exc)
    except (KeyboardInterrupt, _Stopped):
        reason = stop_state["reason"] or "interrupted (Ctrl-C)"
        if stop_state["in_loop"] is False and proc is None:
            stop_state["in_loop"] = True
            _safe(lambda: daq.write_volts(0.0))
            _safe(daq.close)
            if sim_drive is not None:
                _safe(sim_drive.close)
            if drive is not None:
                _safe(drive.close)
            raise _Stopped(reason) from None
    except (DriveError, OSError) as exc:
        reason = f"{type(exc).__name__}: {exc}"
    except Exception as exc:  # anything else (a user controller's bug): abort, keep the trace
        reason = f"{type(exc).__name__}: {exc}"
        abort_tb = traceback.format_exc()
        for ln in abort_tb.rstrip().splitlines():
            (trace or say)(ln)
    finally:
        stop_state["in_loop"] = True
        _safe(lambda: daq.write_volts(0.0))
        sched.undo()
        if drive is not None and drive.enabled:
            disable_failed = _disable(drive, trace or say)
        if monitor is not None:
            monitor.stop()
            if monitor.link_errors and monitor.fault is None:
                say(f"note: {monitor.link_errors} drive status poll(s) failed on "
                    f"the link and the next one answered; check the drive's cable "
                    f"if this repeats")

    status = "complete" if reason is None else f"aborted: {reason}"
    stats = lateness_stats(rows.lateness[:rows.n], rows.missed[:rows.n],
                           cfg.limits.late_threshold_s)
    stats["realtime_priority"] = float(cfg.loop.realtime_priority if sched.realtime else 0)
    stats["cpu"] = float(cpu) if cpu is not None and sched.pinned is not None else -1.0
    stats["drive_link_errors"] = float(monitor.link_errors if monitor is not None else 0)
    try:
        # only the trial that was cut is aborted: those before it ran to their end
        done_trials = trials if reason is None else max(0, last_tick) // per_trial
        fin = recovery.finish(proc, ctrl, status_q, rows, trials, status, stats,
                              (last_tick + 1) * spc, path, cfg, abort_tb, done_trials,
                              {"drive_disable_failed": disable_failed} if disable_failed
                              else None)
    finally:
        if reason is not None:  # (a simulated plant behind the loop: not its whole backlog)
            _safe(daq.stop_at_once)
        daq.close()
        if drive is not None:
            _safe(drive.close)
        if sim_drive is not None:
            sim_drive.close()
    if fin.left is not None:  # a full disk: the journal holds the run for `rig recover`
        return RunReport(path, fin.left, last_tick + 1, stats, None, {})
    samples = fin.samples
    read_back = runfile.read(path)
    final = read_back.status
    # no repeatability figure over truncated trials: only a complete run gets one
    rep = repeatability(path) if trials > 1 and final == "complete" else {}
    found = found_events(read_back, say)
    if rep or found:
        try:
            _add_findings(path, final, rep, found)
        except Exception as exc:
            if not journal.is_disk_full(exc):
                raise
            left = recovery.after_failed_write(
                path, f"aborted: disk full ({path.parent}) while adding the events found")
            return RunReport(path, left, last_tick + 1, stats, None, {})
    # the run file is whole: its journal is no longer needed
    with contextlib.suppress(OSError):
        journal.remove(path)
    return RunReport(path, final, last_tick + 1, stats, samples, rep)


def _add_findings(path: Path, final: str, rep: dict[str, Any],
                  found: dict[int, dict[str, float]]) -> None:
    """The repeatability and the events found, added to the closed run file."""
    from rig.loop.acquisition import SPACE_MARGIN

    if shutil.disk_usage(path.parent).free < SPACE_MARGIN:
        raise OSError(errno.ENOSPC, f"No space left on device (under {SPACE_MARGIN // 1024} "
                      f"KB free in {path.parent})")
    journal.fault_point("HDF5 reopen")
    w = runfile.RunWriter.reopen(path)
    try:
        if rep:
            w.add_metadata("repeatability", rep)
        for k, ev in found.items():
            w.trial(k).write_events(ev, EVENT_DOCS, source=events.SOURCE, methods=events.METHODS)
        journal.fault_point("HDF5 events")
    except BaseException:
        recovery.FAILED_HANDLES.append(w)  # no close, no teardown of a failed HDF5 handle
        raise
    w.close(final)


def found_events(run: runfile.Run, say: Callable[[str], None]) -> dict[int, dict[str, float]]:
    """The events found in each trial's measured channels (rig.analysis.events), by trial
    index; a trial whose search fails is left without events, with a warning."""
    out: dict[int, dict[str, float]] = {}
    for k, tr in enumerate(run.trials):
        if "time" not in tr.channels:
            continue
        try:
            ev = events.find(tr.channels["time"], tr.channels)
        except (ValueError, FloatingPointError, np.linalg.LinAlgError) as exc:
            say(f"warning: trial {k}: its events were not found ({exc})")
            continue
        if ev:
            out[k] = ev
    return out


def daq_lockstep(daq: Daq) -> bool:
    return bool(getattr(daq, "lockstep", False))


def _disable(drive: Drive, report: Callable[[str], None]) -> str | None:
    """Disable the drive at the run's end; a failure is reported (``report``: the CLI's
    stderr) and returned for the run file's metadata (``drive_disable_failed``), and the
    cleanup goes on (0 V is already out)."""
    try:
        drive.disable()
    except Exception as exc:  # noqa: BLE001 - reported and recorded; the cleanup goes on
        why = f"{type(exc).__name__}: {exc}"
        report(f"WARNING: the drive did not take its disable command ({why}); the demand is "
               f"0 V: switch the drive off at its panel")
        return why
    return None


def _safe(fn: Callable[[], Any]) -> None:
    """Run a cleanup step; cleanup must go on (the drive and the file matter more)."""
    with contextlib.suppress(Exception):
        fn()


def _expect(status_q: Any, proc: Any, what: str, timeout: float) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            msg = status_q.get(timeout=0.1)
        except queue.Empty:
            if not proc.is_alive():
                raise _Abort(f"the acquisition process died while starting (exit code "
                             f"{proc.exitcode})") from None
            continue
        if msg[0] == what:
            return
        if msg[0] == "error":
            first = msg[1].splitlines()[0]
            raise _Abort(first if first.startswith("disk full") else f"acquisition: {first}")
    raise _Abort(f"the acquisition process did not report {what!r} within {timeout} s")
