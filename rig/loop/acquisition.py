"""The acquisition process: 2 kHz samples from the cards into the run file.

A separate OS process (multiprocessing, spawn) that owns the run file. It
reads the load cell, the strain bridge and the encoders on one sample clock
in blocks (``acquisition.read_period_s``), checks the sample counter for
continuity, converts raw values to SI with the calibrations in use, and
appends raw and calibrated channels to the current trial -- to the run file's journal
first (rig.loop.journal), then to the HDF5 file -- flushing at least every
``acquisition.flush_period_s`` (<= 0.5 s). The loop's 500 Hz records
arrive over a queue and go to ``commands/``. A card overflow or a gap stops
acquisition with a clear message: the file is closed ``aborted: ...`` and the
process exits with code 1. SIGINT, SIGHUP and SIGTERM are ignored here: the run's
process decides. This process is also the supervisor of the run's process
(rig.loop.supervisor): if that dies, it zeroes the demand, disables the drive, closes the
file ``aborted: the controller process ... died`` and removes the shared blocks the
dead process owned. Before each flush it checks the free space (``DiskFull``:
``aborted: disk full ...``); an ENOSPC at any write ends the same way, and after a
failed HDF5 write nothing more goes to that file (the run's process rebuilds it from
the journal). The process always ends with ``os._exit`` once its answer is sent.

Messages from the run (queue ``ctrl``):
    ("go",)                                      start the sample clock
    ("trial", k, record_start_sample, profile_start_sample)
    ("commands", k, {name: array})
    ("stop", end_sample, status, metadata, {k: trial attrs})
Messages to the run (queue ``status``): ("ready",), ("started",),
("done", n_samples), ("error", message).
"""

from __future__ import annotations

import contextlib
import functools
import os
import queue
import shutil
import signal
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rig.daq import DaqFault
from rig.errors import InputError, RigError
from rig.inputs.config import RigConfig, from_mapping
from rig.loop import journal
from rig.loop.backends import open_reader, serial_drive
from rig.loop.supervisor import ControllerWatch, make_safe
from rig.recordings import runfile
from rig.sensors import table as sensor_table
from rig.sensors.table import COMMAND_DOCS, COMMAND_UNITS, CalRecord

ABORT_DRAIN_S = 0.3  # s: the wait for the samples of an aborted run's last ticks (a card
# delivers them within a read period; a simulated plant behind the loop is stopped)
SPACE_MARGIN = 512 * 1024  # bytes kept free: closing the file, the loop's last records


class DiskFull(RigError, OSError):
    """Too little free space left to write the next block safely."""


def bytes_per_sample(cfg: RigConfig) -> int:
    """Upper estimate of the run file's bytes per 2 kHz sample: raw and calibrated channels
    (time, sample counter, raw and SI per sensor) as float64, plus the loop's records
    (10 float64 per control period)."""
    channels = 2 + 2 * len(sensor_table.sensors(cfg))
    per_tick = 8 * len(COMMAND_UNITS) / cfg.rates.samples_per_cycle
    return int(8 * channels + per_tick) + 8


@dataclass
class _Trial:
    index: int
    record_start: int
    profile_start: int
    rows: list[np.ndarray] = field(default_factory=list)
    commands: list[dict[str, np.ndarray]] = field(default_factory=list)
    writer: runfile.TrialWriter | None = None
    announced: bool = False   # its attributes are in the journal


