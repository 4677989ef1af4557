"""The run file's journal: an append-only file of checksummed records beside a measured run's
HDF5 file (``RUN.h5.journal``), from which ``rig recover RUN.h5`` rebuilds the run file.

Why: HDF5 has no transactions. A write that meets a full disk (ENOSPC), a SIGKILL, or a
crash inside the library can leave the HDF5 file unreadable (half-written metadata:
"address of object past end of allocation"), and after a failed write h5py's handles may
fail again (and have crashed the process) when they are closed. The journal is written
with plain ``os.write`` on a file opened ``O_APPEND``: every block the acquisition
flushes goes to the journal first, then to the HDF5 file. A record is whole or is
discarded: each carries its length and a CRC-32, so a record cut short (by ENOSPC or a
kill in the middle of ``write``) is recognised and dropped with everything after it, and
every record before it is intact (the kernel keeps the written pages when the process
dies). ``JournalWriter.sync`` (``os.fdatasync``), which the acquisition calls after each
flush's records, puts them on the disk, so a power failure or a kernel crash keeps every
record synced before it too (the journal's directory entry is synced when it is
created); its cost: benchmarks/acquisition_memory.py (``--no-sync`` to compare).

Layout: the 8 bytes ``RIGJRNL1``, then records. A record is a 20-byte head
``<4s I Q I>`` (``b"REC1"``, the payload's CRC-32, the payload's length, the JSON part's
length), then the payload: a JSON object (the record's kind and fields) followed by the
record's float64 arrays (little-endian, C order, shapes in the JSON). Kinds:

    begin   {path, kind, attrs, metadata: {name: [text, format]}}    the run file's start
    trial   {trial, attrs}                                           a trial's attributes
    append  {trial, section, names, shapes, units, docs}  + arrays   rows of channels/commands
    meta    {name, text, format}                                     a metadata dataset
    close   {status}                                                 the writer's last word

The journal of a run that ended well is removed once the run file is closed and read back;
one that is left beside a run file means the run file may lack data or be unreadable:
``rig recover RUN.h5`` (``recover``) rebuilds it from the journal.

A test seam: ``RIG_FAULT_ENOSPC=<process>:<n>`` makes the ``n``-th write through
``fault_point`` in the process named ``process`` (``acquisition`` or ``run``) fail with
ENOSPC, a journal write after writing half its bytes (tests/test_run_enospc.py).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import struct
import sys
import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np

from rig.errors import InputError
from rig.recordings import runfile

MAGIC = b"RIGJRNL1"
HEAD = struct.Struct("<4sIQI")
REC = b"REC1"
FAULT_ENV = "RIG_FAULT_ENOSPC"
MAX_RECORD = 1 << 31  # bytes: a longer length is a damaged head


def journal_path(path: str | Path) -> Path:
    """The journal beside run file ``path`` (``RUN.h5`` -> ``RUN.h5.journal``)."""
    p = Path(path)
    return p.with_name(p.name + ".journal")


# The close record's reserve: a disk that fills at once leaves no room to append the run's
# final status ("aborted: disk full ...") to its journal, and whether the last page had room
# was luck (CI: "recovered from the journal (the run's writer died)" instead of the disk-full
# status). So the journal's start also writes this many bytes beside it (``end_path``), and
# a close record the journal cannot take is written over them: overwriting bytes the file
# already holds needs no new space.
END_RESERVE_BYTES = 4096


def end_path(path: str | Path) -> Path:
    """The close record's reserve beside run file ``path`` (``RUN.h5.journal.end``)."""
    return _reserve_of(journal_path(path))


def _reserve_of(jpath: Path) -> Path:
    """The reserve beside journal ``jpath``."""
    return jpath.with_name(jpath.name + ".end")


def remove(path: str | Path) -> None:
    """Remove run file ``path``'s journal and its reserve (the run file is whole)."""
    for p in (journal_path(path), end_path(path)):
        with contextlib.suppress(FileNotFoundError):
            p.unlink()


class _Faults:
    """The test seam (module doc): counts writes in this process, fails the chosen one."""

    def __init__(self) -> None:
        self.count = 0
        self.process = ""

    def armed(self) -> tuple[str, int] | None:
        spec = os.environ.get(FAULT_ENV, "")
        who, _, n = spec.partition(":")
        return (who, int(n)) if who and n.isdigit() else None

    def hit(self) -> bool:
        """True when this write is the one to fail (counted only in the chosen process)."""
        arm = self.armed()
        if arm is None or arm[0] != self.process:
            return False
        self.count += 1
        return self.count == arm[1]


