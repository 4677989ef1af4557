"""Physical effects: named additions to the base action model.

A model is the base mechanism plus a list of effects. An effect declares its
parameters (name, units, default, physical bounds, whether it is usually
fitted) and the residual signature its absence leaves in measurements, and it
changes the model through any of these hooks:

- ``apply(build)``: before the model is packed: change parameters, switch the
  kernel's built-in coordinates (``build.flags``) or contact laws
  (``build.contact_overrides``).
- ``transform_input(time, force)``: change the force that reaches the key
  (e.g. a drive's lag); runs on the profile before integration.
- ``generalized_force(t, q, qdot)``: extra generalized forces on the 9
  coordinates (Python; the model then integrates through scipy, slower).
- ``add_channels(result)`` / ``measure(result)``: new output channels, or
  what a sensor does to the channels (filters, misreadings).

A user's effect is a subclass in their own file or package, named in the model
YAML as ``package.module:Class`` or ``path/to/file.py:Class``.
"""

from __future__ import annotations

import importlib
import importlib.util
import math
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from rig.params import Parameters

if TYPE_CHECKING:
    from rig.model.action import SimResult


@dataclass(frozen=True)
class EffectParameter:
    """One parameter of an effect."""

    name: str
    units: str
    default: float
    bounds: tuple[float, float]
    fitted: bool = False
    description: str = ""
    path: str | None = None  # the model parameter it sets, if any (dotted path)


@dataclass(frozen=True)
class Signature:
    """The residual an effect's absence leaves in measurements."""

    channels: tuple[str, ...]
    phases: tuple[str, ...]
    kind: str  # bias | lag | oscillation | timing | shape
    frequency_hz: float | None = None
    text: str = ""


@dataclass
class Build:
    """What effects may change before the model is packed."""

    params: Parameters
    flags: dict[str, bool] = field(default_factory=lambda: {"liftoff": False,
                                                            "flexible_shank": False})
    contact_overrides: dict[tuple[int, int], float] = field(default_factory=dict)


