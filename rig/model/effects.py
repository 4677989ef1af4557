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
- ``states`` with ``state_derivative(t, q, qdot, z)`` and
  ``generalized_force(t, q, qdot, z)``: new state variables z (e.g. a new
  coordinate and its rate) with their own dynamics, coupled to the mechanism
  through generalized forces; each becomes an output channel ``<effect>_<state>``.
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

from rig.errors import InputError, not_a_file
from rig.inputs.params import Parameters

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
    off: float | None = None  # the value at which the effect changes nothing (if any)
    # start-scan points the fit needs over the bounds at least (0: the fit's own count): a
    # parameter that sets a ringing mode's frequency makes the time-domain cost ripple
    scan: int = 0
    # a scale quantity whose bounds start at 0 (a damping): plausible values spread over
    # decades at the bottom of its range, so the fit works in log(value + shift), shift
    # LOG_SHIFT of the default, not linearly across the bounds (rig.analysis.fit.Target)
    log: bool = False


# the shift of a ``log`` parameter's fitted coordinate, a share of its default: values down
# to about this share of the default are scanned and fitted as finely as those near it
LOG_SHIFT = 0.01


@dataclass(frozen=True)
class EffectState:
    """A state variable an effect adds to the model (first order; a coordinate and its
    rate are two states)."""

    name: str
    units: str
    atol: float = 1e-8
    initial: float = 0.0


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
    states: ClassVar[tuple[EffectState, ...]] = ()
    # names of effects this one switches on as well (diagnose credits it only with
    # what it adds beyond them)
    implies: ClassVar[tuple[str, ...]] = ()
    # False for input models (fingertip): diagnose does not propose them
    diagnosable: ClassVar[bool] = True
    # the parameter (s) of transform_input that is a pure dead time, if it has one: any
    # effect whose whole transform is a time shift (input_shift) trades with it exactly
    dead_time: ClassVar[str | None] = None

    def __init__(self, **values: float) -> None:
        known = {p.name: p for p in self.parameters}
        self.values: dict[str, float] = {p.name: p.default for p in self.parameters}
        self.explicit: set[str] = set()  # set by the user; others follow the model's parameters
        for key, value in values.items():
            if key not in known:
                raise InputError(f"effect {self.name}: unknown parameter {key!r} "
                                 f"(expected one of {sorted(known)})")
            self.set(key, value)

    def set(self, key: str, value: Any) -> None:
        """Set a parameter, checking it is a finite number within its bounds
        (``"default"`` sets the library's default)."""
        spec = {p.name: p for p in self.parameters}.get(key)
        if spec is None:
            raise InputError(f"effect {self.name}: unknown parameter {key!r}")
        if isinstance(value, str) and value.strip().lower() == "default":
            value = spec.default  # the library's default back, explicitly
        if isinstance(value, bool) or not isinstance(value, int | float) \
                or not math.isfinite(float(value)):
            raise InputError(f"effect {self.name}: parameter {key!r}: expected a finite number "
                             f"in {spec.units}, got {value!r}")
        lo, hi = spec.bounds
        if not lo <= float(value) <= hi:
            raise InputError(f"effect {self.name}: parameter {key!r} = {value} is outside its "
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

    def input_shift(self) -> float | None:
        """The time shift (s, later positive) that is the whole of ``transform_input`` at
        the current values, or None if it is anything else."""
        return None

    def generalized_force(self, t: float, q: np.ndarray, qd: np.ndarray,
                          *z: np.ndarray) -> np.ndarray | None:
        """Extra generalized forces (9); effects with ``states`` also receive their z."""
        return None

    def state_derivative(self, t: float, q: np.ndarray, qd: np.ndarray,
                         z: np.ndarray) -> np.ndarray:
        """dz/dt of the effect's own states."""
        return np.zeros(len(self.states))

    def runs_in_python(self) -> bool:
        """True if the effect adds forces or states evaluated in Python at each step."""
        return bool(self.states) or (
            type(self).generalized_force is not Effect.generalized_force)

    def add_channels(self, result: SimResult) -> None:
        return None

    def measure(self, result: SimResult) -> None:
        return None

    def describe(self) -> dict[str, Any]:
        """Metadata written into run files."""
        return {"name": self.name, "class": f"{type(self).__module__}:{type(self).__qualname__}",
                "values": dict(self.values), "summary": self.summary}


# start-scan points over the shank's Young's modulus (log-spaced, 1e9-4e10 Pa: 8 % apart).
# The first bending mode rings ~50 cycles at ~280 Hz in a 0.2-0.4 s window, so the
# training cost against E ripples: minima ~20 % apart in E, each basin ~10 % wide
# (measured, issue 39, wide benchmark development seed 619: E = 8.2e9 Pa hidden; from the
# coarse scan's best start, 1.0e10, the fit stopped in the next basin, 9.4e9, and the
# shank predicted the held-out blow worse than the rigid one)
SHANK_E_SCAN = 48


class FlexibleShank(Effect):
    """The hammer shank as a Rayleigh beam (u1200 Taylor shape functions)."""

    name = "flexible_shank"
    summary = ("Hammer shank as a Rayleigh beam (one axial, two bending Taylor coordinates) "
               "clamped in the hammer flange, head carried at its end; adds shank_strain and "
               "shank_tip_deflection.")
    parameters = (
        EffectParameter("E", "Pa", 10.18e9, (1e9, 4e10), True, "shank Young's modulus",
                        "hammer_shank_beam.E", scan=SHANK_E_SCAN),
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
               "through contact 14, the rail placed so that the key rests at the revolute "
               "key's height; adds key_lift.")
    parameters = (
        EffectParameter("damping", "s/m", 100.0, (0.0, 1000.0), True,
                        "damping factor D of contact 14", "contacts.14.D"),
        EffectParameter("stiffness_scale", "1", 1.0, (0.05, 20.0), False,
                        "scale on contact 14's stiffness polynomial (a, b, c)"),
        EffectParameter("pin_friction", "N", 0.0, (0.0, 10.0), True,
                        "friction of the key bushing on the balance-rail pin while the key "
                        "slides up and down", "key_pin_friction.force"),
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


@dataclass(frozen=True)
class RailLift:
    """How the key left its balance rail in a time window of a ``key_liftoff`` blow."""

    height: float  # m: largest height of the key pivot above its rest (y0)
    clearance: float  # m: height less the rail felt's compression at rest; > 0 = clear of it
    airborne: float  # s: time the rail (contact 14) carried no force


def rail_lift(result: SimResult, start: float = -math.inf, end: float = math.inf) -> RailLift:
    """The key's lift off its balance rail between ``start`` and ``end`` (s) of a blow from
    rest. The rail felt lets go as soon as it unloads faster than it recovers (Eq. 3.2
    never pulls), so ``airborne`` can exceed zero while ``clearance`` is still negative."""
    lift = result.channels.get("key_lift")
    if lift is None:
        raise InputError("result: key_lift: the blow was simulated without key_liftoff")
    t = result.time
    w = (t >= start) & (t < end)
    if not w.any():
        raise InputError(f"start, end: no samples between {start} and {end} s")
    height = float(lift[w].max())
    felt = float(result.contact("contact_penetration", 14)[0])
    free = w & (result.contact("contact_force", 14) <= 0.0)
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    return RailLift(height, height - felt, float(free.sum()) * dt)


def _uniform(time: np.ndarray, force: np.ndarray) -> float:
    dt = np.diff(time)
    if dt.size == 0 or np.ptp(dt) > 1e-9 * max(1.0, float(dt.mean())):
        raise InputError("transform_input: expected force on a uniform time grid")
    return float(dt.mean())


def _shift(time: np.ndarray, force: np.ndarray, delay: float) -> np.ndarray:
    """force(t - delay) on a uniform grid, held at the end values outside the record.

    A whole number of samples moves the record; the fraction, taken in [0.5, 1.5)
    samples, goes through a first-order Thiran all-pass, ``(a + z^-1) / (1 + a z^-1)``
    with ``a = (1 - d) / (1 + d)``: its gain is exactly 1 at every frequency and its group
    delay d at low frequencies. Linear interpolation between samples would low-pass the
    record by an amount that depends on the delay's fraction of a sample (cos(pi f dt): 8 %
    at 250 Hz and 2 kHz half-way between samples), which made a fitted delay's cost ripple
    with a period of one sample and its minima trade against a low-pass's bandwidth."""
    from scipy import signal

    x = np.asarray(force, float)
    if x.size < 2 or delay == 0:
        return x.copy()
    d_samples = delay / _uniform(time, x)
    m = math.floor(d_samples - 0.5)
    frac = d_samples - m  # in [0.5, 1.5)
    if m >= 0:
        x = np.concatenate([np.full(min(m, x.size), x[0]), x[:x.size - min(m, x.size)]])
    else:
        k = min(-m, x.size)
        x = np.concatenate([x[k:], np.full(k, x[-1])])
    a = (1.0 - frac) / (1.0 + frac)
    zi = signal.lfilter_zi([a, 1.0], [1.0, a]) * x[0]
    out, _ = signal.lfilter([a, 1.0], [1.0, a], x, zi=zi)
    return np.asarray(out)


class DriveDynamics(Effect):
    """The drive, motor and arm between the recorded force and the key."""

    name = "drive_dynamics"
    summary = ("The force reaching the key lags the recorded force (a demand, or a force "
               "measured upstream) through a dead time and a second-order low-pass: the "
               "drive's current loop, the motor and the arm (thesis Appendix D: ~8 ms).")
    parameters = (
        EffectParameter("delay", "s", 0.0, (0.0, 0.03), True, "dead time"),
        EffectParameter("bandwidth", "Hz", 80.0, (5.0, 1000.0), True,
                        "natural frequency of the second-order lag"),
        EffectParameter("damping_ratio", "1", 0.7, (0.2, 2.0), False,
                        "damping ratio of the second-order lag"),
    )
    signature = Signature(
        ("key_angle", "whippen_angle", "hammer_angle"), ("key descent",), "lag",
        None, "every body moves later than the model driven by the recorded force; strike, "
        "let-off and key-bottom times shift later by several ms, strike speed barely changes")
    dead_time = "delay"

    def transform_input(self, time: np.ndarray, force: np.ndarray) -> np.ndarray:
        from scipy import signal

        dt = _uniform(time, force)
        shifted = _shift(time, force, self.values["delay"])
        wn = 2 * np.pi * self.values["bandwidth"]
        z = self.values["damping_ratio"]
        num, den = signal.bilinear([wn * wn], [1.0, 2 * z * wn, wn * wn], fs=1.0 / dt)
        zi = signal.lfilter_zi(num, den) * shifted[0]
        out, _ = signal.lfilter(num, den, shifted, zi=zi)
        return np.asarray(out)


class LoadCellFilter(Effect):
    """The load cell's conditioning filter between the key force and its record."""

    name = "load_cell_filter"
    summary = ("The recorded force is the key force after the SCXI-1520's 4-pole Butterworth "
               "low-pass (100 Hz in the thesis), so it lags the force on the key; the model "
               "is driven by the record advanced by the filter's low-frequency group delay.")
    parameters = (
        EffectParameter("cutoff", "Hz", 100.0, (10.0, 2000.0), True, "filter cut-off"),
    )
    signature = Signature(
        ("key_angle", "whippen_angle", "hammer_angle"), ("key descent",), "lag", None,
        "the bodies move EARLIER than the model driven by the recorded force, by ~4 ms at "
        "100 Hz; event times shift earlier")

    #: group delay at low frequency of a 4-pole Butterworth, times its cut-off (rad)
    GROUP_DELAY_RAD = 2.6131

    def transform_input(self, time: np.ndarray, force: np.ndarray) -> np.ndarray:
        _uniform(time, force)
        return _shift(time, force, self.input_shift())

    def input_shift(self) -> float:
        return -self.GROUP_DELAY_RAD / (2 * np.pi * self.values["cutoff"])


class KeyEncoderMisread(Effect):
    """The key's encoder misreads while the key bounces on its balance rail."""

    name = "key_encoder_misread"
    summary = ("The key's circular scale is centred on the balance-rail pivot; when the key "
               "lifts off the rail the scale's centre moves and the encoder reads a false "
               "rotation proportional to the lift (thesis Section 4.2, Fig. 4.12). Needs and "
               "switches on key lift-off.")
    parameters = (
        EffectParameter("sensitivity", "rad/m", 63.0, (-500.0, 500.0), True,
                        "false rotation per metre of lift (1/scale radius for a head level "
                        "with the centre; R3213: 15.9 mm)", off=0.0),
    )
    signature = Signature(
        ("key_angle",), ("check", "release"), "shape", None,
        "spikes in the measured key angle alone (the other encoders disagree) when the key "
        "bottoms and when it falls back on the rail")
    implies = ("key_liftoff",)

    def apply(self, build: Build) -> None:
        super().apply(build)
        build.flags["liftoff"] = True

    def measure(self, result: SimResult) -> None:
        lift = result.channels.get("key_lift")
        if lift is None:
            return
        result.channels["key_angle"] = (result.channels["key_angle"]
                                        + self.values["sensitivity"] * (lift - lift[0]))


# start-scan points over the back check's friction coefficient (0-1.5: 0.031 apart). The
# hammer tail sticks on the check or slides down it, so where it comes to rest, and the
# held hammer angle, turns on the friction: the training cost against it is a narrow V
# around the truth, a factor 2 within +-0.04 (measured, issue 39, wide benchmark
# development seed 1489: friction 0.243 hidden, the cost at the true stiffness and damping
# 9.4e-4 at 0.24, 2.0e-3 at 0.21 and 0.28, 3.4e-3 at 0.15, 1.1e-2 at 0.41; seed 1538, 0.248
# hidden: 3.7e-6 at 0.25 against 1.8e-4 at 0.20 and 8.2e-5 at 0.30). Four points, 0.375
# apart, step over the well; the fit then slid along the friction-stiffness valley to a
# stiffness scale of 9-11 and a friction of 0.35-0.38, the training cost 40 % above the
# truth's and the held-out test p = 0.99 where the truth's is 5e-5.
BACKCHECK_FRICTION_SCAN = 48


class BackcheckLaw(Effect):
    """A different contact and friction law where the back check catches the hammer."""

    name = "backcheck_law"
    summary = ("Contact 4 (back check - hammer tail) with its own stiffness, damping and "
               "friction: the thesis blames this contact for its strain mismatch while the "
               "hammer is held (Section 4.1.5).")
    parameters = (
        EffectParameter("stiffness_scale", "1", 1.0, (0.05, 20.0), True,
                        "scale on the felt's stiffness polynomial", off=1.0),
        EffectParameter("friction", "1", 0.434, (0.0, 1.5), True,
                        "kinetic friction coefficient A", "contacts.4.A", off=0.434,
                        scan=BACKCHECK_FRICTION_SCAN),
        EffectParameter("damping", "s/m", 2.446, (0.0, 50.0), True, "damping factor D",
                        "contacts.4.D", off=2.446, log=True),
    )
    signature = Signature(
        ("hammer_angle", "shank_strain"), ("check",), "bias", None,
        "a steady offset of the hammer angle and the shank's static bending while the back "
        "check holds the hammer; a different catch time and rebound")

    def apply(self, build: Build) -> None:
        super().apply(build)
        scale = self.values["stiffness_scale"]
        for coef in ("a", "b", "c"):
            build.params.set(f"contacts.4.{coef}", build.params.get(f"contacts.4.{coef}") * scale)


FELT_CONTACTS = tuple(range(1, 14))


class FeltHysteresis(Effect):
    """Rate-independent felt hysteresis in place of speed-dependent damping."""

    name = "felt_hysteresis"
    summary = ("Every felt contact loads along (1 + h) f_fit(x) and unloads along "
               "(1 - h) f_fit(x) whatever the speed (Stamm's observation; the thesis's open "
               "question), instead of f_fit(x)(1 + D xdot).")
    parameters = (
        EffectParameter("ratio", "1", 0.3, (0.0, 0.95), True, "hysteresis ratio h"),
        EffectParameter("speed_scale", "m/s", 1e-3, (1e-5, 0.05), False,
                        "penetration speed over which loading turns into unloading"),
    )
    signature = Signature(
        ("hammer_angle", "key_angle"), ("string contact", "check", "release"), "shape", None,
        "slow contacts dissipate as much as fast ones: softer blows rebound less and hard "
        "blows more than the damped model says; string contact time and the hammer's rebound "
        "speed change most")

    def apply(self, build: Build) -> None:
        super().apply(build)
        from rig.model import kernel as k

        for cid in FELT_CONTACTS:
            build.contact_overrides[(cid, k.L_TYPE)] = float(k.LAW_HYSTERETIC)
            build.contact_overrides[(cid, k.L_P1)] = self.values["ratio"]
            build.contact_overrides[(cid, k.L_P2)] = self.values["speed_scale"]


class CompliantString(Effect):
    """A compliant string (a spring in series with the hammer felt) in place of the bar."""

    name = "compliant_string"
    summary = ("The string yields under the hammer like a spring in series with the felt "
               "(contact 12), instead of the rigid bar of the thesis's rig.")
    parameters = (
        EffectParameter("stiffness", "N/m", 5e4, (1e3, 1e8), True,
                        "the string's stiffness at the strike point"),
    )
    signature = Signature(
        ("hammer_angle", "shank_strain", "hammer_head_velocity"), ("string contact",),
        "timing", None,
        "a longer string contact and a later, slower rebound; the flight back to the check "
        "starts later")

    def apply(self, build: Build) -> None:
        super().apply(build)
        from rig.model import kernel as k

        build.contact_overrides[(12, k.L_TYPE)] = float(k.LAW_SERIES_SPRING)
        build.contact_overrides[(12, k.L_P1)] = self.values["stiffness"]


BUILTIN: dict[str, type[Effect]] = {cls.name: cls for cls in (
    FlexibleShank, KeyLiftoff, DriveDynamics, LoadCellFilter, KeyEncoderMisread, BackcheckLaw,
    FeltHysteresis, CompliantString)}


def _one_line(text: str) -> str:
    return " ".join(text.split())


def _where(exc: BaseException, path: Path) -> str:
    """'line N: ' of the user's file where ``exc`` was raised (or its syntax error), if known."""
    if isinstance(exc, SyntaxError) and exc.lineno:
        return f"line {exc.lineno}: "
    tb = exc.__traceback__
    line = None
    while tb is not None:
        if Path(tb.tb_frame.f_code.co_filename).resolve() == path.resolve():
            line = tb.tb_lineno
        tb = tb.tb_next
    return f"line {line}: " if line else ""


def _load_class(ref: str) -> type[Effect]:
    target, _, cls_name = ref.rpartition(":")
    if not target or not cls_name:
        raise InputError(f"effect {ref!r}: expected a library name, 'module:Class' or "
                         f"'path.py:Class'")
    if target.endswith(".py"):
        path = Path(target)
        if not path.is_file():
            raise InputError(f"effect {ref!r}: {path}: {not_a_file(path)}")
        mod_name = f"rig_user_effect_{abs(hash(str(path.resolve())))}"
        spec = importlib.util.spec_from_file_location(mod_name, path)
        if spec is None or spec.loader is None:
            raise InputError(f"effect {ref!r}: cannot import {path}")
        module = importlib.util.module_from_spec(spec)
        sys.modules[mod_name] = module
        try:
            spec.loader.exec_module(module)
        except Exception as exc:  # the user's file: any error is theirs, said on one line
            sys.modules.pop(mod_name, None)
            raise InputError(_one_line(f"effect {ref!r}: {path} failed to import: "
                                       f"{_where(exc, path)}{type(exc).__name__}: {exc}")
                             ) from None
    else:
        try:
            module = importlib.import_module(target)
        except Exception as exc:
            raise InputError(_one_line(f"effect {ref!r}: cannot import module {target!r} "
                                       f"({type(exc).__name__}: {exc})")) from None
    cls = getattr(module, cls_name, None)
    if not (isinstance(cls, type) and issubclass(cls, Effect)):
        raise InputError(f"effect {ref!r}: {cls_name} is not a subclass of rig Effect")
    return cls


def make(spec: str | Mapping[str, Any] | Effect, base_dir: Path | None = None) -> Effect:
    """An effect from a name, a ``{name: {param: value}}`` mapping, or an instance."""
    if isinstance(spec, Effect):
        return spec
    values: Mapping[str, Any] = {}
    if isinstance(spec, Mapping):
        if len(spec) != 1:
            raise InputError(f"effect {dict(spec)!r}: expected one name with its parameters")
        ((name, vals),) = spec.items()
        values = vals or {}
        if not isinstance(values, Mapping):
            raise InputError(f"effect {name}: expected a mapping of parameter values")
    elif isinstance(spec, str):
        name = spec
    else:
        raise InputError(f"effect {spec!r}: expected a name or a mapping")
    if name in BUILTIN:
        cls = BUILTIN[name]
    elif ":" in name:
        ref = name
        target = name.rpartition(":")[0]
        if target.endswith(".py") and base_dir is not None and not Path(target).is_absolute():
            ref = f"{base_dir / target}:{name.rpartition(':')[2]}"
        cls = _load_class(ref)
    else:
        raise InputError(f"effect {name!r}: not in the library (known: {sorted(BUILTIN)}); "
                         f"name a user effect as 'module:Class' or 'file.py:Class'")
    return cls(**dict(values))
