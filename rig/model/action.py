"""The grand-piano action model: rest state, blows, stepping, channels (SimResult and the
events of a blow are in rig.model.result, re-exported here).

    model = ActionModel()                                  # rigid base model
    model = ActionModel(effects=["flexible_shank"])        # plus effects
    result = model.simulate(profiles.load("profiles/forte.yaml"))
    result.events["strike"], result.channels["hammer_angle"]

    stepper = model.stepper()                              # for the 500 Hz loop
    chunk = stepper.advance(0.002, f_start=0.0, f_end=1.5)

Swappable parts are constructor arguments: the parameter set, the effects, the
integrator. A failed integration does not raise: the result carries
``status`` and ``message`` (like scipy's ``solve_ivp``).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import math
import time as _time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rig.errors import InputError
from rig.inputs import profiles as _profiles
from rig.inputs.params import Parameters
from rig.model import assembly, modelfile, restcache
from rig.model import kernel as k
from rig.model.effects import Build, Effect, make
from rig.model.integration import by_name
from rig.model.integrators import Advance, DormandPrince, ExtraForce, Integrator
from rig.model.result import SimResult, contact_indicator, find_events  # noqa: F401 - re-exported
from rig.model.vocabulary import (  # noqa: E402,F401 - the vocabulary, re-exported
    ANGLE_CHANNELS,
    CHANNEL_DOCS,
    CHANNEL_UNITS,
    COORDINATES,
    EVENT_DOCS,
    EVENT_ORDER,
    KEY_MOVE_THRESHOLD_M,
)

# rest states by equations_key: models with identical equations (a fit varying an input
# or sensor parameter) settle the action once
_REST_CACHE: dict[bytes, np.ndarray] = {}
# balance-rail placements (offset m, rest state) by the equations before placement
_RAIL_CACHE: dict[bytes, tuple[float, np.ndarray]] = {}
# integrators the rest state settles with when the model uses them (others: dopri54)
SETTLE_WITH_OWN_INTEGRATOR = ("rosenbrock", "dopri54")
HEAD_STRIKE_POINT = "Phh3"


def _remember(cache: dict[bytes, Any], key: bytes, value: Any) -> None:
    if len(cache) >= 256:
        cache.clear()
    cache[key] = value


@dataclass
class Chunk:
    """Output samples produced by one ``Stepper.advance`` call."""

    time: np.ndarray
    states: np.ndarray
    force: np.ndarray
    status: int
    message: str

    def angle(self, name: str) -> np.ndarray:
        return self.states[:, ANGLE_CHANNELS[name]]


@contextlib.contextmanager
def _naming(path: str | Path | None, key: str) -> Iterator[None]:
    """A model file's errors name the file and its key (``model.yaml: effects: ...``)."""
    try:
        yield
    except InputError as exc:
        text = str(exc)
        if path is None or text.startswith(str(path)):
            raise
        text = text if text.startswith(f"{key}:") else f"{key}: {text}"
        raise InputError(f"{path}: {text}") from None


