"""The on-disk cache of rest states (and balance-rail placements), by content hash.

Settling the action under gravity and polishing the equilibrium takes about
0.5 s (and imports scipy.optimize); the result depends only on the model's
equations (``ActionModel.equations_key``: every packed array, the active
coordinates, effects that run in Python), the starting state, the tolerances
and the code that computes it (the model's sources, and the source file of
each effect that runs in Python: a user's edited force law settles afresh).
Those go into a SHA-1 key together with the versions of rig and numpy, so a
changed parameter, effect or kernel never finds a stale entry.

Location: ``$RIG_CACHE_DIR`` if set (empty: no disk cache), else
``$XDG_CACHE_HOME/rig`` or ``~/.cache/rig``; entries are ``rest/<key>.npy``
(plain arrays, read without pickle), written to a temporary file and renamed
so readers never see half a file; past MAX_ENTRIES files the oldest are
removed. A missing, unreadable or malformed entry is
recomputed; an unwritable folder only costs the recomputation.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import inspect
import os
import tempfile
from collections.abc import Iterable
from pathlib import Path

import numpy as np

MAX_ENTRIES = 4096  # about 1 MB; beyond it the oldest quarter goes
_SOURCES = ("kernel.py", "assembly.py", "action.py", "effects.py", "integrators.py",
            "integrators_stiff.py", "restcache.py")


def folder() -> Path | None:
    """The cache folder (None: disk cache switched off with RIG_CACHE_DIR='')."""
    env = os.environ.get("RIG_CACHE_DIR")
    if env is not None:
        return Path(env) / "rest" if env.strip() else None
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "rig" / "rest"


@functools.cache
def _code_stamp() -> bytes:
    from rig.version import __version__

    h = hashlib.sha1(f"{__version__} numpy {np.__version__}".encode())
    here = Path(__file__).resolve().parent
    for name in _SOURCES:
        try:
            h.update((here / name).read_bytes())
        except OSError:
            h.update(name.encode())
    return h.digest()


def key(kind: str, parts: Iterable[bytes | np.ndarray | str]) -> str:
    """A hex key for an entry of ``kind`` from its inputs (bytes, arrays or text)."""
    h = hashlib.sha1(kind.encode() + b"\0" + _code_stamp())
    for part in parts:
        if isinstance(part, np.ndarray):
            arr = np.ascontiguousarray(part)
            h.update(f"{arr.dtype}{arr.shape}".encode())
            h.update(arr.tobytes())
        elif isinstance(part, str):
            h.update(part.encode())
        else:
            h.update(part)
        h.update(b"\0")
    return h.hexdigest()


def source_of(cls: type) -> bytes | None:
    """The source file of a class (a user effect's force law is in no other key), or None."""
    try:
        path = inspect.getsourcefile(cls)
        return Path(path).read_bytes() if path else None
    except (OSError, TypeError):
        return None


def load(hexkey: str | None, size: int) -> np.ndarray | None:
    """The stored float vector of ``size`` values, or None (absent or malformed)."""
    where = folder()
    if where is None or hexkey is None:
        return None
    try:
        arr = np.load(where / f"{hexkey}.npy", allow_pickle=False)
    except (OSError, ValueError, EOFError):
        return None
    if arr.dtype != np.float64 or arr.shape != (size,) or not np.all(np.isfinite(arr)):
        return None
    return arr


def store(hexkey: str | None, value: np.ndarray) -> None:
    """Write the vector atomically; failures (read-only home, full disk) are ignored."""
    where = folder()
    if where is None or hexkey is None:
        return
    try:
        where.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=where, prefix=".tmp-", suffix=".npy")
        try:
            with os.fdopen(fd, "wb") as f:
                np.save(f, np.asarray(value, dtype=np.float64), allow_pickle=False)
            os.replace(tmp, where / f"{hexkey}.npy")
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        _prune(where)
    except OSError:
        pass


def _prune(where: Path) -> None:
    """Keep at most MAX_ENTRIES (a fit writes one per parameter set): drop the oldest."""
    entries = [e for e in os.scandir(where) if e.name.endswith(".npy")
               and not e.name.startswith(".")]
    if len(entries) <= MAX_ENTRIES:
        return
    entries.sort(key=lambda e: e.stat().st_mtime)
    for e in entries[: len(entries) - MAX_ENTRIES * 3 // 4]:
        with contextlib.suppress(OSError):  # (another process got there first)
            os.unlink(e.path)
