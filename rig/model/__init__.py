"""The planar grand-piano action model: kernel, integrators, simulation."""

from __future__ import annotations

from pathlib import Path

_HERE = Path(__file__).resolve().parent
# Modules whose compiled (numba, cache=True) functions call kernel.rhs. numba keys its
# on-disk cache on each file's own timestamp, so after an edit of kernel.py their
# cached machine code would still hold the old kernel.
_KERNEL_USERS = ("integrators", "integrators_stiff")


def _drop_stale_caches() -> None:
    kernel = _HERE / "kernel.py"
    cache = _HERE / "__pycache__"
    if not kernel.exists() or not cache.is_dir():
        return
    stamp = kernel.stat().st_mtime
    for name in _KERNEL_USERS:
        for entry in cache.glob(f"{name}.*.nb[ic]"):
            try:
                if entry.stat().st_mtime < stamp:
                    entry.unlink()
            except OSError:  # another process got there first, or a read-only install
                pass


_drop_stale_caches()