class Effect:
    """Base class of every effect (built-in and user)."""

    name: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    parameters: ClassVar[tuple[EffectParameter, ...]] = ()
    signature: ClassVar[Signature] = Signature((), (), "shape")

    def __init__(self, **values: float) -> None:
        known = {p.name: p for p in self.parameters}
        self.values: dict[str, float] = {p.name: p.default for p in self.parameters}
        self.explicit: set[str] = set()  # set by the user; others follow the model's parameters
        for key, value in values.items():
            if key not in known:
                raise ValueError(f"effect {self.name}: unknown parameter {key!r} "
                                 f"(expected one of {sorted(known)})")
            self.set(key, value)

    def set(self, key: str, value: Any) -> None:
        """Set a parameter, checking it is a finite number within its bounds."""
        spec = {p.name: p for p in self.parameters}.get(key)
        if spec is None:
            raise ValueError(f"effect {self.name}: unknown parameter {key!r}")
        if isinstance(value, bool) or not isinstance(value, int | float) \
                or not math.isfinite(float(value)):
            raise ValueError(f"effect {self.name}: parameter {key!r}: expected a finite number "
                             f"in {spec.units}, got {value!r}")
        lo, hi = spec.bounds
        if not lo <= float(value) <= hi:
            raise ValueError(f"effect {self.name}: parameter {key!r} = {value} is outside its "
                             f"physical bounds [{lo}, {hi}] {spec.units}")
        self.values[key] = float(value)
        self.explicit.add(key)

    # hooks -------------------------------------------------------------------
    def apply(self, build: Build) -> None:
        """Write the user's values of mapped parameters into the model's parameter tree.

        A mapped parameter the user did not set takes the tree's value, so a
        parameter file and the effect agree on one number.
        """
        for p in self.parameters:
            if p.path is None:
                continue
            if p.name in self.explicit:
                build.params.set(p.path, self.values[p.name])
            else:
                self.values[p.name] = float(build.params.get(p.path))

    def transform_input(self, time: np.ndarray, force: np.ndarray) -> np.ndarray:
        return force

    def generalized_force(self, t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray | None:
        return None

    def has_generalized_force(self) -> bool:
        return type(self).generalized_force is not Effect.generalized_force

    def add_channels(self, result: SimResult) -> None:
        return None

    def measure(self, result: SimResult) -> None:
        return None

    def describe(self) -> dict[str, Any]:
        """Metadata written into run files."""
        return {"name": self.name, "class": f"{type(self).__module__}:{type(self).__qualname__}",
                "values": dict(self.values), "summary": self.summary}


class FlexibleShank(Effect):
    """The hammer shank as a Rayleigh beam (u1200 Taylor shape functions)."""

    name = "flexible_shank"
    summary = ("Hammer shank as a Rayleigh beam (one axial, two bending Taylor coordinates) "
               "clamped in the hammer flange, head carried at its end; adds shank_strain and "
               "shank_tip_deflection.")
    parameters = (
        EffectParameter("E", "Pa", 10.18e9, (1e9, 4e10), True, "shank Young's modulus",
                        "hammer_shank_beam.E"),
        EffectParameter("density", "kg/m^3", 560.0, (200.0, 1500.0), False, "shank density",
                        "hammer_shank_beam.density"),
        EffectParameter("damping_ratio", "1", 0.01, (0.0, 0.2), True,
                        "modal damping ratio of the first bending mode",
                        "hammer_shank_damping.ratio"),
    )
    signature = Signature(
        ("shank_strain", "hammer_angle"), ("string contact", "flight back to the check"),
        "oscillation", 280.0,
        "ring-down of the shank's first bending mode after the strike, and a static bending "
        "while the back check holds the hammer; a rigid shank shows neither")

    def apply(self, build: Build) -> None:
        super().apply(build)
        build.flags["flexible_shank"] = True


class KeyLiftoff(Effect):
    """The key on a massless slider resting on the balance rail (contact 14)."""

    name = "key_liftoff"
    summary = ("Key pivot on a massless body sliding vertically, resting on the balance rail "
               "through contact 14; adds key_lift.")
    parameters = (
        EffectParameter("damping", "s/m", 100.0, (0.0, 1000.0), True,
                        "damping factor D of contact 14", "contacts.14.D"),
        EffectParameter("stiffness_scale", "1", 1.0, (0.05, 20.0), False,
                        "scale on contact 14's stiffness polynomial (a, b, c)"),
    )
    signature = Signature(
        ("key_angle", "key_dip"), ("check", "release"), "oscillation", None,
        "the key bounces on its balance rail when its front bottoms and when it falls back; "
        "a revolute key shows a cleaner key angle at those moments")

    def apply(self, build: Build) -> None:
        super().apply(build)
        scale = self.values["stiffness_scale"]
        if scale != 1.0:
            for coef in ("a", "b", "c"):
                build.params.set(f"contacts.14.{coef}",
                                 build.params.get(f"contacts.14.{coef}") * scale)
        build.flags["liftoff"] = True


BUILTIN: dict[str, type[Effect]] = {cls.name: cls for cls in (FlexibleShank, KeyLiftoff)}


def register(cls: type[Effect]) -> type[Effect]:
    """Add an effect class to the library (usable by name in model YAML)."""
    if not cls.name:
        raise ValueError(f"{cls.__qualname__}: an effect needs a non-empty name")
    BUILTIN[cls.name] = cls
    return cls


def _load_class(ref: str) -> type[Effect]:
    target, _, cls_name = ref.rpartition(":")
    if not target or not cls_name:
        raise ValueError(f"effect {ref!r}: expected a library name, 'module:Class' or "
                         f"'path.py:Class'")
    if target.endswith(".py"):
        path = Path(target)
        if not path.is_file():
            raise ValueError(f"effect {ref!r}: file {path} not found")
        mod_name = f"rig_user_effect_{abs(hash(str(path.resolve())))}"
        spec = importlib.util.spec_from_file_location(mod_name, path)
        if spec is None or spec.loader is None:
            raise ValueError(f"effect {ref!r}: cannot import {path}")
        module = importlib.util.module_from_spec(spec)
        sys.modules[mod_name] = module
        spec.loader.exec_module(module)
    else:
        try:
            module = importlib.import_module(target)
        except ImportError as exc:
            raise ValueError(f"effect {ref!r}: cannot import module {target!r} ({exc})") from None
    cls = getattr(module, cls_name, None)
    if not (isinstance(cls, type) and issubclass(cls, Effect)):
        raise ValueError(f"effect {ref!r}: {cls_name} is not a subclass of rig Effect")
    return cls


def make(spec: str | Mapping[str, Any] | Effect, base_dir: Path | None = None) -> Effect:
    """An effect from a name, a ``{name: {param: value}}`` mapping, or an instance."""
    if isinstance(spec, Effect):
        return spec
    values: Mapping[str, Any] = {}
    if isinstance(spec, Mapping):
        if len(spec) != 1:
            raise ValueError(f"effect {dict(spec)!r}: expected one name with its parameters")
        ((name, vals),) = spec.items()
        values = vals or {}
        if not isinstance(values, Mapping):
            raise ValueError(f"effect {name}: expected a mapping of parameter values")
    elif isinstance(spec, str):
        name = spec
    else:
        raise ValueError(f"effect {spec!r}: expected a name or a mapping")
    if name in BUILTIN:
        cls = BUILTIN[name]
    elif ":" in name:
        ref = name
        target = name.rpartition(":")[0]
        if target.endswith(".py") and base_dir is not None and not Path(target).is_absolute():
            ref = f"{base_dir / target}:{name.rpartition(':')[2]}"
        cls = _load_class(ref)
    else:
        raise ValueError(f"effect {name!r}: not in the library (known: {sorted(BUILTIN)}); "
                         f"name a user effect as 'module:Class' or 'file.py:Class'")
    return cls(**dict(values))