class Acquisition:
    """The acquisition loop (runs inside the acquisition process; testable in-process)."""

    def __init__(self, cfg: RigConfig, cals: dict[str, CalRecord], writer: runfile.RunWriter,
                 ctrl: Any, status: Any, jw: journal.JournalWriter | None = None) -> None:
        self.cfg, self.cals, self.writer = cfg, cals, writer
        self.journal = jw
        self.h5_failed: BaseException | None = None  # a write to the HDF5 file failed
        self.journaled = 0   # samples whose journal record is whole (flushed for good)
        self.pending = 0     # samples taken since the last flush
        self.ctrl, self.status = ctrl, status
        self.trials: list[_Trial] = []
        self.next_sample = 0
        self.units = sensor_table.channel_units(cfg)
        self.docs = sensor_table.channel_docs(cfg)
        self.sample_col = sensor_table.column(cfg, sensor_table.SAMPLE)
        self.feedback_col = sensor_table.column(cfg, sensor_table.FEEDBACK)
        self.stop: tuple[Any, ...] | None = None

    # -- messages --------------------------------------------------------------------
    def handle(self, msg: tuple[Any, ...]) -> None:
        kind = msg[0]
        if kind == "trial":
            _, k, rec, prof = msg
            self.trials.append(_Trial(int(k), int(rec), int(prof)))
        elif kind == "commands":
            _, k, data = msg
            self._trial(int(k)).commands.append(data)
        elif kind == "stop":
            self.stop = msg
        else:
            raise InputError(f"message: unknown kind {kind!r}")

    def _trial(self, k: int) -> _Trial:
        for tr in self.trials:
            if tr.index == k:
                return tr
        raise RuntimeError(f"commands for trial {k} before the trial was announced")

    def poll(self) -> None:
        while True:
            try:
                msg = self.ctrl.get_nowait()
            except queue.Empty:
                return
            self.handle(msg)

    # -- samples -----------------------------------------------------------------------
    def take(self, rows: np.ndarray) -> None:
        """Check counter continuity and file rows under their trials."""
        if rows.shape[0] == 0:
            return
        counter = rows[:, self.sample_col]
        if counter[0] != self.next_sample or np.any(np.diff(counter) != 1):
            bad = self.next_sample if counter[0] != self.next_sample else int(
                counter[np.flatnonzero(np.diff(counter) != 1)[0]]) + 1
            raise DaqFault(f"gap in the sample counter at sample {bad}")
        self.next_sample = int(counter[-1]) + 1
        self.pending += rows.shape[0]
        if not self.trials:
            raise DaqFault("samples arrived before the first trial was announced")
        starts = [t.record_start for t in self.trials]
        which = np.searchsorted(starts, counter, side="right") - 1
        for i in np.unique(which):
            if i < 0:
                raise DaqFault(f"sample {int(counter[0])} precedes the first trial")
            self.trials[int(i)].rows.append(rows[which == i])

    def write_pending(self) -> None:
        """Write what arrived since the last flush: to the journal first (each block a whole
        record, rig.loop.journal), then to the HDF5 file, then flush it. A failed HDF5 write is
        kept in ``h5_failed``: nothing more goes to that file (the journal has it all)."""
        self.check_space()
        self.pending = 0
        blocks: list[tuple[_Trial, str, dict[str, np.ndarray], Any, Any, int]] = []
        new_trials = []
        for tr in self.trials:
            if tr.writer is None and not tr.announced and (tr.rows or tr.commands):
                new_trials.append(tr)
            if tr.rows:
                block = np.vstack(tr.rows)
                tr.rows.clear()
                data = sensor_table.convert(block, self.cfg, self.cals, tr.profile_start)
                blocks.append((tr, "channels", data, self.units, self.docs, block.shape[0]))
            for cmd in tr.commands:
                blocks.append((tr, "commands", cmd, COMMAND_UNITS, COMMAND_DOCS, 0))
            tr.commands.clear()
        if self.journal is not None:
            for tr in new_trials:
                self.journal.trial(tr.index, self._trial_attrs(tr))
                tr.announced = True
            for tr, section, data, units, docs, rows in blocks:
                self.journal.append(tr.index, section, data, units, docs)
                self.journaled += rows
            self.journal.sync()   # on the disk: a power failure keeps them too
        if self.h5_failed is not None:
            return
        try:
            for tr in new_trials:
                tr.announced = True
            for tr, section, data, units, docs, _ in blocks:
                if tr.writer is None:
                    tr.writer = self.writer.trial(tr.index)
                    tr.writer.set_attrs(**self._trial_attrs(tr))
                journal.fault_point("HDF5 append")
                tr.writer.append(section, data, units, docs)
            journal.fault_point("HDF5 flush")
            self.writer.flush()
            # the groups of trials before the one being written are closed (each open HDF5
            # object pins its header in the metadata cache: memory growing with the trials)
            current = max((i for i, tr in enumerate(self.trials) if tr.writer is not None),
                          default=0)
            for tr in self.trials[:current]:
                tr.writer = None
        except Exception as exc:
            self.h5_failed = exc
            raise

    def _trial_attrs(self, tr: _Trial) -> dict[str, Any]:
        return {"t0": tr.profile_start / self.cfg.rates.acquisition_hz,
                "record_start_sample": tr.record_start,
                "profile_start_sample": tr.profile_start}

    def check_space(self) -> None:
        """DiskFull before a write that could meet a full disk: HDF5 after ENOSPC may leave a
        half-written block (or an unreadable file), so the acquisition stops while
        ``SPACE_MARGIN`` bytes are still free for closing the file and the loop's records."""
        rows = sum(r.shape[0] for tr in self.trials for r in tr.rows)
        cmds = sum(next(iter(c.values())).size for tr in self.trials for c in tr.commands
                   if c)
        # (twice: the journal and the HDF5 file)
        need = 2 * (rows * bytes_per_sample(self.cfg) + cmds * 8 * len(COMMAND_UNITS))
        free = shutil.disk_usage(self.writer.path.parent).free
        if free < need + SPACE_MARGIN:
            raise DiskFull(f"disk full ({free // 1024} KB free in {self.writer.path.parent} "
                           f"at sample {self.next_sample}; the {self.journaled} samples "
                           f"flushed before it are kept)")

    def finish(self, status: str, metadata: dict[str, Any], trial_attrs: dict[int, Any]) -> None:
        self.write_pending()
        if self.journal is not None:
            for name, value in metadata.items():
                self.journal.metadata(name, value)
            for k, attrs in trial_attrs.items():
                self.journal.trial(int(k), attrs)
            self.journal.close_record(status)
        for name, value in metadata.items():
            self.writer.add_metadata(name, value)
        for k, attrs in trial_attrs.items():
            self.writer.trial(int(k)).set_attrs(**attrs)
        journal.fault_point("HDF5 close")
        self.writer.close(status)


