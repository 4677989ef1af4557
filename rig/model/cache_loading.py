"""Loading the model's cached machine code without numba's compiler start-up.

Every process that calls a compiled function loads its machine code from numba's
on-disk cache. Before loading, numba refreshes its target and typing contexts, which
imports every lowering and typing registry numba has (about 70 modules: the array
math, linear algebra, random, typed containers ...) and, through
``numba.np.arraymath``, scipy.linalg to check for a BLAS. None of it is needed to
load machine code that is already compiled, only to compile. Measured on this
project's 2-CPU machine (docs/performance.md, "Waiting for the command line"):
0.20-0.28 s of a 0.9-1.0 s ``rig simulate``.

:func:`install` makes a cache load initialise only numba's runtime (the NRT, which
the loaded code calls) instead of refreshing the contexts, and leaves the registries
to the first real compilation, whose compiler refreshes both contexts itself
(``numba.core.compiler.CompilerBase``), so a later compile in the same process sees
every registry as before. It is applied once, on import of :mod:`rig.model`, only
where numba has the methods it wraps and unless ``RIG_NUMBA_EAGER_REGISTRIES=1``;
anything unexpected leaves numba as it is.
"""

from __future__ import annotations

import os
import threading
from typing import Any

_state = threading.local()
_installed = False


def install() -> bool:
    """Make numba's cache loads skip the lowering registries; True if it is in effect."""
    global _installed
    if _installed:
        return True
    if os.environ.get("RIG_NUMBA_EAGER_REGISTRIES", "") == "1":
        return False
    try:
        from numba.core import caching, cpu
        from numba.core.runtime import rtsys
    except ImportError:  # pragma: no cover - a numba without these modules
        return False
    cache_cls: Any = getattr(caching, "Cache", None)
    ctx_cls: Any = getattr(cpu, "CPUContext", None)
    load = getattr(cache_cls, "load_overload", None)
    refresh = getattr(ctx_cls, "refresh", None)
    if load is None or refresh is None or not hasattr(rtsys, "initialize"):
        return False  # pragma: no cover - numba changed: leave it alone

    def load_overload(self: Any, sig: Any, target_context: Any) -> Any:
        outer = getattr(_state, "loading", False)
        _state.loading = True
        try:
            return load(self, sig, target_context)
        finally:
            _state.loading = outer

    def refresh_context(self: Any) -> None:
        if getattr(_state, "loading", False):
            rtsys.initialize(self)  # what loaded code needs; compiling refreshes the rest
            return
        refresh(self)

    cache_cls.load_overload = load_overload
    ctx_cls.refresh = refresh_context
    _installed = True
    return True


def installed() -> bool:
    """Whether :func:`install` is in effect in this process."""
    return _installed
