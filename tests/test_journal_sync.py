"""The journal's records are put on the disk at each flush (issue 37): the acquisition
syncs its journal (``os.fdatasync``) after the records of every flush, so a power failure
keeps what was flushed, not only a killed process."""

from __future__ import annotations

import os
import queue
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from rig.calibration import records as cal_records
from rig.inputs import config
from rig.loop import journal
from rig.loop.acquisition import Acquisition
from rig.recordings import runfile
from rig.sensors import table as calrecords
from rig.sim_backend.daq import row_width


class _NoMessages:
    def get_nowait(self) -> Any:
        raise queue.Empty


def _synced(monkeypatch: pytest.MonkeyPatch) -> list[tuple[int, int]]:
    """Each fdatasync: (fd, the file's size then)."""
    calls: list[tuple[int, int]] = []
    real = os.fdatasync

    def spy(fd: int) -> None:
        calls.append((fd, os.fstat(fd).st_size))
        real(fd)

    monkeypatch.setattr(journal.os, "fdatasync", spy)
    return calls


def test_every_flush_syncs_the_journal_after_its_records(tmp_path: Path,
                                                          monkeypatch: pytest.MonkeyPatch):
    calls = _synced(monkeypatch)
    cfg = config.from_mapping({"backend": "sim", "data_folder": str(tmp_path)})
    path = tmp_path / "r.h5"
    writer = runfile.RunWriter(path, "measured", {"note": "t"}, crash_safe=True)
    jw = journal.JournalWriter.create(path)
    # the new journal's head, then the close record's reserve beside it
    assert calls[0] == (jw.fd, len(journal.MAGIC)) and len(calls) == 2
    assert calls[1][0] != jw.fd and calls[1][1] == journal.END_RESERVE_BYTES
    acq = Acquisition(cfg, cal_records.lookup(cfg), writer, _NoMessages(), None, jw)
    col = calrecords.column(cfg, calrecords.SAMPLE)
    n = 0
    acq.handle(("trial", 0, 0, 10))
    for flush in range(3):
        rows = np.zeros((40, row_width(cfg)))
        rows[:, col] = np.arange(n, n + 40)
        n += 40
        acq.take(rows)
        acq.write_pending()
        # one sync per flush, after its records: the journal's size then is its size now
        assert len(calls) == flush + 3
        assert calls[-1] == (jw.fd, os.fstat(jw.fd).st_size)
        assert journal.scan(journal.journal_path(path)).good_bytes == calls[-1][1]
    acq.finish("complete", {}, {})
    jw.close()


def test_a_journal_not_durable_is_not_synced_and_a_broken_one_raises(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    calls = _synced(monkeypatch)
    jw = journal.JournalWriter.create(tmp_path / "a.h5", durable=False)
    jw.trial(0, {})
    jw.sync()
    assert calls == []
    jw.close()
    jw = journal.JournalWriter.create(tmp_path / "b.h5")
    jw.broken = OSError(28, "No space left on device")
    with pytest.raises(OSError, match="No space"):
        jw.sync()
    jw.close()