class _ControllerDied(RigError):
    def __init__(self, watch: ControllerWatch) -> None:
        super().__init__(f"the controller process (pid {watch.pid}) died; the supervisor zeroed "
                         f"the demand and disabled the drive")
        self.watch = watch


def _drain(acq: Acquisition, reader: Any, watch: ControllerWatch, quiet_s: float = 0.1,
           limit_s: float = 2.0) -> None:
    """Take the rows still in the card buffer after the loop's death (until none come for
    ``quiet_s``); a fault while draining keeps what was taken."""
    watch.safe.wait(timeout=limit_s)
    end = time.monotonic() + limit_s
    quiet = time.monotonic() + quiet_s
    try:
        acq.poll()
        while time.monotonic() < min(end, quiet):
            rows = reader.read(0.01)
            if rows.shape[0]:
                acq.take(rows)
                quiet = time.monotonic() + quiet_s
    except (DaqFault, OSError, ValueError, EOFError):
        pass


def run_acquisition(spec: dict[str, Any], cfg_data: dict[str, Any], cals: dict[str, Any],
                    path: str, metadata: dict[str, Any], ctrl: Any, status: Any,
                    controller_pid: int | None = None) -> None:
    """Entry point of the acquisition process; it supervises ``controller_pid`` (default its
    parent, the loop's process): see rig.loop.supervisor. It ends with ``os._exit`` once the file
    is closed and the answer sent: the run's process waits for that answer, not for an
    interpreter's teardown (numba and h5py loaded: about a second, several under load), and
    after a failed HDF5 write h5py's teardown of its handles is skipped."""
    code = _acquire(spec, cfg_data, cals, path, metadata, ctrl, status, controller_pid)
    with contextlib.suppress(Exception):
        status.close()
        status.join_thread()
    os._exit(code)


