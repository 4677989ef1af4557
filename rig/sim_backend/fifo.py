"""The simulated card's input buffer: a ring in shared memory, one writer, one reader.

The writer (the simulated rig, in the loop's process) appends rows; the reader
(the acquisition process) takes them. Like a DAQ card's buffer, the writer
never waits in real-time mode: if the reader falls more than ``capacity`` rows
behind, unread rows are overwritten and the reader's next read raises
``BufferOverflow`` (the gap is never silently skipped). In lock-step mode the
writer waits for room instead.
"""

from __future__ import annotations

import time
from multiprocessing import shared_memory

import numpy as np

from rig.errors import InputError, RigError

_HEADER = 4  # int64: written, read, closed, reserved


class BufferOverflow(RigError, RuntimeError):
    """Unread samples were overwritten: the acquisition fell behind."""


class SharedFifo:
    """Ring of ``capacity`` rows x ``width`` float64 in named shared memory."""

    def __init__(self, capacity: int, width: int, name: str | None = None) -> None:
        if capacity < 1 or width < 1:
            raise InputError(f"capacity, width: expected positive sizes, got {capacity}, {width}")
        self.capacity, self.width = capacity, width
        size = 8 * (_HEADER + capacity * width)
        self.owner = name is None
        self.shm = shared_memory.SharedMemory(name=name, create=self.owner, size=size)
        self.header = np.ndarray((_HEADER,), np.int64, self.shm.buf, 0)
        self.data = np.ndarray((capacity, width), np.float64, self.shm.buf, 8 * _HEADER)
        if self.owner:
            self.header[:] = 0

    @property
    def spec(self) -> tuple[str, int, int]:
        """(name, capacity, width): enough to attach from another process."""
        return self.shm.name, self.capacity, self.width

    @classmethod
    def attach(cls, spec: tuple[str, int, int]) -> SharedFifo:
        name, capacity, width = spec
        return cls(capacity, width, name)

    @property
    def written(self) -> int:
        return int(self.header[0])

    @property
    def read_count(self) -> int:
        return int(self.header[1])

    def free(self) -> int:
        return self.capacity - (self.written - self.read_count)

    def write(self, rows: np.ndarray, wait: bool = False, timeout: float = 10.0) -> None:
        """Append rows; with wait=True block until the reader made room."""
        n = rows.shape[0]
        if n > self.capacity:
            raise InputError(f"rows: {n} rows do not fit a buffer of {self.capacity}")
        if wait:
            end = time.monotonic() + timeout
            while self.free() < n:
                if time.monotonic() > end:
                    raise TimeoutError("the acquisition process stopped reading")
                time.sleep(0.0002)
        w = self.written
        idx = (w + np.arange(n)) % self.capacity
        self.data[idx] = rows
        self.header[0] = w + n  # publish after the data

    def read(self, max_rows: int | None = None) -> np.ndarray:
        """Take the available rows (oldest first); BufferOverflow if some were overwritten."""
        w, r = self.written, self.read_count
        if w - r > self.capacity:
            raise BufferOverflow(f"{w - r - self.capacity} samples were overwritten before they "
                                 f"were read (buffer {self.capacity} samples)")
        n = w - r if max_rows is None else min(max_rows, w - r)
        idx = (r + np.arange(n)) % self.capacity
        rows = self.data[idx].copy()
        if self.written - r > self.capacity:  # overwritten while copying
            raise BufferOverflow("samples were overwritten while being read")
        self.header[1] = r + n
        return rows

    def mark_closed(self) -> None:
        self.header[2] = 1

    @property
    def closed(self) -> bool:
        return bool(self.header[2])

    def close(self) -> None:
        del self.header, self.data
        self.shm.close()
        if self.owner:
            self.shm.unlink()
