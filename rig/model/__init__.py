"""The planar grand-piano action model: kernel, integrators, simulation."""

from __future__ import annotations

from pathlib import Path

_HERE = Path(__file__).resolve().parent
# Modules whose compiled (numba, cache=True) functions call compiled functions of other
# modules: numba keys its on-disk cache on each file's own timestamp, so after an edit
# of a module they call, their cached machine code would still hold the old code.
_COMPILED_CALLERS = {
    "integrators": ("kernel",),
    "integrators_stiff": ("kernel", "integrators"),
}


def _drop_stale_caches(here: Path = _HERE) -> None:
    cache = here / "__pycache__"
    if not cache.is_dir():
        return
    for name, callees in _COMPILED_CALLERS.items():
        stamps = [(here / f"{c}.py").stat().st_mtime for c in callees
                  if (here / f"{c}.py").exists()]
        if not stamps:
            continue
        stamp = max(stamps)
        for entry in cache.glob(f"{name}.*.nb[ic]"):
            try:
                if entry.stat().st_mtime < stamp:
                    entry.unlink()
            except OSError:  # another process got there first, or a read-only install
                pass


_drop_stale_caches()

# loading cached machine code without importing numba's compiler registries (about
# 0.2 s of every command that simulates): see rig.model.cache_loading
from rig.model import cache_loading as _cache_loading  # noqa: E402

_cache_loading.install()

# the effect library's members in their own modules register themselves in
# rig.model.effects.BUILTIN on import; imported here so the library is whole whichever
# module of the model is imported first (and effects.py imports none of them: no cycle)
from rig.model import fingertip as _fingertip  # noqa: E402,F401