class ActionModel:
    """Base mechanism plus effects, with a swappable integrator."""

    def __init__(self, params: Parameters | None = None,
                 effects: Sequence[str | Mapping[str, Any] | Effect] = (),
                 integrator: Integrator | None = None, *, output_rate: float | None = None,
                 base_dir: Path | None = None) -> None:
        self.params = params.copy() if params is not None else Parameters.default()
        self.effects: list[Effect] = [make(e, base_dir) for e in effects]
        names = [e.name for e in self.effects]
        if len(set(names)) != len(names):
            raise InputError(f"effects: each effect may appear once, got {names}")
        build = Build(self.params.copy())
        for effect in self.effects:
            effect.apply(build)
        self.build = build
        self.packed = self._pack()
        num = build.params.tree["numerics"]
        self.python_forces = [e for e in self.effects if e.runs_in_python()]
        # states that effects add past the kernel's 18: (effect, slice of the state vector)
        self.effect_states: list[tuple[Effect, slice]] = []
        start = k.NY
        for e in self.effects:
            if e.states:
                self.effect_states.append((e, slice(start, start + len(e.states))))
                start += len(e.states)
        self.n_state = start
        if integrator is None:
            integrator = by_name("scipy-LSODA" if self.python_forces else "rosenbrock",
                                 rtol=num["rtol"], max_step=num["max_step"])
        self.integrator = integrator
        self.output_rate = float(output_rate or num["output_rate_hz"])
        if not self.output_rate > 0:
            raise InputError(f"output_rate: expected a positive rate in Hz, got {output_rate}")
        self.atol = np.r_[np.full(k.NQ, num["atol_angle"]), np.full(k.NQ, num["atol_rate"])]
        length = build.params.tree["hammer_shank_beam"]["length"]
        for q, tol in ((k.QU1, num["atol_shank_axial"]),
                       (k.QV1, num["atol_shank_tip"] / length**2),
                       (k.QV2, num["atol_shank_tip"] / length**3)):
            self.atol[q] = tol
            self.atol[k.NQ + q] = tol * num["shank_rate_factor"]
        # the Dahl option's bristles: a thousandth of their presliding (m or rad)
        dahl = build.params.tree["friction_law"].get("dahl", {})
        for zs in range(k.QZ + 1, k.NQ):
            size = dahl.get("presliding_angle" if zs < k.QZ_CONTACT[1] else "presliding", 1e-6)
            self.atol[zs] = 1e-3 * float(size)
            self.atol[k.NQ + zs] = self.atol[zs] / float(dahl.get("damping_time", 1e-3))
        self.atol = np.r_[self.atol, [st.atol for e, _ in self.effect_states for st in e.states]]
        self.active = np.ones(k.NQ, dtype=bool)
        self.active[k.QYK] = build.flags["liftoff"]
        self.active[k.QU1 : k.QV2 + 1] = build.flags["flexible_shank"]
        self.active[k.QZ] = self.packed.arrays.sp[k.S_BRISTLE] > 0.5
        self.active[k.QZ + 1 :] = False
        self.active[k.bristle_coords(self.packed.arrays.cl, self.packed.arrays.jf)] = True
        pts = build.params.tree["points"]
        self._head_pt = np.array(pts["hammer_head"][HEAD_STRIKE_POINT]["at"], dtype=float)
        beam = build.params.tree["hammer_shank_beam"]
        gx, gy = beam["strain_gauge_at"][:2]
        self._gauge = np.array([beam["length"] - gx, gy])
        self._rest: np.ndarray | None = None
        self.balance_rail: dict[str, float] | None = None
        if build.flags["liftoff"]:
            self._place_balance_rail()

    def _pack(self, liftoff: bool | None = None) -> assembly.Packed:
        """The build's arrays (with lift-off as built unless ``liftoff`` says otherwise)."""
        build = self.build
        packed = assembly.pack(build.params,
                               liftoff=build.flags["liftoff"] if liftoff is None else liftoff,
                               flexible_shank=build.flags["flexible_shank"])
        for (cid, col), value in build.contact_overrides.items():
            packed.arrays.cl[packed.contact_ids.index(cid), col] = value
        return packed

    # -- construction from files ------------------------------------------------
    @classmethod
    def from_yaml(cls, path: str | Path | None, *, effects: Sequence[str] = (),
                  integrator: str | None = None) -> ActionModel:
        """A model from a model YAML (rig.model.modelfile: parameters, effects, integrator);
        extra effects appended."""
        data, base = modelfile.read(path)
        params = Parameters.default()
        pspec = data.get("parameters")
        with _naming(path, "parameters"):
            if isinstance(pspec, str):
                params = Parameters.from_file(base / pspec)
            elif isinstance(pspec, Mapping):
                params.update(pspec, source=f"{path}: parameters")
            elif pspec is not None:
                raise InputError(f"{path}: parameters: expected a file name or a mapping")
        eff = list(data.get("effects") or [])
        extra = [e for e in effects if e not in eff]
        # (with effects added on the command line an error may be theirs: not named the file's)
        with _naming(None if extra else path, "effects"):
            model = cls(params, eff + extra, None, base_dir=base)
        ispec = data.get("integrator")
        num = params.tree["numerics"]
        if integrator is not None or ispec is not None:
            spec = dict(ispec) if isinstance(ispec, Mapping) else {}
            # a block without a name keeps the model's default integrator (its tolerances set)
            name = integrator or str(spec.get("name") or model.integrator.name)
            with _naming(path if integrator is None else None, "integrator"):
                model.integrator = by_name(name, rtol=float(spec.get("rtol", num["rtol"])),
                                           max_step=float(spec.get("max_step", num["max_step"])))
        return model

    # -- information -------------------------------------------------------------
    @property
    def effect_names(self) -> list[str]:
        return [e.name for e in self.effects]

    @property
    def coordinates(self) -> list[str]:
        return [n for n, a in zip(COORDINATES, self.active, strict=True) if a]

    @functools.cached_property
    def parameters_yaml(self) -> str:
        """The full parameter set (after effects) as YAML, for run files."""
        return self.build.params.to_yaml()

    def describe(self) -> dict[str, Any]:
        """Metadata for run files: effects, integrator, coordinates (the full parameter
        set is ``parameters_yaml``, dumped only when a run file is written)."""
        return {
            "effects": [e.describe() for e in self.effects],
            "integrator": {"name": self.integrator.name,
                           "rtol": getattr(self.integrator, "rtol", math.nan)},
            "coordinates": self.coordinates,
            "shank_first_mode_hz": self.packed.shank_first_mode_rad_s / (2 * math.pi),
            **({"balance_rail": dict(self.balance_rail)} if self.balance_rail else {}),
        }

    @functools.cached_property
    def equations_key(self) -> bytes:
        """A digest of everything the equations of motion depend on (for caches)."""
        return self._digest()

    def _digest(self) -> bytes:
        h = hashlib.sha1()
        for a in self.packed.arrays:
            arr = np.ascontiguousarray(a)
            h.update(str(arr.shape).encode())
            h.update(arr.tobytes())
        h.update(self.active.tobytes())
        h.update(repr([e.describe() for e in self.python_forces]).encode())
        return h.digest()

    def workspace(self) -> k.Workspace:
        return k.make_workspace(self.packed.n_frames, self.packed.n_contacts)

    def _table_state(self) -> np.ndarray:
        st = self.build.params.tree["initial_state"]
        y = np.zeros(self.n_state)
        for i, name in enumerate(COORDINATES):
            if self.active[i] and name != "y_k" and not name.startswith("z_"):
                y[i] = st[name]
        for e, sl in self.effect_states:
            y[sl] = [s.initial for s in e.states]
        return y

    def accelerations(self, y: np.ndarray, force: float = 0.0) -> np.ndarray:
        """Generalized accelerations at state y (9 coordinates) under a key force (N)."""
        ws = self.workspace()
        dy = np.zeros(k.NY)
        k.rhs(0.0, np.asarray(y, dtype=float), float(force), self.packed.arrays, ws, dy)
        return dy[k.NQ :].copy()

    def energy(self, y: np.ndarray) -> tuple[float, float, float]:
        """(kinetic, gravitational potential, shank strain) energy in J at state y."""
        kin, pot, ela = k.energy(np.asarray(y, dtype=float), self.packed.arrays,
                                 self.workspace())
        return float(kin), float(pot), float(ela)

    # -- rest state ------------------------------------------------------------------
    def rest_state(self) -> np.ndarray:
        """Static equilibrium under gravity with zero key force (state vector, kernel.NY)."""
        if self._rest is None and self.equations_key in _REST_CACHE:
            self._rest = _REST_CACHE[self.equations_key].copy()
        if self._rest is None:
            disk = self._disk_key("rest", self.equations_key)
            rest = restcache.load(disk, self.n_state)  # (settled by an earlier process)
            if rest is None:
                rest = self._polish(self._settle())
                restcache.store(disk, rest)
            self._rest = rest
            _remember(_REST_CACHE, self.equations_key, self._rest.copy())
        return self._rest.copy()

    def _disk_key(self, kind: str, equations: bytes) -> str | None:
        """The on-disk cache's key: the equations, starting state, tolerances, integrator
        and the source of effects that run in Python (None: not cacheable on disk)."""
        i = self.integrator  # (settles the action only when effects run in Python)
        settle = (f"{i.name} {getattr(i, 'rtol', '')} {getattr(i, 'max_step', '')}"
                  if self.python_forces else "")
        code = [restcache.source_of(type(e)) for e in self.python_forces]
        if any(c is None for c in code):
            return None
        return restcache.key(kind, [equations, self._table_state(), self.atol, settle,
                                    *(c for c in code if c is not None)])

    def _settle(self, arrays: k.Model | None = None) -> np.ndarray:
        """The state after 0.4 s under gravity from Table 3.2 (friction and damping remove
        the energy), velocities zeroed."""
        extra = self.extra_force()
        # the model's own integrator where it is the default compiled one: a first use then
        # compiles one integrator, not two (the polish below makes the result the same)
        own = extra is not None or self.integrator.name in SETTLE_WITH_OWN_INTEGRATOR
        integ = self.integrator if own else DormandPrince(rtol=1e-6, max_step=1e-3)
        adv = integ.advance(arrays or self.packed.arrays, self.workspace(), self._table_state(),
                            0.0, 0.4, 1e-5, np.zeros(1), np.zeros(1), np.zeros(0), self.atol,
                            extra)
        y = adv.y.copy()
        y[k.NQ : k.NY] = 0.0
        return y

    def _polish(self, y: np.ndarray, arrays: k.Model | None = None,
                active: np.ndarray | None = None) -> np.ndarray:
        """Solve accelerations (and effect states' rates) = 0 at zero velocity from y."""
        arrays = arrays or self.packed.arrays
        active = self.active if active is None else active
        ws = self.workspace()
        extra = self.extra_force()
        idx = np.r_[np.flatnonzero(active), np.arange(k.NY, self.n_state)]
        dy = np.zeros(self.n_state)

        def residual(x: np.ndarray) -> np.ndarray:
            yy = y.copy()
            yy[idx] = x
            if extra is not None:
                ws.qx[:], dy[k.NY :] = extra(0.0, yy)
            k.rhs(0.0, yy, 0.0, arrays, ws, dy)
            ws.qx[:] = 0.0
            return np.r_[dy[k.NQ + idx[idx < k.NQ]], dy[k.NY :]]

        from scipy.optimize import least_squares  # (lazy: 0.7 s of import, rarely needed)

        sol = least_squares(residual, y[idx], xtol=1e-14, ftol=1e-14, gtol=1e-14,
                            x_scale=1e-3)
        out = y.copy()
        out[idx] = sol.x
        return out

    def _place_balance_rail(self) -> None:
        """Place the balance rail so that the key rests at the revolute key's height.

        Thesis 4.2: the contact point on the ground was chosen so that the key is
        at the same height at rest as with a revolute joint. The key pivot is put
        at y0 (y_k = 0) with every body at the revolute model's rest, and contact
        14's ground feature is moved vertically until the rail carries the key
        there (under the model's own felt stiffness). The moved point is written
        into the parameter set and recorded in ``balance_rail``.
        """
        ids = self.packed.contact_ids
        if 14 not in ids:
            return
        row = ids.index(14)
        spec = next(c for c in self.build.params.tree["contacts"] if int(c["id"]) == 14)
        refs = (str(spec["first"]), str(spec["second"]))
        sides = [i for i, ref in enumerate(refs) if ref.startswith("ground.")]
        if not sides or not np.any(self.packed.arrays.cl[row, [k.L_A, k.L_B, k.L_C]] > 0):
            return  # no ground feature, or a rail without stiffness: nothing to place
        side = sides[0]
        key = self._digest()
        if key not in _RAIL_CACHE:
            disk = self._disk_key(f"rail{row},{side}", key)
            stored = restcache.load(disk, 1 + self.n_state)
            if stored is None:
                offset, rest = self._solve_rail(row, side)
                restcache.store(disk, np.r_[offset, rest])
            else:
                offset, rest = float(stored[0]), stored[1:].copy()
            _remember(_RAIL_CACHE, key, (offset, rest))
        offset, rest = _RAIL_CACHE[key]
        solved = [a.copy() for a in self.packed.arrays]
        solved[2][row, side, k.C_Y] += offset
        path = f"points.{refs[side]}.at"
        x, y = self.build.params.get(path)
        self.build.params.set(path, [x, y + offset])
        self.packed = self._pack()
        self.balance_rail = {"y_m": float(self.packed.arrays.cf[row, side, k.C_Y]),
                             "offset_m": offset}
        if all(np.array_equal(a, b) for a, b in zip(solved, self.packed.arrays, strict=True)):
            self._rest = rest.copy()  # (else another contact shares the point: solve again)

    def _solve_rail(self, row: int, side: int) -> tuple[float, np.ndarray]:
        """(offset of contact 14's ground feature in m, rest state) with the pivot at y0."""
        revolute = self._pack(liftoff=False)
        fixed = self.active.copy()
        fixed[k.QYK] = False
        y = self._polish(self._settle(revolute.arrays), revolute.arrays, fixed)
        y[k.QYK] = 0.0
        arrays = k.Model(*(a.copy() for a in self.packed.arrays))
        base = float(arrays.cf[row, side, k.C_Y])
        ws, dy = self.workspace(), np.zeros(k.NY)
        extra = self.extra_force()
        q_force = extra(0.0, y)[0] if extra is not None else np.zeros(k.NQ)

        def lift_acceleration(offset: float) -> float:
            arrays.cf[row, side, k.C_Y] = base + offset
            ws.qx[:] = q_force
            k.rhs(0.0, y[: k.NY], 0.0, arrays, ws, dy)
            return float(dy[k.NQ + k.QYK])

        # the rail pushes harder the higher it sits: 10 mm down the key hangs in the air
        lo, hi = -0.01, 0.01
        if not lift_acceleration(lo) < 0 < lift_acceleration(hi):
            raise InputError("contacts.14: the balance rail cannot hold the key at rest "
                             "within 10 mm of its given height")
        from scipy.optimize import brentq

        offset = float(brentq(lift_acceleration, lo, hi, xtol=1e-14, rtol=1e-12))
        arrays.cf[row, side, k.C_Y] = base + offset
        return offset, self._polish(y, arrays)

    # -- simulation --------------------------------------------------------------------
    def stepper(self, y0: np.ndarray | None = None, t0: float = 0.0, *,
                keep_history: bool = True) -> Stepper:
        """A state that advances piece by piece (the simulated rig's 500 Hz loop, which passes
        ``keep_history=False``: its memory stays flat however long it runs)."""
        return Stepper(self, self.rest_state() if y0 is None else np.asarray(y0, float), t0,
                       keep_history=keep_history)

    def simulate(self, profile: _profiles.Profile, duration: float | None = None, *,
                 y0: np.ndarray | None = None,
                 progress: Callable[[float, float], None] | None = None,
                 chunk: float = 0.05) -> SimResult:
        """Simulate a blow under the profile's key force, from rest unless y0 is given."""
        duration = profile.duration if duration is None else float(duration)
        if not duration > 0:
            raise InputError(f"duration: expected a positive time in s, got {duration}")
        profile = self._input_profile(profile)
        ft, ff = self.input_force(profile)
        step = self.stepper(y0)
        wall0 = _time.perf_counter()
        t = 0.0
        while t < duration - 1e-12:
            t_next = min(duration, t + chunk)
            c = step.advance_table(t_next, ft, ff)
            t = t_next
            if progress is not None:
                progress(t, duration)
            if c.status != 0:
                break
        res = step.result()
        res.stats["wall_time_s"] = _time.perf_counter() - wall0
        res.stats["simulated_time_s"] = t
        res.metadata["profile"] = profile.to_metadata()
        return res

    def _input_profile(self, profile: _profiles.Profile) -> _profiles.Profile:
        """A force profile as it is; a motion profile goes to the effect that plays it
        (fingertip) and the key force from the table is zero."""
        movers = [e for e in self.effects if hasattr(e, "drive_by_motion")]
        if getattr(profile, "kind", "force") != "motion":
            for e in movers:
                e.drive_by_motion(self, None)
            return profile
        if not movers:
            raise InputError(f"{profile.source}: kind: motion needs the fingertip effect "
                             f"(-e fingertip)")
        movers[0].drive_by_motion(self, profile)
        return _profiles.Profile(profile.time, np.zeros_like(profile.force), profile.name,
                                 profile.description, profile.source, "motion")

    def input_force(self, profile: _profiles.Profile,
                    resolution: float = 1e-4) -> tuple[np.ndarray, np.ndarray]:
        """Force knots that reach the key after every effect's input transform."""
        ft, ff = profile.time.astype(float), profile.force.astype(float)
        transforming = [e for e in self.effects
                        if type(e).transform_input is not Effect.transform_input]
        if transforming:
            ft = np.arange(0.0, profile.duration + resolution / 2, resolution)
            ff = profile.at(ft)
            for e in transforming:
                ff = np.asarray(e.transform_input(ft, ff), dtype=float)
        return ft, ff

    def extra_force(self) -> ExtraForce | None:
        """Python-level effects' generalized forces and state rates, or None if none."""
        if not self.python_forces:
            return None
        slices = {id(e): sl for e, sl in self.effect_states}

        def total(t: float, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            force = np.zeros(k.NQ)
            dz = np.zeros(self.n_state - k.NY)
            # effects see the mechanism's 9 coordinates (not the bristle deflection)
            q, qd = y[: k.NQ_MECH], y[k.NQ : k.NQ + k.NQ_MECH]
            for e in self.python_forces:
                sl = slices.get(id(e))
                if sl is None:
                    f = e.generalized_force(t, q, qd)
                else:
                    z = y[sl]
                    f = e.generalized_force(t, q, qd, z)
                    dz[sl.start - k.NY : sl.stop - k.NY] = e.state_derivative(t, q, qd, z)
                if f is not None:
                    force[: k.NQ_MECH] += np.asarray(f, dtype=float)
            return force, dz

        return total

    def channels(self, time: np.ndarray, states: np.ndarray,
                 force: np.ndarray) -> dict[str, np.ndarray]:
        """Output channels (SI) from sampled states and key forces."""
        n = time.shape[0]
        xo = np.zeros((k.N_X, n))
        co = np.zeros((k.N_CONTACT_OUT, n, self.packed.n_contacts))
        if n:
            k.sample_outputs(self.packed.arrays, self.workspace(), states, force,
                             self._head_pt, self._gauge, xo, co)
        rest_keytop = self.keytop_rest()
        ch: dict[str, np.ndarray] = {"time": time.copy(), "force": force.copy()}
        for name, qi in ANGLE_CHANNELS.items():
            ch[name] = states[:, qi].copy()
            ch[name.replace("_angle", "_angular_velocity")] = states[:, k.NQ + qi].copy()
        ch["hammer_head_velocity"] = xo[k.X_HEAD_VY]
        ch["hammer_head_x"] = xo[k.X_HEAD_X]
        ch["hammer_head_y"] = xo[k.X_HEAD_Y]
        ch["key_dip"] = rest_keytop - xo[k.X_KEYTOP_Y]
        ch["contact_force"] = co[k.O_FN]
        ch["contact_friction"] = co[k.O_FT]
        ch["contact_penetration"] = co[k.O_PEN]
        ch["contact_penetration_rate"] = co[k.O_PENRATE]
        ch["contact_slip"] = co[k.O_SLIP]
        ch["contact_point_x"] = co[k.O_PX]
        if self.build.flags["flexible_shank"]:
            ch["shank_strain"] = xo[k.X_STRAIN]
            ch["shank_tip_deflection"] = xo[k.X_TIP_DEFL]
        if self.build.flags["liftoff"]:
            ch["key_lift"] = xo[k.X_KEY_LIFT]
        for e, sl in self.effect_states:
            for st, col in zip(e.states, range(sl.start, sl.stop), strict=True):
                ch[f"{e.name}_{st.name}"] = states[:, col].copy()
        return ch

    def keytop_rest(self) -> float:
        rest = self.rest_state()[None, :]
        xo = np.zeros((k.N_X, 1))
        co = np.zeros((k.N_CONTACT_OUT, 1, self.packed.n_contacts))
        k.sample_outputs(self.packed.arrays, self.workspace(), rest, np.zeros(1),
                         self._head_pt, self._gauge, xo, co)
        return float(xo[k.X_KEYTOP_Y, 0])

    def result_from_samples(self, time: np.ndarray, states: np.ndarray, force: np.ndarray,
                            status: int = 0, message: str = "ok") -> SimResult:
        ch = self.channels(time, states, force)
        units = dict(CHANNEL_UNITS)
        units.update({f"{e.name}_{st.name}": st.units for e, _ in self.effect_states
                      for st in e.states})
        res = SimResult(time=ch["time"], channels=ch, units=units, events={},
                        status=status, message=message, contact_ids=self.packed.contact_ids)
        for e in self.effects:
            e.add_channels(res)
        # events are facts of the mechanism: found before sensor effects alter channels
        cl = self.packed.arrays.cl
        damping = {cid: (0.0 if int(cl[i, k.L_TYPE]) == k.LAW_HYSTERETIC else float(cl[i, k.L_D]))
                   for i, cid in enumerate(self.packed.contact_ids)}
        res.events = find_events(res, damping=damping)
        for e in self.effects:
            e.measure(res)
        res.model = self
        res.metadata["model"] = self.describe()
        res.metadata["contact_names"] = list(self.packed.contact_names)
        return res


class Stepper:
    """The model's state advanced piece by piece, with outputs on a fixed grid."""

    def __init__(self, model: ActionModel, y0: np.ndarray, t0: float = 0.0, *,
                 keep_history: bool = True) -> None:
        self.model = model
        self.keep_history = keep_history  # False: only each chunk is returned, none kept
        self.y = np.array(y0, dtype=float)
        self.t = float(t0)
        self.h = 1e-5
        self._ws = model.workspace()
        self._times: list[np.ndarray] = []
        self._states: list[np.ndarray] = []
        self._forces: list[np.ndarray] = []
        self._dt = 1.0 / model.output_rate
        self._next = int(math.floor(self.t / self._dt + 1e-9)) + 1
        self.status = 0
        self.message = "ok"
        self.stats = {"steps": 0.0, "rejected": 0.0, "rhs": 0.0}
        if self.t == 0.0 and keep_history:  # the initial sample
            self._times.append(np.zeros(1))
            self._states.append(self.y[None, :].copy())
            self._forces.append(np.zeros(1))

    def advance(self, t_end: float, f_start: float, f_end: float | None = None) -> Chunk:
        """Advance to t_end with the key force going linearly from f_start to f_end (N)."""
        if f_end is None:
            f_end = f_start
        for name, v in (("f_start", f_start), ("f_end", f_end), ("t_end", t_end)):
            if not math.isfinite(v):
                raise InputError(f"{name}: expected a finite number, got {v}")
        return self.advance_table(t_end, np.array([self.t, t_end]), np.array([f_start, f_end]))

    def advance_table(self, t_end: float, force_t: np.ndarray, force_f: np.ndarray) -> Chunk:
        """Advance to t_end under the piecewise-linear force (force_t s, force_f N)."""
        if self.status != 0:
            raise RuntimeError(f"the simulation has failed ({self.message}); it cannot advance")
        if t_end <= self.t:
            raise InputError(f"t_end: expected a time after {self.t} s, got {t_end}")
        last = int(math.floor(t_end / self._dt + 1e-9))
        out_t = np.arange(self._next, last + 1) * self._dt
        adv: Advance = self.model.integrator.advance(
            self.model.packed.arrays, self._ws, self.y, self.t, t_end, self.h,
            np.ascontiguousarray(force_t, dtype=float), np.ascontiguousarray(force_f, dtype=float),
            out_t, self.model.atol, self.model.extra_force())
        n = adv.out.shape[0]
        times = out_t[:n]
        forces = np.interp(times, force_t, force_f)
        if self.keep_history:
            self._times.append(times)
            self._states.append(adv.out)
            self._forces.append(forces)
        self._next += n
        self.stats["steps"] += adv.n_steps
        self.stats["rejected"] += adv.n_rejected
        self.stats["rhs"] += adv.n_rhs
        if adv.success:
            self.y = adv.y
            self.t = t_end
            self.h = adv.step
        else:
            self.status = adv.status
            reached = times[-1] if n else self.t
            self.message = f"{adv.message} near t = {reached:.6f} s"
        return Chunk(times, adv.out, forces, adv.status, adv.message)

    def result(self) -> SimResult:
        """Every sample produced so far, with channels and events."""
        if not self.keep_history:
            raise RuntimeError("this stepper keeps no history (keep_history=False)")
        time = np.concatenate(self._times) if self._times else np.zeros(0)
        states = (np.concatenate(self._states) if self._states
                  else np.zeros((0, self.model.n_state)))
        force = np.concatenate(self._forces) if self._forces else np.zeros(0)
        res = self.model.result_from_samples(time, states, force, self.status, self.message)
        res.stats.update(self.stats)
        return res
