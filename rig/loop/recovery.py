"""The run's side of the acquisition process at the end: the loop's records, stopping the
process, and recovering the run file when it died.

The loop's records (``LoopRecords``) go to the acquisition process in batches; the last
``KEEP_RECORDS_S`` of them stay in the run's process, so that when the acquisition process
died (or failed) ``finish`` can close the file itself: the records it had not written,
the run's metadata and an ``aborted: ...`` status naming why.
"""

from __future__ import annotations

import contextlib
import queue
import shutil
import signal
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rig.inputs.config import RigConfig
from rig.loop import journal
from rig.recordings import runfile
from rig.sensors.table import COMMAND_DOCS, COMMAND_UNITS

COLUMNS = tuple(COMMAND_UNITS)  # a loop record's columns (the run file's commands/) ...
TRIAL = len(COLUMNS)            # ... and then the index of its trial
LATENESS, MISSED = COLUMNS.index("lateness"), COLUMNS.index("missed")


ACQUISITION_EXIT_S = 1.0  # s: the acquisition's exit after it closed the file and said so
KEEP_RECORDS_S = 10.0  # s of the loop's records kept after sending (the recovery's margin)


class LoopRecords:
    """The loop's records (one row per cycle: the ``COLUMNS`` and the trial), sent to the
    acquisition process in batches. Memory stays flat over long runs: only the last ``keep``
    rows are kept once sent (enough to refill what a dead acquisition had not flushed), and
    lateness and missed ticks go into arrays sized for the run up front."""

    def __init__(self, trials: int, total: int, keep: int) -> None:
        self.rows: list[list[float]] = []
        self.base = 0                 # rows dropped from the front (all sent)
        self.sent = [0] * trials      # rows of trial k sent
        self.made = [0] * trials      # rows of trial k recorded
        self.keep = max(keep, 1)
        # 8 bytes a cycle (float32 lateness to well under a microsecond, uint32 missed
        # ticks): 1.4 MB for 200 forte trials, touched as the run goes on
        self.lateness = np.zeros(total + 1, np.float32)
        self.missed = np.zeros(total + 1, np.uint32)
        self.n = 0

    def add(self, row: list[float]) -> None:
        self.rows.append(row)
        self.made[int(row[TRIAL])] += 1
        self.lateness[self.n] = row[LATENESS]
        self.missed[self.n] = row[MISSED]
        self.n += 1

    def unsent(self) -> int:
        return self.base + len(self.rows) - sum(self.sent)

    def send(self, ctrl: Any) -> None:
        """Send the rows not yet sent, per trial; then drop all but the last ``keep``."""
        done = sum(self.sent) - self.base
        arr = np.array(self.rows[done:], dtype=float).reshape(-1, TRIAL + 1)
        for k in np.unique(arr[:, TRIAL]).astype(int):
            part = arr[arr[:, TRIAL] == k]
            ctrl.put(("commands", int(k), {c: part[:, j] for j, c in enumerate(COLUMNS)}))
            self.sent[k] += part.shape[0]
        excess = len(self.rows) - self.keep
        if excess > 0:
            del self.rows[:excess]
            self.base += excess

    def trial_rows(self, k: int) -> tuple[int, np.ndarray]:
        """(index within trial k of its first kept row, the kept rows of trial k)."""
        arr = np.array(self.rows, dtype=float).reshape(-1, TRIAL + 1)
        part = arr[arr[:, TRIAL] == k]
        return self.made[k] - part.shape[0], part


@dataclass
class Finished:
    """How the acquisition ended: its sample count when it closed the file itself; ``left``,
    the run's final status when the run file could not be finished (a full disk: the journal
    is left for ``rig recover``); ``recovered``, samples of a file rebuilt from the journal."""

    samples: int | None
    left: str | None = None
    recovered: int | None = None