FAULTS = _Faults()


def set_process(name: str) -> None:
    """Name this process for the test seam (``acquisition`` or ``run``)."""
    FAULTS.process = name
    FAULTS.count = 0


def fault_point(what: str) -> None:
    """Raise ENOSPC here when the test seam chose this write."""
    if FAULTS.hit():
        raise OSError(errno.ENOSPC, f"No space left on device (injected at {what})")


def is_disk_full(exc: BaseException) -> bool:
    """ENOSPC (or EDQUOT) however the library reports it (HDF5 errors name ``errno = 28``)."""
    if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return True
    text = str(exc)
    return "errno = 28" in text or "No space left on device" in text or (
        "errno = 122" in text)


class DiskFullEchoes:
    """Keeps the echoes of a full disk off stderr, counting them.

    After a write fails with ENOSPC, h5py's objects fail again as they are freed; Cython
    reports each such failure from ``__dealloc__`` by printing its traceback (through
    ``sys.excepthook``) and an "Exception ignored" line (``sys.unraisablehook``). The run
    has already said "disk full" once; these are that same fault again, so they are
    counted here instead of printed. Any other exception reaches the hooks it had before.
    """

    def __init__(self) -> None:
        self.count = 0
        self._except = sys.excepthook
        self._unraisable = sys.unraisablehook

    def install(self) -> DiskFullEchoes:
        sys.excepthook = self._on_exception
        sys.unraisablehook = self._on_unraisable
        return self

    def _on_exception(self, kind: type[BaseException], exc: BaseException,
                      tb: TracebackType | None) -> None:
        if is_disk_full(exc):
            self.count += 1
        else:
            self._except(kind, exc, tb)

    def _on_unraisable(self, info: Any) -> None:
        if info.exc_value is not None and is_disk_full(info.exc_value):
            self.count += 1
        else:
            self._unraisable(info)


def _encode(kind: str, fields: Mapping[str, Any], arrays: list[np.ndarray]) -> bytes:
    doc = {"k": kind, **fields}
    if arrays:
        doc["shapes"] = [list(a.shape) for a in arrays]
    js = json.dumps(doc, default=runfile.json_default).encode()
    payload = js + b"".join(np.ascontiguousarray(a, dtype="<f8").tobytes() for a in arrays)
    return HEAD.pack(REC, zlib.crc32(payload), len(payload), len(js)) + payload


