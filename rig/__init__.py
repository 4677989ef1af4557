"""rig: controller, data acquisition and model workbench for a grand-piano-action test rig.

``rig.load``, ``rig.simulate`` and ``rig.diagnose`` are the Python API (rig.api); they are
imported on first use so that ``import rig`` stays light.
"""

from typing import Any

from rig.version import __version__

__all__ = ["__version__", "diagnose", "load", "simulate"]

_API = ("load", "simulate", "diagnose")


def __getattr__(name: str) -> Any:
    if name in _API:
        from rig import api

        return getattr(api, name)
    raise AttributeError(f"module 'rig' has no attribute {name!r}")