def finish(proc: Any, ctrl: Any, status_q: Any, rows: LoopRecords, trials: int, status: str,
            stats: dict[str, float], end_sample: int, path: Path, cfg: RigConfig,
            abort_tb: str | None = None, done_trials: int = 0,
            extra_meta: dict[str, Any] | None = None) -> Finished:
    """Stop the acquisition process and see the file closed; recover it if the process died.
    ``extra_meta``: more of the run's metadata from the loop's side (a failed drive disable)."""
    meta: dict[str, Any] = {"loop_lateness": stats, **(extra_meta or {})}
    if abort_tb is not None:
        meta["abort_traceback"] = abort_tb
    tattrs: dict[int, dict[str, Any]] = {k: {"status": "complete"} for k in range(done_trials)}
    if proc is None:
        return Finished(None)
    msgs = []
    if proc.is_alive():
        rows.send(ctrl)
        ctrl.put(("stop", end_sample, status, meta, tattrs))
        # wait for its answer (the file is closed by then), not for its interpreter's exit
        end = time.monotonic() + 30.0
        while time.monotonic() < end:
            try:
                msgs.append(status_q.get(timeout=0.02))
            except queue.Empty:
                if not proc.is_alive():
                    break
                continue
            if msgs[-1][0] in ("done", "error"):
                break
        proc.join(timeout=ACQUISITION_EXIT_S)
    while True:
        try:
            msgs.append(status_q.get(timeout=0.05))
        except queue.Empty:
            break
    done = [m for m in msgs if m[0] == "done"]
    errors = [m[1].splitlines()[0] for m in msgs if m[0] == "error"]
    if proc.is_alive():
        proc.kill()
        proc.join(timeout=5.0)
        if not done:
            errors.append("the acquisition process did not stop; killed")
    # the acquisition is gone: what is still in the command queue's pipe has no reader, and
    # joining its feeder thread at exit would hang the run's process for good
    ctrl.cancel_join_thread()
    ctrl.close()
    status_q.close()
    if done and proc.exitcode in (0, -signal.SIGKILL):  # (killed while exiting, file closed)
        return Finished(int(done[0][1]))
    # the acquisition process died or failed: finish the file here
    why = errors[0] if errors else f"the acquisition process died (exit code {proc.exitcode})"
    final = status if status.startswith("aborted") else f"aborted: {why}"
    if errors and "acquisition process died" in status:
        final = f"aborted: {errors[0]}"
    if not path.is_file():
        return Finished(None)
    jpath = journal.journal_path(path)
    if jpath.is_file():
        sc = journal.scan(jpath)
        if sc.records and sc.records[0][0].get("k") == "begin":
            return _finish_from_journal(path, rows, trials, final, meta, tattrs, errors)
        journal.remove(path)  # (it failed before its first record: nothing in it)
    try:  # (the acquisition failed before it began the journal: the file holds no samples)
        _finish_in_place(path, rows, trials, final, meta, tattrs, errors)
    except Exception as exc:
        if not journal.is_disk_full(exc):
            raise
        return Finished(None, f"{final}; the run file {path} may be unreadable: it holds no "
                              f"samples (disk full as it began)")
    return Finished(None)


def _finish_in_place(path: Path, rows: LoopRecords, trials: int, final: str,
                     meta: dict[str, Any], tattrs: dict[int, dict[str, Any]],
                     errors: list[str]) -> None:
    journal.fault_point("HDF5 reopen")
    w = runfile.RunWriter.reopen(path)
    for k in range(trials):
        first, part = rows.trial_rows(k)
        if not part.shape[0]:
            continue
        grp = f"trial_{k:03d}"
        have = 0
        if grp in w.file and "commands" in w.file[grp] and "time" in w.file[grp]["commands"]:
            have = int(w.file[grp]["commands"]["time"].shape[0])
        tw = w.trial(k)
        if have < first + part.shape[0]:  # (a gap if the file lacks rows no longer kept)
            tw.append("commands", {c: part[max(0, have - first):, j]
                                   for j, c in enumerate(COLUMNS)}, COMMAND_UNITS, COMMAND_DOCS)
    for name, value in meta.items():
        w.add_metadata(name, value)
    for k, attrs in tattrs.items():
        if f"trial_{k:03d}" in w.file:
            w.trial(k).set_attrs(**attrs)
    if errors and final != f"aborted: {errors[0]}":
        w.add_metadata("acquisition_error", errors[0])
    w.close(final)