class JournalWriter:
    """Appends records to a journal; ``create`` starts a new one (refusing an existing one)."""

    def __init__(self, path: Path, fd: int, durable: bool = True) -> None:
        self.path, self.fd = path, fd
        self.durable = durable   # sync() puts the records on the disk (False: a no-op)
        self.broken: OSError | None = None   # set once a write failed: nothing more written
        try:
            _lock(fd, path)  # (the kernel drops the lock with a dead writer)
        except BaseException:
            os.close(fd)
            raise

    @classmethod
    def create(cls, run_path: str | Path, durable: bool = True) -> JournalWriter:
        path = journal_path(run_path)
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        self = cls(path, fd, durable)
        os.ftruncate(fd, 0)
        self._write(MAGIC, "journal head")
        self.sync()
        efd = os.open(end_path(run_path), os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:  # the reserve: the journal's head, then zeros (no record until it is used)
            os.write(efd, MAGIC + bytes(END_RESERVE_BYTES - len(MAGIC)))
            if durable:
                os.fdatasync(efd)
        finally:
            os.close(efd)
        if durable:   # the new file's name in its folder survives a power failure too
            dfd = os.open(path.parent, os.O_RDONLY)
            try:
                os.fsync(dfd)
            finally:
                os.close(dfd)
        return self

    @classmethod
    def append_to(cls, run_path: str | Path) -> JournalWriter:
        """Open an existing journal to add records (the run's process after the
        acquisition's death); a record cut short at its end stays ignored by the reader,
        so records after it would be lost: the file is first cut after its last whole one."""
        path = journal_path(run_path)
        good = scan(path).good_bytes
        fd = os.open(path, os.O_WRONLY | os.O_APPEND)
        self = cls(path, fd)  # (closes fd if it cannot lock it)
        try:
            os.ftruncate(fd, good)
        except BaseException:
            self.close()
            raise
        return self

    def _write(self, data: bytes, what: str) -> None:
        if self.broken is not None:
            raise self.broken
        try:
            if FAULTS.hit():  # the test seam: half the record reaches the disk
                os.write(self.fd, data[:len(data) // 2])
                raise OSError(errno.ENOSPC, f"No space left on device (injected at {what})")
            view = memoryview(data)
            while view:
                n = os.write(self.fd, view)
                view = view[n:]
        except OSError as exc:
            self.broken = exc
            raise

    def sync(self) -> None:
        """Put the records written so far on the disk (``os.fdatasync``; nothing when not
        ``durable``): what a power failure or a kernel crash then cannot take."""
        if self.broken is not None:
            raise self.broken
        if not self.durable:
            return
        try:
            os.fdatasync(self.fd)
        except OSError as exc:
            self.broken = exc
            raise

    def begin(self, path: Path, kind: str, attrs: Mapping[str, Any],
              metadata: Mapping[str, Any]) -> None:
        meta = {name: list(runfile.metadata_text(v)) for name, v in metadata.items()}
        self._write(_encode("begin", {"path": path.name, "kind": kind, "attrs": dict(attrs),
                                      "metadata": meta}, []), "journal begin")

    def trial(self, k: int, attrs: Mapping[str, Any]) -> None:
        self._write(_encode("trial", {"trial": int(k), "attrs": dict(attrs)}, []),
                    "journal trial")

    def append(self, k: int, section: str, data: Mapping[str, np.ndarray],
               units: Mapping[str, str], docs: Mapping[str, str]) -> None:
        names = list(data)
        arrays = [np.asarray(data[n], dtype=float) for n in names]
        self._write(_encode("append", {
            "trial": int(k), "section": section, "names": names,
            "units": {n: units[n] for n in names if n in units},
            "docs": {n: docs[n] for n in names if n in docs}}, arrays), "journal append")

    def metadata(self, name: str, value: Any, fmt: str | None = None) -> None:
        text, kind = runfile.metadata_text(value)
        self._write(_encode("meta", {"name": name, "text": text, "format": fmt or kind}, []),
                    "journal metadata")

    def close_record(self, status: str) -> None:
        """The run's final status: appended to the journal, or, when the journal cannot take
        it (a full disk), written over the reserve beside it (``end_path``); OSError only
        when neither took it."""
        try:
            self._write(_encode("close", {"status": status}, []), "journal close")
        except OSError:
            if not self._close_in_reserve(status):
                raise

    def _close_in_reserve(self, status: str) -> bool:
        rec = MAGIC + _encode("close", {"status": status}, [])
        if len(rec) > END_RESERVE_BYTES:  # (a status is one line; keep its start)
            rec = MAGIC + _encode("close", {"status": status[:END_RESERVE_BYTES // 2]}, [])
        try:
            fd = os.open(_reserve_of(self.path), os.O_WRONLY)
        except OSError:
            return False
        try:
            os.pwrite(fd, rec, 0)
            if self.durable:
                os.fdatasync(fd)
        except OSError:
            return False
        finally:
            os.close(fd)
        return True

    def close(self) -> None:
        with contextlib.suppress(OSError):
            os.close(self.fd)


def _lock(fd: int, path: Path) -> None:
    """One writer (or recovery) at a time: a journal locked by a live run is refused."""
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise InputError(f"{path}: a run is still writing it (recover once it has "
                         f"ended)") from None


@dataclass
class Scan:
    """What a journal holds: its whole records, and the bytes they span."""

    records: list[tuple[dict[str, Any], list[np.ndarray]]] = field(default_factory=list)
    good_bytes: int = 0
    torn: bool = False   # bytes after the last whole record (a write cut short)


def scan(path: str | Path) -> Scan:
    """Every whole record of the journal at ``path``, stopping at the first damaged one."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        raise InputError(f"{p}: no journal (nothing to recover from)") from None
    if not data.startswith(MAGIC):
        if len(data) < len(MAGIC) and MAGIC.startswith(data):
            return Scan([], 0, bool(data))
        raise InputError(f"{p}: not a rig run-file journal")
    out = Scan(good_bytes=len(MAGIC))
    pos = len(MAGIC)
    while pos + HEAD.size <= len(data):
        tag, crc, length, jlen = HEAD.unpack_from(data, pos)
        end = pos + HEAD.size + length
        if tag != REC or length > MAX_RECORD or jlen > length or end > len(data):
            break
        payload = data[pos + HEAD.size:end]
        if zlib.crc32(payload) != crc:
            break
        doc = json.loads(payload[:jlen])
        arrays = []
        off = jlen
        for shape in doc.get("shapes", []):
            n = int(np.prod(shape)) * 8
            arrays.append(np.frombuffer(payload, "<f8", count=n // 8, offset=off)
                          .reshape(shape).copy())
            off += n
        out.records.append((doc, arrays))
        pos = end
        out.good_bytes = pos
    out.torn = pos < len(data)
    return out


@dataclass
class Recovered:
    path: Path
    status: str
    samples: int          # rows of channels over all trials
    trials: int
    torn: bool            # the journal ended in a record cut short (dropped)


def recover(run_path: str | Path, *, out: str | Path | None = None,
            force: bool = False, keep_journal: bool = False) -> Recovered:
    """Rebuild the run file from its journal (``rig recover RUN.h5``): written to a new file
    beside it, then moved over ``out`` (default the run file itself, which a journal left
    beside it marks as unfinished; another existing ``out`` needs ``force``). A journal
    without a ``close`` record (its writers died) gives status ``aborted: recovered from
    the journal (the run's writer died)``. The journal is removed afterwards unless
    ``keep_journal``."""
    run_path = Path(run_path)
    jpath = journal_path(run_path)
    if run_path.is_dir():
        raise InputError(f"{run_path}: is a folder, expected a run file (.h5)")
    if not jpath.is_file():
        raise InputError(f"{run_path}: no journal {jpath.name} beside it (nothing to recover; "
                         f"a run that ended well leaves none)")
    target = Path(out) if out is not None else run_path
    if target.is_dir():
        raise InputError(f"--out: {target} is a folder, expected a file")
    if out is not None and target.exists() and not force:
        raise InputError(f"--out: {target} exists (use --force to replace it)")
    lock = os.open(jpath, os.O_RDONLY)
    try:
        _lock(lock, jpath)
        return _recover_locked(run_path, jpath, target, keep_journal)
    finally:
        with contextlib.suppress(OSError):
            os.close(lock)


def _recover_locked(run_path: Path, jpath: Path, target: Path,
                    keep_journal: bool) -> Recovered:
    sc = scan(jpath)
    if not sc.records or sc.records[0][0].get("k") != "begin":
        raise InputError(f"{jpath}: holds no whole first record (the run wrote nothing "
                         f"recoverable)")
    end = _reserve_of(jpath)
    if not any(doc["k"] == "close" for doc, _ in sc.records) and end.is_file():
        # the final status the full journal could not take, in its reserve
        sc.records += [r for r in scan(end).records if r[0].get("k") == "close"][:1]
    tmp = target.with_name(f".{target.name}.recovering")
    status, samples, trials = _replay(sc, tmp)
    os.replace(tmp, target)
    if not keep_journal:
        with contextlib.suppress(OSError):
            jpath.unlink()
        with contextlib.suppress(OSError):
            end.unlink()
    return Recovered(target, status, samples, trials, sc.torn)


DIED = "aborted: recovered from the journal (the run's writer died)"


def _replay(sc: Scan, tmp: Path) -> tuple[str, int, int]:
    head = sc.records[0][0]
    status = DIED
    samples = 0
    ok = False
    w = runfile.RunWriter(tmp, head["kind"], None, crash_safe=True)
    try:
        for name, value in head["attrs"].items():
            if name not in ("status", "n_trials"):
                w.file.attrs[name] = value
        for name, (text, fmt) in head["metadata"].items():
            w.add_metadata(name, text, fmt)
        writers: dict[int, runfile.TrialWriter] = {}

        def trial(k: int) -> runfile.TrialWriter:
            if k not in writers:
                writers[k] = w.trial(k)
            return writers[k]

        for doc, arrays in sc.records[1:]:
            kind = doc["k"]
            if kind == "trial":
                trial(doc["trial"]).set_attrs(**doc["attrs"])
            elif kind == "append":
                data = dict(zip(doc["names"], arrays, strict=True))
                trial(doc["trial"]).append(doc["section"], data, doc["units"], doc["docs"])
                if doc["section"] == "channels" and "time" in data:
                    samples += int(data["time"].shape[0])
            elif kind == "meta":
                w.add_metadata(doc["name"], doc["text"], doc["format"])
            elif kind == "close":
                status = str(doc["status"])
        if not (status == "complete" or status.startswith("aborted")):
            status = DIED
        w.close(status)
        ok = True
    finally:
        if not ok:
            with contextlib.suppress(Exception):
                w.file.close()
            with contextlib.suppress(OSError):
                tmp.unlink()
    return status, samples, len(writers)