def _acquire(spec: dict[str, Any], cfg_data: dict[str, Any], cals: dict[str, Any],
             path: str, metadata: dict[str, Any], ctrl: Any, status: Any,
             controller_pid: int | None) -> int:
    """The acquisition (``run_acquisition``); its exit code."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # SIGTERM/SIGHUP to the whole group (a closed terminal) must not kill the file's writer:
    # the run's process decides, and if it dies the supervisor closes the file
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    controller_pid = controller_pid or os.getppid()
    journal.set_process("acquisition")
    journal.DiskFullEchoes().install()  # h5py's frees after ENOSPC: one "disk full" line
    cfg = from_mapping(cfg_data)
    records = {k: CalRecord(**v) for k, v in cals.items()}
    code = 0
    reader = None
    watch: ControllerWatch | None = None
    writer: runfile.RunWriter | None = None
    acq: Acquisition | None = None
    try:
        writer = runfile.RunWriter(Path(path), "measured", metadata, crash_safe=True)
        jw = journal.JournalWriter.create(path)
        acq = Acquisition(cfg, records, writer, ctrl, status, jw)
        jw.begin(Path(path), "measured", dict(writer.file.attrs), metadata)
        reader = open_reader(spec)
        watch = ControllerWatch(controller_pid, functools.partial(
            make_safe, reader, cfg, serial_drive=serial_drive(cfg)))
        watch.start()
        status.put(("ready",))
        start_end = time.monotonic() + cfg.acquisition.start_timeout_s
        while True:
            if watch.dead.is_set():
                raise _ControllerDied(watch)
            try:
                msg = ctrl.get(timeout=0.05)
            except queue.Empty:
                if time.monotonic() > start_end:
                    raise
                continue
            if msg[0] == "go":
                break
            acq.handle(msg)
            if acq.stop is not None:  # the run ended before the clock started: close at once
                _, _, final_status, meta, tattrs = acq.stop
                acq.finish(final_status, meta, tattrs)
                status.put(("done", 0))
                return 0
        reader.start()
        status.put(("started",))
        period = cfg.acquisition.read_period_s
        flush_rows = int(cfg.acquisition.flush_period_s * cfg.rates.acquisition_hz)
        last_flush = time.monotonic()
        drain_until = None
        while True:
            if watch.dead.is_set():
                raise _ControllerDied(watch)
            acq.poll()
            rows = reader.read(period)
            acq.take(rows)
            if rows.shape[0]:
                reader.publish_feedback(int(rows[-1, acq.sample_col]),
                                        float(rows[-1, acq.feedback_col]))
            now = time.monotonic()
            # every flush_period_s, and as soon as that many samples wait (a process starved
            # on a loaded machine reads them in one go): at most that much lost to a crash
            if now - last_flush >= cfg.acquisition.flush_period_s or acq.pending >= flush_rows:
                acq.write_pending()
                last_flush = now
            if acq.stop is not None:
                end_sample = int(acq.stop[1])
                # a complete run's every sample; an abort's, while they come quickly (a
                # simulated plant behind the loop is then stopped: rig.daq.stop_at_once)
                drain_until = drain_until or now + (
                    5.0 if acq.stop[2] == "complete" else ABORT_DRAIN_S)
                if acq.next_sample >= end_sample or now > drain_until:
                    break
        assert acq.stop is not None
        _, _, final_status, meta, tattrs = acq.stop
        if acq.next_sample < int(acq.stop[1]):
            final_status = (f"aborted: acquisition got {acq.next_sample} of {acq.stop[1]} "
                            f"samples" if final_status == "complete" else final_status)
            meta = {**meta, "acquisition_shortfall": {
                "samples": acq.next_sample, "of": int(acq.stop[1]),
                "why": "the samples of the last ticks had not come within "
                       f"{ABORT_DRAIN_S} s of the abort (a simulated rig behind the loop)"}}
        acq.finish(final_status, meta, tattrs)
        status.put(("done", acq.next_sample))
    except _ControllerDied as exc:
        code = 1
        why = str(exc)
        if reader is not None and acq is not None:  # every sample the card buffered
            _drain(acq, reader, exc.watch)
        if exc.watch.error:
            why += f" (making the rig safe failed: {exc.watch.error})"
        if _abort(acq, writer, f"aborted: {why}"):
            # nobody else will finish the file, and it is whole: its journal is not needed
            with contextlib.suppress(OSError):
                journal.remove(path)
    except Exception as exc:  # a full disk, a card fault, anything: the reason, exit 1
        code = 1
        full = isinstance(exc, DiskFull) or journal.is_disk_full(exc)
        if full:
            msg = str(exc) if isinstance(exc, DiskFull) else _disk_full_message(acq, path)
        elif isinstance(exc, DaqFault):
            msg = str(exc)
        else:
            msg = f"acquisition failed: {type(exc).__name__}: {str(exc).splitlines()[0]}"
        _abort(acq, writer, f"aborted: {msg}", write=not full)
        if not full and not isinstance(exc, DaqFault | OSError):
            msg += "\n" + traceback.format_exc(limit=3)
        status.put(("error", msg))
    finally:
        if watch is not None:
            orphaned = watch.dead.is_set()
            watch.stop()
        if reader is not None:
            reader.close()
            if watch is not None and orphaned:
                reader.release_orphaned()
    return code


def _disk_full_message(acq: Acquisition | None, path: str) -> str:
    where = Path(path).parent
    if acq is None:
        return f"disk full (no space left in {where} to begin the run file)"
    return (f"disk full (no space left in {where} at sample {acq.next_sample}; the "
            f"{acq.journaled} samples flushed before it are kept)")


def _abort(acq: Acquisition | None, writer: runfile.RunWriter | None, status: str,
           write: bool = True) -> bool:
    """Write what is pending (unless ``write`` is False: the disk is full) and close the
    journal and the file ``status``. Nothing more goes to an HDF5 file whose write failed:
    HDF5 after a failed write may fail again, or crash, as its handles are closed. True
    when everything was written and the file closed."""
    closed = False
    try:
        if acq is not None and write:
            acq.poll()
            acq.write_pending()
    except Exception as exc:  # (the journal has what was flushed)
        write = False
        if acq is not None and acq.h5_failed is None and journal.is_disk_full(exc):
            acq.h5_failed = exc
    finally:
        if acq is not None and acq.journal is not None:
            with contextlib.suppress(OSError):
                acq.journal.close_record(status)
        if writer is not None and (acq is None or acq.h5_failed is None):
            with contextlib.suppress(Exception):
                journal.fault_point("HDF5 close")
                writer.close(status)
                closed = write
    return closed
