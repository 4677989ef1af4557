"""The 500 Hz loop's controller hook: the demand (N) from the feedforward and the load cell.

``loop.controller`` names it: ``open_loop`` (the thesis's control: the feedforward is the
demand) or ``module:Class`` of the user's own (rig.control.feedback is one); rig.services.run
calls it once per cycle, after ``reset()`` at each trial's start, and limits its demand with
``rig.motor_torque.Limiter``. A controller with a ``target_n`` attribute is told the
profile's force now (N, not advanced) before each call (rig.control.feedback.LoadCellPI
compares the load cell with it).
"""

from __future__ import annotations

import importlib
from typing import Protocol

from rig.errors import InputError


class Controller(Protocol):
    """The loop's feedback hook: the demand (N) from the feedforward and the load cell."""

    def reset(self) -> None: ...

    def __call__(self, t: float, feedforward_n: float, measured_n: float) -> float: ...


class OpenLoop:
    """The thesis's open-loop control: the (advanced) profile is the demand."""

    name = "open_loop"

    def reset(self) -> None:
        pass

    def __call__(self, t: float, feedforward_n: float, measured_n: float) -> float:
        return feedforward_n


def load_controller(spec: str) -> Controller:
    """``open_loop`` or ``module:Class`` (a class with reset() and __call__)."""
    if spec == "open_loop":
        return OpenLoop()
    mod, _, cls = spec.partition(":")
    if not mod or not cls:
        raise InputError(f"loop.controller: expected 'open_loop' or 'module:Class', got {spec!r}")
    try:
        obj: Controller = getattr(importlib.import_module(mod), cls)()
    except Exception as exc:  # the user's module: any error in importing or making it, one line
        text = " ".join(f"loop.controller: cannot load {spec!r} ({type(exc).__name__}: "
                        f"{exc})".split())
        raise InputError(text) from None
    return obj
