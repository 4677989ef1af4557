"""The run's side of the acquisition process at the end: the loop's records, stopping the
process, and recovering the run file when it died.

The loop's records (``LoopRecords``) go to the acquisition process in batches; the last
``KEEP_RECORDS_S`` of them stay in the run's process, so that when the acquisition process
died (or failed) ``finish`` can close the file itself: the records it had not written,
the run's metadata and an ``aborted: ...`` status naming why.
"""

from __future__ import annotations

import queue
import signal
import time
from pathlib import Path
from typing import Any

import numpy as np

from rig import runfile
from rig.calrecords import COMMAND_DOCS, COMMAND_UNITS
from rig.config import RigConfig

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
        self.lateness = np.zeros(total + 1)
        self.missed = np.zeros(total + 1)
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


def finish(proc: Any, ctrl: Any, status_q: Any, rows: LoopRecords, trials: int, status: str,
            stats: dict[str, float], end_sample: int, path: Path, cfg: RigConfig,
            abort_tb: str | None = None, done_trials: int = 0) -> int | None:
    """Stop the acquisition process and see the file closed; recover it if the process died."""
    meta: dict[str, Any] = {"loop_lateness": stats}
    if abort_tb is not None:
        meta["abort_traceback"] = abort_tb
    tattrs: dict[int, dict[str, Any]] = {k: {"status": "complete"} for k in range(done_trials)}
    if proc is None:
        return None
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
        return int(done[0][1])
    # the acquisition process died or failed: finish the file here
    why = errors[0] if errors else f"the acquisition process died (exit code {proc.exitcode})"
    final = status if status.startswith("aborted") else f"aborted: {why}"
    if errors and "acquisition process died" in status:
        final = f"aborted: {errors[0]}"
    if not path.is_file():
        return None
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
    return None