def _finish_from_journal(path: Path, rows: LoopRecords, trials: int, final: str,
                         meta: dict[str, Any], tattrs: dict[int, dict[str, Any]],
                         errors: list[str]) -> Finished:
    """The acquisition died or failed and left its journal: add the loop's records it had not
    written, the metadata and the final status to the journal, then rebuild the run file
    from it (rig.loop.journal.recover) when the disk has room; else leave the journal (and the
    HDF5 file as the acquisition left it) for ``rig recover``. The HDF5 file is never written
    here: after a failed write (a full disk) HDF5 may fail again or crash."""
    jpath = journal.journal_path(path)
    try:
        have = _journaled_commands(jpath)
        jw = journal.JournalWriter.append_to(path)
        try:
            for k in range(trials):
                first, part = rows.trial_rows(k)
                start = max(0, have.get(k, 0) - first)
                if part.shape[0] > start:
                    jw.append(k, "commands", {c: part[start:, j] for j, c in enumerate(COLUMNS)},
                              COMMAND_UNITS, COMMAND_DOCS)
            for name, value in meta.items():
                jw.metadata(name, value)
            for k, attrs in tattrs.items():
                jw.trial(k, attrs)
            if errors and final != f"aborted: {errors[0]}":
                jw.metadata("acquisition_error", errors[0])
            jw.close_record(final)
        finally:
            jw.close()
    except OSError:  # a full disk: the journal keeps what it had
        pass
    size = jpath.stat().st_size if jpath.is_file() else 0
    free = shutil.disk_usage(path.parent).free
    if free < REBUILD_FACTOR * size + REBUILD_MARGIN:
        return Finished(None, _left(final, path))
    try:
        rec = journal.recover(path)
    except Exception as exc:  # noqa: BLE001 - the journal stays; say how to finish
        if not journal.is_disk_full(exc):
            raise
        return Finished(None, _left(final, path))
    return Finished(None, recovered=rec.samples)


FAILED_HANDLES: list[Any] = []  # HDF5 handles whose write failed: kept, never closed


def after_failed_write(path: Path, status: str) -> str:
    """A write to a closed run file failed (a full disk): the file may be damaged, so it is
    rebuilt from its journal with ``status`` when there is room; the final status (with how
    to recover when the journal had to be left)."""
    with contextlib.suppress(OSError):
        jw = journal.JournalWriter.append_to(path)
        try:
            jw.close_record(status)
        finally:
            jw.close()
    jpath = journal.journal_path(path)
    size = jpath.stat().st_size if jpath.is_file() else 0
    if size and shutil.disk_usage(path.parent).free >= REBUILD_FACTOR * size + REBUILD_MARGIN:
        try:
            journal.recover(path)
            return status
        except Exception as exc:  # noqa: BLE001 - the journal stays
            if not journal.is_disk_full(exc):
                raise
    return _left(status, path)


REBUILD_FACTOR = 1.5     # the rebuilt file's size over the journal's, with room to spare
REBUILD_MARGIN = 1 << 20  # bytes


def _left(final: str, path: Path) -> str:
    why = final if "disk full" in final else f"{final}; disk full"
    return f"{why}; free space, then `rig recover {path}` rebuilds the run file from its journal"


def _journaled_commands(jpath: Path) -> dict[int, int]:
    """Rows of the loop's records per trial in the journal's whole records."""
    have: dict[int, int] = {}
    for doc, arrays in journal.scan(jpath).records:
        if doc["k"] == "append" and doc["section"] == "commands" and arrays:
            have[doc["trial"]] = have.get(doc["trial"], 0) + int(arrays[0].shape[0])
    return have
