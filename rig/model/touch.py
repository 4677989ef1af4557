"""The feel of the action as a piano technician measures it: touch weights at the key front.

Figures (docs/touch.md has the definitions and the method):

- ``down_weight``: the least static weight at the key front that keeps the key going down
  through the middle of the touch stroke, every joint's and contact's friction opposing
  the descent;
- ``up_weight``: the most weight at which the key still comes up through the middle of the
  stroke, friction opposing the return;
- ``down_weight_stroke`` / ``up_weight_stroke``: the same over the whole touch stroke (the
  largest down force, the smallest up force): the weights that carry the key all the way
  down, and let it return all the way up;
- ``balance_weight`` (DW + UW) / 2 and ``friction`` (DW - UW) / 2;
- ``strike_weight``: the hammer's weight at its strike point (pivot -> striking-felt centre
  level, centre pin supported), and ``hammer_mass``;
- ``front_weight``: the key's own weight at the key front (key alone on its balance pin);
- ``key_ratio``: capstan contact's horizontal arm over the key front's, about the balance pin;
- ``action_ratio``: strike-point rise per key-front dip over the touch stroke;
- ``inertia_mass``: the mass a finger accelerates at the key front, mid-stroke (twice the
  action's kinetic energy at 1 m/s of key-front speed along the press): a key-front
  acceleration a needs this mass times a on top of the static force.

Method: quasi-static equilibria along a slow press. The frictionless path is solved point
by point (every active coordinate's generalized force zero with the key front held at the
dip). The presses with friction are then solved step by step, down from rest and back up
from the stroke's end, each step implicitly (backward Euler at a vanishing press speed):
every joint's and contact's friction is evaluated at the slip the step itself makes, so
friction opposes the actual slip, a joint or contact whose slip in the step stays under
a tolerance of a tenth of a nanometre (a nanoradian) sticks and carries what statics asks
of it up to its sliding limit, and a felt contact opens or closes wherever its
compression says. The friction laws (Eq. 3.6 and 3.8) are taken as Coulomb's: the kinetic
coefficient A (contacts) and torque E (pins) with their threshold speeds set to those
tolerances per step and without the static hump (B1, F1), solved by continuation from
10^4 times wider tolerances down (each solve starting from the wider one's answer, the
slips of what sticks shrunk with the width); a step that finds no equilibrium so starts
again from steps in which one pin or one contact sticks (the jack that the knuckle's
friction drags off its stop on the return, with a weak repetition spring). The worked key
(``Touch.worked_key``): the key let go after that return (the force held at zero, friction
carried over) comes to a rest of its own, and a second press from there gives the weights
a press of a worked key measures. The return from where a press in time leaves the key
(``stop_returns``): the model, every friction element sticking, simulated under a force
profile, and from its state at the stop the force lowered quasi-statically as above (the
key that runs into its stop leaves the jack off its whippen stop; docs/touch.md, "The
up-weight after a press in time").
Forces in N; weights in grams-force (N / G0 x 1000).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from rig.errors import InputError

if TYPE_CHECKING:
    from rig.model.action import ActionModel

G0 = 9.80665  # m/s^2, standard gravity: grams-force at the key front = N / G0 * 1000
STEP_M = 2.5e-4  # key-front dip between the stroke's points
FIRST_M = 2.5e-4  # the stroke's first point: the key off its back felt, the hammer off its rail
MAX_DIP_M = 0.02  # no stroke goes past this even without a stop
PRESS_SPEED = 1e-6  # m/s at the key front: the press's speed (inertia and damping vanish)
STEP_S = STEP_M / PRESS_SPEED  # one step's duration (s): a step's increments over it are speeds
SLIP_TOL_M = 1e-10  # a contact slipping less than this in a step sticks (Coulomb's width)
TURN_TOL_RAD = 1e-9  # a pin turning less than this in a step sticks
NEWTON_TOL = 1e-12  # N m: Newton's steps stop under this imbalance
FORCE_TOL = 1e-8  # N m: the largest generalized-force imbalance a step with friction may leave
SPLITS = 3  # a step that finds no equilibrium is halved up to this many times
RETURN_STEPS = 10  # the return from the stop takes the travel threshold in this many steps
LADDER = (1e4, 1e3, 1e2, 1e1, 1.0)  # the tolerances' continuation, widest first
# contacts that end the touch stroke when they close (ids of rig/data/action-parameters.yaml)
STROKE_STOPS = {2: "key meets the front punching", 8: "jack toe meets the let-off button",
                11: "repetition lever meets the drop screw"}
# contacts that must be open at the stroke's start (rest supports the press lifts off)
REST_SUPPORTS = {3: "key back felt", 13: "hammer rest rail"}
FIGURES = ("down_weight", "up_weight", "balance_weight", "friction", "down_weight_stroke",
           "up_weight_stroke", "strike_weight", "hammer_mass", "front_weight", "key_ratio",
           "action_ratio", "inertia_mass")
FIGURE_DOCS = {
    "down_weight": "least weight at the key front that keeps the key going down, mid-stroke "
                   "(friction opposing)",
    "up_weight": "most weight at the key front at which the key still comes up, mid-stroke "
                 "(friction opposing)",
    "down_weight_stroke": "least weight that takes the key down through the whole touch stroke",
    "up_weight_stroke": "most weight at which the key returns through the whole touch stroke",
    "balance_weight": "(down-weight + up-weight) / 2",
    "friction": "(down-weight - up-weight) / 2",
    "strike_weight": "hammer's weight at its strike point, line pivot -> striking felt level",
    "hammer_mass": "mass of the hammer (flange/base, shank, head)",
    "front_weight": "key's own weight at the key front, key alone on its balance pin",
    "key_ratio": "capstan contact's horizontal arm / key front's, about the balance pin",
    "action_ratio": "strike-point rise per key-front dip over the touch stroke",
    "inertia_mass": "mass felt at the key front when accelerating the key, mid-stroke "
                    "(2 x kinetic energy at 1 m/s)",
}
UNITS = {"down_weight": "g", "up_weight": "g", "down_weight_stroke": "g",
         "up_weight_stroke": "g", "balance_weight": "g", "friction": "g",
         "strike_weight": "g", "hammer_mass": "g", "front_weight": "g", "key_ratio": "1",
         "action_ratio": "1", "inertia_mass": "g"}
HAMMER_FRAMES = (6, 7)  # kernel frames F_HAMMER, F_HEAD (the hammer's bodies)


@dataclass
class Touch:
    """The touch figures of one model (grams-force where a weight, N alongside)."""

    figures: dict[str, float]
    newtons: dict[str, float]
    dip_m: np.ndarray            # the stroke's key-front dips
    down_n: np.ndarray           # key force to press down at each dip (N)
    up_n: np.ndarray             # key force held while the key returns at each dip (N)
    frictionless_n: np.ndarray   # key force in equilibrium with friction removed (N)
    stroke_end: str              # what ended the stroke
    key_front_radius_m: float    # horizontal arm of the key front about the balance pin, rest
    friction_shares_g: dict[str, float] = field(default_factory=dict)  # down press, mid-stroke
    method: dict[str, Any] = field(default_factory=dict)
    # the presses' states (speeds = each step's increments over STEP_S): the down press at
    # dip_m and then at the turn one step further (its force last in turn_force_n), the up
    # press at dip_m
    down_states: np.ndarray = field(default_factory=lambda: np.empty(0))
    up_states: np.ndarray = field(default_factory=lambda: np.empty(0))
    turn_force_n: float = math.nan
    # the worked key's press (``_worked``): its rest, its down press's dips and forces to the
    # turn, the up force one step back; empty when not computed
    worked: dict[str, Any] = field(default_factory=dict)

    def worked_key(self) -> dict[str, float]:
        """What a slow press of a worked key measures, in grams-force at the key front (and
        the dips, m): the key pressed down through its stroke and let go back to rest first,
        the friction's state carried over; then the down force where it has gone the
        stroke's first step (0.25 mm) from that rest and the up force one step back from
        where the press stops (docs/touch.md, "The worked key")."""
        w = self.worked
        if not w:
            raise ValueError("the worked key's press was not computed (measure(worked=True))")
        return {"down_weight": grams(w["down_N"][0]), "up_weight": grams(w["up_N"]),
                "down_dip_m": w["dip_m"][0], "up_dip_m": w["up_dip_m"],
                "rest_dip_m": w["rest_dip_m"]}

    def from_rest(self) -> dict[str, float]:
        """What a slow press from rest measures, in grams-force at the key front (and the
        dips, m): the down force at the stroke's first point (the key has gone its first
        step, 0.25 mm, from rest) and the up force at its last (one step back from where
        the press stopped). `rig measure touch`'s travel rule reads the weights there: once
        the key goes, the balance force falls along the stroke, so it runs to its stop and
        back to rest and no mid-stroke weight can be read (docs/touch.md, "On the rig")."""
        return {"down_weight": grams(float(self.down_n[0])),
                "up_weight": grams(float(self.up_n[-1])),
                "down_dip_m": float(self.dip_m[0]), "up_dip_m": float(self.dip_m[-1])}

    def to_json(self) -> dict[str, Any]:
        return {
            "figures": {n: {"value": self.figures[n], "units": UNITS[n],
                            **({"newtons": self.newtons[n]} if n in self.newtons else {}),
                            "definition": FIGURE_DOCS[n]} for n in FIGURES},
            "key_front_radius_m": self.key_front_radius_m,
            "stroke": {"dip_m": self.dip_m.tolist(), "down_N": self.down_n.tolist(),
                       "up_N": self.up_n.tolist(), "frictionless_N": self.frictionless_n.tolist(),
                       "end": self.stroke_end},
            "friction_shares_g": self.friction_shares_g,
            "method": self.method,
            **({"worked": {**self.worked_key(), "stroke": {
                "dip_m": self.worked["dip_m"][:-1], "down_N": self.worked["down_N"]},
                "turn_dip_m": self.worked["turn_dip_m"],
                "turn_force_N": self.worked["turn_force_N"],
                "up_N": self.worked["up_N"]}} if self.worked else {}),
        }


def acceleration_force(result: Touch, accel: float) -> float:
    """Force (N) at the key front, on top of the static one, that accelerates the key front
    at ``accel`` m/s^2 mid-stroke from rest along the press: ``inertia_mass`` x accel (the
    velocity-squared terms vanish at rest)."""
    return result.figures["inertia_mass"] * 1e-3 * accel


def grams(force_n: float) -> float:
    """Grams-force of a force in N (a technician's weight of that many grams at G0)."""
    return force_n / G0 * 1e3


class _Statics:
    """Quasi-static equilibria of a model at a held key-front dip."""

    def __init__(self, model: ActionModel) -> None:
        from rig.model import kernel as k

        if model.effect_states:
            names = ", ".join(e.name for e, _ in model.effect_states)
            raise InputError(f"model: effects: {names} adds state variables; rig touch solves "
                             f"the mechanism's statics only (leave it out)")
        self.k = k
        self.model = model
        self.ws = model.workspace()
        self.extra = model.extra_force()
        self.coords = np.array([i for i in np.flatnonzero(model.active) if i < k.QZ])
        # each coordinate's size in the integrator's terms (the shank's bending coordinates
        # are 1e3-1e4 times an angle's): the solver's variable scaling, the residual's units
        self.scale = model.atol[self.coords] / model.atol[k.QK]
        base = model.packed.arrays
        # the friction laws as Coulomb's, their widths from LADDER's widest to the target
        self.ladder = [self._arrays(base, friction=True, widen=w) for w in LADDER]
        self.sliding = self.ladder[-1]
        self.frictionless = self._arrays(base, friction=False)
        sp = base.sp
        self.pivot_y0 = float(sp[k.S_PIVY0])
        self.px, self.py = float(sp[k.S_KEYPX]), float(sp[k.S_KEYPY])
        self.rest = model.rest_state()
        # the rest state's mass matrix over the solved coordinates (residuals in forces)
        k.energy(np.r_[self.rest[: k.NQ], np.zeros(k.NQ)], model.packed.arrays, self.ws)
        self.mass = self.ws.M[np.ix_(self.coords, self.coords)].copy()
        self.keytop_rest = self.keytop_y(self.rest)
        self.dy = np.zeros(k.NY)
        # which sticking start (``_sticking_starts``' index) balanced the last step that
        # needed one: tried first on the next step, from its increments
        self.stuck_start: int | None = None
        self.ids = list(model.packed.contact_ids)
        # the striking felt's centre in the head frame and the strain gauge (as ActionModel)
        tree = model.build.params.tree
        from rig.model.action import HEAD_STRIKE_POINT

        self.head_pt = np.array(tree["points"]["hammer_head"][HEAD_STRIKE_POINT]["at"], float)
        beam = tree["hammer_shank_beam"]
        self.gauge = np.array([beam["length"] - beam["strain_gauge_at"][0],
                               beam["strain_gauge_at"][1]])

    def _arrays(self, base: Any, friction: bool, widen: float = 1.0) -> Any:
        k = self.k
        a = k.Model(*(x.copy() for x in base))
        cl, jf = a.cl, a.jf
        if not friction:
            cl[:, k.L_MU_A] = 0.0
            cl[:, k.L_MU_S] = 0.0
            cl[:, k.L_FLAW] = k.FRICTION_SMOOTHED
            jf[:, 0] = 0.0
        else:
            for i in range(cl.shape[0]):
                if cl[i, k.L_MU_A] > 0 and cl[i, k.L_FLAW] == k.FRICTION_SMOOTHED \
                        and cl[i, k.L_B1] != 0 and cl[i, k.L_B2] <= 0:
                    raise InputError(f"contacts.{self.model.packed.contact_ids[i]}: B1 > 0 "
                                     f"with B2 = 0 is viscous friction without a sliding "
                                     f"limit; rig touch needs B2 > 0")
            # Coulomb's law: the kinetic coefficient A (the bristle law's too), no static hump,
            # the threshold speeds those at which a step slips its tolerance
            cl[:, k.L_FLAW] = k.FRICTION_SMOOTHED
            cl[:, k.L_B1] = 0.0
            cl[:, k.L_VT] = SLIP_TOL_M * widen / STEP_S
            jf[:, 1] = 0.0
            jf[:, 3] = TURN_TOL_RAD * widen / STEP_S
        # the bristle laws (the back check's, the Dahl option's) are taken as Coulomb's too:
        # no bristle coordinate
        cl[:, k.L_ZSLOT] = 0.0
        jf[:, k.J_LAW] = 0.0
        a.sp[k.S_BRISTLE] = 0.0
        return a

    def keytop_y(self, y: np.ndarray) -> float:
        k = self.k
        th = y[k.QK]
        return self.pivot_y0 + y[k.QYK] + math.sin(th) * self.px + math.cos(th) * self.py

    def front_radius(self, y: np.ndarray) -> float:
        th = y[self.k.QK]
        return math.cos(th) * self.px - math.sin(th) * self.py

    def solve(self, dip: float, guess: np.ndarray, f0: float, arrays: Any,
              qd: np.ndarray | None = None) -> tuple[np.ndarray, float, float]:
        """(state, key force N, worst residual) in equilibrium with the key front at dip."""
        from scipy.optimize import root

        k, c, ws, dy = self.k, self.coords, self.ws, self.dy
        target = self.keytop_rest - dip
        y = guess.copy()
        if qd is not None:
            y[k.NQ : k.NY] = qd
        else:
            y[k.NQ : k.NY] = 0.0

        def residual(x: np.ndarray) -> np.ndarray:
            y[c] = x[:-1]
            ws.qx[:] = self.extra(0.0, y)[0] if self.extra is not None else 0.0
            k.rhs(0.0, y[: k.NY], float(x[-1]), arrays, ws, dy)
            # generalized forces (M qdd) would scale better, but qdd = 0 is the same root
            return np.r_[dy[k.NQ + c], (self.keytop_y(y) - target) * 1e3]

        # start from the guess turned to the target dip
        x0 = np.r_[guess[c], f0]
        x0[list(c).index(k.QK)] += (target - self.keytop_y(guess)) / self.front_radius(guess)
        sol = root(residual, x0, method="hybr",
                   options={"xtol": 1e-13, "diag": np.r_[1.0 / self.scale, 1.0]})
        r = residual(sol.x)
        r[:-1] /= self.scale
        ws.qx[:] = 0.0
        y[c] = sol.x[:-1]
        return y.copy(), float(sol.x[-1]), float(np.max(np.abs(r)))

    def step(self, dip: float, prev: np.ndarray, guess: np.ndarray, f0: float,
             hint: np.ndarray | None = None,
             held: float | None = None) -> tuple[np.ndarray, float, float]:
        """One implicit step of the press with friction: (state, key force N, worst
        generalized-force imbalance N m) in equilibrium with the key front at ``dip``,
        reached from the state ``prev`` in STEP_S seconds, each friction evaluated at the
        slip of the step (the state's speeds are the step's increments over STEP_S).
        ``hint``: the previous step's increments and force, tried first (what stuck then
        mostly sticks now). ``held``: a key force (N) to hold instead of the dip (the key
        let go to it: the dip is then the answer's, ``dip`` only the guess's)."""
        from scipy.optimize import root

        k, c, ws, dy = self.k, self.coords, self.ws, self.dy
        target = self.keytop_rest - dip
        y = prev.copy()
        y[k.NQ : k.NY] = 0.0

        def residual(x: np.ndarray, arrays: Any) -> np.ndarray:
            y[c] = prev[c] + x[:-1]
            y[k.NQ + c] = x[:-1] / STEP_S
            ws.qx[:] = self.extra(0.0, y)[0] if self.extra is not None else 0.0
            k.rhs(0.0, y[: k.NY], float(x[-1]), arrays, ws, dy)
            # the generalized forces' imbalance (the accelerations times the rest state's
            # mass matrix; the same root), each coordinate's in N m per its scale
            return np.r_[(self.mass @ dy[k.NQ + c]) * self.scale,
                         (self.keytop_y(y) - target) * 1e3 if held is None
                         else x[-1] - held]

        def jacobian(x: np.ndarray, arrays: Any, widen: float) -> np.ndarray:
            # central differences a hundredth of the tolerance wide: they resolve a stuck
            # joint's or contact's law (hybr's own steps would be lost in the rounding of
            # the positions)
            h = np.r_[self.scale * TURN_TOL_RAD * widen * 1e-2, 1e-6]
            out = np.empty((x.size, x.size))
            for j in range(x.size):
                e = np.zeros(x.size)
                e[j] = h[j]
                out[:, j] = (residual(x + e, arrays) - residual(x - e, arrays)) / (2 * h[j])
            return out

        # unknowns: the step's increments (so that differences resolve the tolerances)
        # and the key force
        diag = np.r_[1.0 / self.scale, 1.0]

        def ladder(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            for n, (widen, arrays) in enumerate(zip(LADDER, self.ladder, strict=True)):
                if n:  # what sticks at the wider width slips that much less at this one
                    x = self._narrowed(x, prev, LADDER[n - 1], widen)
                sol = root(residual, x, args=(arrays,), jac=lambda x, a, w=widen:
                           jacobian(x, a, w), method="hybr",
                           options={"xtol": 1e-10, "diag": diag})
                # damped Newton's steps polish what hybr's tolerance leaves (and take over
                # where it stalled on a law's knee)
                x, r = _newton(lambda x, a=arrays: residual(x, a),
                               lambda x, a=arrays, w=widen: jacobian(x, a, w), sol.x)
            return x, r

        r = np.full(c.size + 1, np.inf)
        again = self.stuck_start
        self.stuck_start = None
        if hint is not None:
            x, r = _newton(lambda x: residual(x, self.sliding),
                           lambda x: jacobian(x, self.sliding, 1.0), hint.copy(), 8)
            if np.max(np.abs(r)) > FORCE_TOL and again is not None:
                # the previous step balanced from a sticking start: the same element
                # sticking, from the previous step's increments, first
                tries = self._sticking_starts(hint, prev)
                if again < len(tries):
                    x_new, r_new = ladder(tries[again])
                    if np.max(np.abs(r_new)) <= FORCE_TOL:
                        x, r, self.stuck_start = x_new, r_new, again
        starts = [np.r_[guess[c] - prev[c], f0]] if hint is None else [
            hint.copy(), np.r_[guess[c] - prev[c], f0]]
        for start in starts:
            if np.max(np.abs(r)) > FORCE_TOL:
                x, r = ladder(start)
        if np.max(np.abs(r)) > FORCE_TOL:
            # no equilibrium near the frictionless path's step: friction takes the step
            # elsewhere (a jack the knuckle's friction drags off its stop). Start again
            # from steps in which one joint or one contact sticks (its slip zeroed by one
            # coordinate's increment) and keep the first that reaches an equilibrium.
            for n_try, x_try in enumerate(self._sticking_starts(x, prev)):
                x_new, r_new = ladder(x_try)
                if np.max(np.abs(r_new)) < np.max(np.abs(r)):
                    x, r = x_new, r_new
                if np.max(np.abs(r)) <= FORCE_TOL:
                    self.stuck_start = n_try
                    break
        residual(x, self.sliding)  # leave the state at x
        ws.qx[:] = 0.0
        return y.copy(), float(x[-1]), float(np.max(np.abs(r)))

    def _slips(self, x: np.ndarray, prev: np.ndarray) -> np.ndarray:
        """Each contact's slip (m) and each pin's turn (rad) in the step of increments x
        (the contacts first, then the pins of JOINT_COORD)."""
        k, c = self.k, self.coords
        y = prev.copy()
        y[c] = prev[c] + x[:-1]
        y[k.NQ : k.NY] = 0.0
        y[k.NQ + c] = x[:-1]  # the step's increments, as if in 1 s
        return np.r_[self.outputs(y, self.sliding)[k.O_SLIP], y[k.NQ + np.array(k.JOINT_COORD)]]

    def _narrowed(self, x: np.ndarray, prev: np.ndarray, wide: float,
                  narrow: float) -> np.ndarray:
        """x moved so that every contact and pin that sticks at the width ``wide`` (its slip
        within three widths) slips ``narrow / wide`` times as much: the continuation's
        predictor (a stuck element's slip scales with the law's width)."""
        k, c = self.k, self.coords
        s0 = self._slips(x, prev)
        nc = self.sliding.cl.shape[0]
        y = prev.copy()
        y[c] = prev[c] + x[:-1]
        y[k.NQ : k.NY] = 0.0
        fn = self.outputs(y, self.sliding)[k.O_FN]
        width = np.r_[np.full(nc, SLIP_TOL_M), np.full(len(k.JOINT_COORD), TURN_TOL_RAD)] * wide
        has = np.r_[(self.sliding.cl[:, k.L_MU_A] > 0) & (fn > 0), self.sliding.jf[:, 0] > 0]
        stuck = has & (np.abs(s0) < 3 * width)
        stuck[nc + list(k.JOINT_COORD).index(k.QK)] = False  # the key turns with the dip
        if not stuck.any():
            return x
        grad = np.empty((s0.size, c.size))
        for j in range(c.size):
            e = np.zeros(x.size)
            e[j] = 1e-6 * self.scale[j]
            grad[:, j] = (self._slips(x + e, prev) - s0) / e[j]
        rows = grad[stuck] / width[stuck, None]
        want = (s0[stuck] * (narrow / wide - 1.0)) / width[stuck]
        dx = np.linalg.lstsq(rows, want, rcond=None)[0]
        return np.r_[x[:-1] + dx, x[-1]]

    def _sticking_starts(self, x: np.ndarray, prev: np.ndarray) -> list[np.ndarray]:
        """Starting points for a step: ``x`` (increments, key force) with the coordinate
        that moves a loaded contact with friction most moved so that the contact does not
        slip, or with one pin's turn zeroed."""
        k, c = self.k, self.coords
        out = []
        nc = self.sliding.cl.shape[0]
        base = self._slips(x, prev)[:nc]
        fn = self.outputs(np.r_[prev[: k.NQ], np.zeros(k.NQ)], self.sliding)[k.O_FN]
        grad = np.empty((nc, c.size))
        for j in range(c.size):
            e = np.zeros(x.size)
            e[j] = 1e-6 * self.scale[j]
            grad[:, j] = (self._slips(x + e, prev)[:nc] - base) / e[j]
        for i in np.flatnonzero((self.sliding.cl[:, k.L_MU_A] > 0) & (fn > 0)):
            movers = [int(j) for j in np.argsort(-np.abs(grad[i]))
                      if c[j] != k.QK and grad[i, j] != 0]
            if movers:
                x_try = x.copy()
                x_try[movers[0]] -= base[i] / grad[i, movers[0]]
                out.append(x_try)
        for j in range(c.size):
            if c[j] != k.QK and c[j] in k.JOINT_COORD:
                x_try = x.copy()
                x_try[j] = 0.0
                out.append(x_try)
        return out

    def outputs(self, y: np.ndarray, arrays: Any, force: float = 0.0) -> np.ndarray:
        """Per-contact outputs [O_*, contact] at state y."""
        k, m = self.k, self.model
        xo = np.zeros((k.N_X, 1))
        co = np.zeros((k.N_CONTACT_OUT, 1, m.packed.n_contacts))
        k.sample_outputs(arrays, self.ws, y[None, :], np.array([force]), self.head_pt,
                         self.gauge, xo, co)
        return co[:, 0, :]

    def strike_point(self, y: np.ndarray) -> tuple[float, float]:
        k, ws = self.k, self.ws
        k.kinematics(y[: k.NQ], y[k.NQ : k.NY], self.model.packed.arrays.sp,
                     self.model.packed.arrays.sec_xi, ws.org, ws.phi, ws.w, ws.vO, ws.JO,
                     ws.Jp, ws.aO, ws.al, ws.cs)
        hx, hy = self.head_pt
        c, s = ws.cs[k.F_HEAD]
        return (float(ws.org[k.F_HEAD, 0] + c * hx - s * hy),
                float(ws.org[k.F_HEAD, 1] + s * hx + c * hy))

    def potential(self, y: np.ndarray) -> float:
        kin, pot, ela = self.model.energy(np.r_[y[: self.k.NQ], np.zeros(self.k.NQ)])
        return pot


def _newton(fun: Any, jac: Any, x: np.ndarray, iterations: int = 20) -> tuple[np.ndarray,
                                                                                np.ndarray]:
    """Damped Newton's method on ``fun`` from ``x``: each step halved until the largest
    residual falls; stops when it no longer does. (x, residual there)."""
    r = fun(x)
    for _ in range(iterations):
        size = float(np.linalg.norm(r))
        if size < NEWTON_TOL:
            break
        try:
            dx = np.linalg.solve(jac(x), -r)
        except np.linalg.LinAlgError:
            break
        for _half in range(12):
            trial = x + dx
            r_trial = fun(trial)
            if np.linalg.norm(r_trial) < size:
                break
            dx = dx / 2
        else:
            break
        x, r = trial, r_trial
    return x, r


def _moment(st: _Statics, y: np.ndarray, coord: int, h: float = 1e-6) -> float:
    """Gravity moment (N m) of what coordinate ``coord`` turns, about its pivot:
    -dPE/dq with every other coordinate held."""
    a, b = y.copy(), y.copy()
    a[coord] += h
    b[coord] -= h
    return -(st.potential(a) - st.potential(b)) / (2 * h)


def _strike_weight(st: _Statics) -> tuple[float, float]:
    """(strike weight N, hammer mass kg): the hammer's gravity moment about its centre pin
    with the line pivot -> strike point level, over that line's length."""
    k, model = st.k, st.model
    y = st.rest.copy()
    sp = model.packed.arrays.sp
    px, py = float(sp[k.S_PG3X]), float(sp[k.S_PG3Y])
    sx, sy = st.strike_point(y)
    angle = math.atan2(sy - py, sx - px)
    if abs(angle) > math.pi / 2:  # the head left of the pivot: level it pointing left
        angle -= math.copysign(math.pi, angle)
    y[k.QH] -= angle  # turn the hammer until the line is level
    sx, sy = st.strike_point(y)
    length = math.hypot(sx - px, sy - py)
    moment = _moment(st, y, k.QH)  # counter-clockwise positive
    # a strike point right of the pivot is pulled down clockwise by the hammer's weight
    side = 1.0 if sx > px else -1.0
    me = model.packed.arrays.me
    mass = float(sum(me[i, 1] for i in range(me.shape[0]) if int(me[i, 0]) in HAMMER_FRAMES))
    if model.build.flags["flexible_shank"]:
        mass += float(model.packed.arrays.beam[:, 1].sum())
    return -side * moment / length, mass


def measure(model: ActionModel, worked: bool = True) -> Touch:
    """The touch figures of ``model`` (docs/touch.md); ``worked``: also the worked key's
    press (``Touch.worked``: the press after a press and its return; `rig sweep --touch`
    leaves it out)."""
    st = _Statics(model)
    k = st.k
    g = float(model.packed.arrays.sp[k.S_G])
    rest = st.rest
    r_front = st.front_radius(rest)
    # the frictionless path, point by point from the rest state, until a stop closes
    dips: list[float] = []
    path: list[np.ndarray] = []
    forces: list[float] = []
    y, f = rest.copy(), 0.0
    end = f"the stroke reached {MAX_DIP_M * 1e3:.0f} mm"
    stops = {st.ids.index(cid): why for cid, why in STROKE_STOPS.items() if cid in st.ids}
    d = FIRST_M
    while d <= MAX_DIP_M + 1e-12:
        y_new, f_new, err = st.solve(d, y, f, st.frictionless)
        pen = st.outputs(y_new, st.frictionless)[k.O_PEN]
        closed = [why for i, why in stops.items() if pen[i] > 0]
        if closed:  # (a stop closing can also be what the solver failed at)
            end = closed[0]
            break
        if err > 1e-6:
            end = f"no equilibrium at {d * 1e3:.2f} mm"
            break
        y, f = y_new, f_new
        if not dips:
            held = [why for cid, why in REST_SUPPORTS.items()
                    if cid in st.ids and pen[st.ids.index(cid)] > 0]
            if held:
                raise InputError(f"model: the {held[0]} still carries the key or hammer "
                                 f"{FIRST_M * 1e3:.2f} mm into the stroke; rig touch cannot "
                                 f"start its stroke there")
        dips.append(d)
        path.append(y.copy())
        forces.append(f)
        d += STEP_M
    if len(dips) < 3:
        raise InputError(f"model: the touch stroke is too short ({len(dips)} points before "
                         f"{end})")
    dip = np.array(dips)
    states = np.array(path)
    mid = int(np.argmin(np.abs(dip - (dip[0] + dip[-1]) / 2)))  # the middle of the stroke
    tangent = np.gradient(states[:, : k.NQ], dip, axis=0)  # dq / d(dip)
    n = len(dip)
    # the down press from rest, one step past the stroke's end (where the press turns)
    turn = dip[-1] + STEP_M
    down_at = np.r_[dip, turn]
    guesses = [*states, states[-1] + (states[-1] - states[-2])]
    ref_f = [*forces, 2 * forces[-1] - forces[-2]]
    down_path: list[np.ndarray] = []
    down, up = np.empty(n + 1), np.empty(n)
    prev, prev_ref, f_prev, ref_prev = rest, rest, 0.0, 0.0
    worst, failed = 0.0, ""
    hint = None
    for i, d_i in enumerate(down_at):
        guess = prev + (guesses[i] - prev_ref)
        y_i, f_i, err = _advance(st, float(down_at[i - 1]) if i else 0.0, float(d_i), prev,
                                 guess, f_prev + ref_f[i] - ref_prev, hint if i > 1 else None)
        hint = np.r_[y_i[st.coords] - prev[st.coords], f_i]
        worst = max(worst, err)
        if err > FORCE_TOL and not failed:
            failed = _why(st, guesses[i], y_i, f_i, float(d_i), "down")
        down_path.append(y_i)
        down[i] = f_i
        prev, prev_ref, f_prev, ref_prev = y_i, guesses[i], f_i, ref_f[i]
    # the up press from there back to the stroke's start
    up_path: list[np.ndarray] = [np.empty(0)] * n
    hint = None  # (the press turns: what stuck may slip now, and the other way)
    for i in range(n - 1, -1, -1):
        guess = prev + (guesses[i] - prev_ref)
        y_i, f_i, err = _advance(st, float(down_at[i + 1]), float(dip[i]), prev, guess,
                                 f_prev + ref_f[i] - ref_prev, hint if i < n - 2 else None)
        hint = np.r_[y_i[st.coords] - prev[st.coords], f_i]
        worst = max(worst, err)
        if err > FORCE_TOL and not failed:
            failed = _why(st, guesses[i], y_i, f_i, float(dip[i]), "up")
        up_path[i] = y_i
        up[i] = f_i
        prev, prev_ref, f_prev, ref_prev = y_i, guesses[i], f_i, ref_f[i]
    turn_force = float(down[n])
    down = down[:n]
    if worst > FORCE_TOL:
        raise InputError(f"model: {failed}: no quasi-static equilibrium with every friction "
                         f"at its sliding limit, so the touch weights are undefined")
    worked_press: dict[str, Any] = {}
    worked_failed = ""
    if worked:  # (a worked key without an answer leaves the first press's figures standing)
        try:
            worked_press = _worked(st, down_at, down_path, np.r_[down, turn_force],
                                   up_path[0], float(up[0]))
        except InputError as exc:
            worked_failed = str(exc)
    shares = _friction_shares(st, down_path[mid], float(down[mid]))
    dw, uw = float(down[mid]), float(up[mid])
    sw, hammer_mass = _strike_weight(st)
    # the key's own weight turns its front down (clockwise): that moment over the front's arm
    fw = -_moment(st, rest, k.QK) / r_front
    key_ratio = math.nan
    if 1 in st.ids:
        px = st.outputs(states[0], st.frictionless)[k.O_PX, st.ids.index(1)]
        key_ratio = float(-px / st.front_radius(states[0]))  # pivot at x = 0
    s0 = st.strike_point(states[0])[1]
    s1 = st.strike_point(states[-1])[1]
    newtons = {"down_weight": dw, "up_weight": uw, "balance_weight": (dw + uw) / 2,
               "friction": (dw - uw) / 2, "down_weight_stroke": float(down.max()),
               "up_weight_stroke": float(up.min()), "strike_weight": sw, "front_weight": fw}
    figures = {n: grams(v) for n, v in newtons.items()}
    figures["hammer_mass"] = hammer_mass * 1e3
    figures["key_ratio"] = key_ratio
    figures["action_ratio"] = float((s1 - s0) / (dip[-1] - dip[0]))
    moving = np.r_[states[mid][: k.NQ], tangent[mid]]  # 1 m/s of key-front speed
    figures["inertia_mass"] = 2.0 * model.energy(moving)[0] * 1e3
    figures = {n: figures[n] for n in FIGURES}
    return Touch(figures=figures, newtons=newtons, dip_m=dip, down_n=down, up_n=up,
                 frictionless_n=np.array(forces), stroke_end=end, key_front_radius_m=r_front,
                 friction_shares_g=shares, down_states=np.array(down_path),
                 up_states=np.array(up_path), turn_force_n=turn_force, worked=worked_press,
                 method={"g0_m_s2": G0, "model_gravity_m_s2": g, "step_m": STEP_M,
                         "first_m": FIRST_M, "press_speed_m_s": PRESS_SPEED,
                         "slip_tolerance_m": SLIP_TOL_M, "turn_tolerance_rad": TURN_TOL_RAD,
                         "turn_dip_m": float(turn), "worst_residual": worst,
                         "contacts_changed": _changes(st, dip, down_path[:n], up_path),
                         "mid_stroke_dip_m": float(dip[mid]),
                         "down_stroke_at_dip_m": float(dip[int(np.argmax(down))]),
                         "up_stroke_at_dip_m": float(dip[int(np.argmin(up))]),
                         **({"worked_key_failed": worked_failed} if worked_failed else {})})


def _worked(st: _Statics, down_at: np.ndarray, down_path: list[np.ndarray],
            down_f: np.ndarray, back: np.ndarray, f_back: float) -> dict[str, Any]:
    """The worked key's press: the state the first press and its return leave (``back``,
    the up press at the stroke's first point, its force ``f_back``) let go to no key force
    (the key comes back to rest, friction carried over), then a press from that rest down
    through the stroke to the turn (the first point ``FIRST_M`` below that rest, then the
    stroke's points ``down_at``; the first press's states and forces guide each step) and
    back one step (the up force at the stroke's last point). The weights a press of a
    worked key measures by the travel rule (docs/touch.md, "The worked key")."""
    c = st.coords
    # let go from the stroke's first point; where that step finds no equilibrium (the
    # flexible shank's), the key is first taken up by the dip to half and a quarter of it
    d_back = float(down_at[0])
    while True:
        rest, f_rest, err = st.step(0.0, back, st.rest, f_back, held=0.0)
        if err <= FORCE_TOL or d_back < FIRST_M / 5:
            break
        back, f_back, err = _advance(st, d_back, d_back / 2, back, back, f_back, None)
        d_back /= 2
        if err > FORCE_TOL or f_back <= 0:
            break
    if err > FORCE_TOL:
        raise InputError("model: the key let go after its first press finds no rest with "
                         "friction at its sliding limit, so the worked key's weights are "
                         "undefined")
    rest_dip = st.keytop_rest - st.keytop_y(rest)
    first = rest_dip + FIRST_M
    # the stroke's points from the first past the worked rest's first point, to the turn
    later = [i for i in range(len(down_at)) if down_at[i] > first + STEP_M / 2]
    dips = np.r_[first, down_at[later]]
    refs = [down_path[max(later[0] - 1, 0)], *(down_path[i] for i in later)]
    ref_f = np.r_[down_f[max(later[0] - 1, 0)], down_f[later]]
    forces = np.empty(dips.size)
    prev, prev_ref, f_prev, ref_prev, d_prev = rest, st.rest, 0.0, 0.0, rest_dip
    hint = None
    for i, d_i in enumerate(dips):
        y_i, f_i, err = _advance(st, d_prev, float(d_i), prev, prev + (refs[i] - prev_ref),
                                 f_prev + ref_f[i] - ref_prev, hint if i > 1 else None)
        if err > FORCE_TOL:
            raise InputError(f"model: {_why(st, refs[i], y_i, f_i, float(d_i), 'worked down')}"
                             f": no quasi-static equilibrium with every friction at its "
                             f"sliding limit, so the worked key's weights are undefined")
        hint = np.r_[y_i[c] - prev[c], f_i]
        forces[i] = f_i
        prev, prev_ref, f_prev, ref_prev, d_prev = y_i, refs[i], f_i, ref_f[i], float(d_i)
    # back one step from the turn: the up force at the stroke's last point
    d_up = float(down_at[-2])
    y_up, f_up, err = _advance(st, d_prev, d_up, prev, down_path[-2] + (prev - down_path[-1]),
                               f_prev, None)
    if err > FORCE_TOL:
        raise InputError(f"model: {_why(st, down_path[-2], y_up, f_up, d_up, 'worked up')}: "
                         f"no quasi-static equilibrium with every friction at its sliding "
                         f"limit, so the worked key's weights are undefined")
    return {"rest_dip_m": float(rest_dip), "dip_m": dips.tolist(),
            "down_N": forces[:-1].tolist(), "turn_dip_m": float(dips[-1]),
            "turn_force_N": float(forces[-1]), "up_dip_m": d_up, "up_N": float(f_up)}


def sticking_parameters(params: Any) -> Any:
    """A copy of ``params`` with Dahl's law at every pin and at every contact with friction
    but one whose bristle law already sticks (the back check's): an action whose every
    friction element sticks, as `sim.friction: stick` makes the simulated rig's."""
    from rig.model.assembly import JOINTS

    out = params.copy()
    laws = out.tree.get("friction_law", {}).get("contact", {})
    for c in out.tree["contacts"]:
        cid = int(c["id"])
        if c["A"] > 0 and laws.get(cid) != "bristle":
            out.set(f"friction_law.contact.{cid}", "dahl")
    for pin in JOINTS:
        out.set(f"friction_law.joint.{pin}", "dahl")
    return out


def stop_returns(model: ActionModel, time_s: np.ndarray, force_n: np.ndarray,
                 at_s: list[float], threshold_m: float = FIRST_M) -> list[dict[str, Any]]:
    """The up-weights a slow return from the key's stop measures after presses in time
    (docs/touch.md, "The up-weight after a press in time"): the model with every friction
    element sticking (``sticking_parameters``) simulated in time (``ActionModel`` 's
    integrator) from its rest under the key-front force profile (``time_s`` s, ``force_n``
    N, piecewise linear); at each time of ``at_s`` (the key held at its stop) its state is
    taken and the force then lowered quasi-statically (``_Statics``, friction carried over):
    the key taken up ``threshold_m`` from where it stood in ``RETURN_STEPS`` steps (the
    stop's felts and the stuck joints first give back what the held force compressed, then
    the key comes up). Each return: the force
    there (``up_weight`` g, ``up_n`` N), where the key stood (``stop_dip_m``) and came to
    (``up_dip_m``), the force held (``held_n``) and each contact's penetration at the stop
    (``penetration_m`` by contact id: < 0 open)."""
    from rig.model.action import ActionModel, Stepper

    t = np.asarray(time_s, float)
    f = np.asarray(force_n, float)
    if t.ndim != 1 or t.shape != f.shape or t.size < 2 or np.any(np.diff(t) <= 0):
        raise InputError("the force profile: expected increasing times and as many forces")
    if not at_s or any(not t[0] < a <= t[-1] for a in at_s) or np.any(np.diff(at_s) <= 0):
        raise InputError("at_s: expected increasing times within the force profile")
    pressed = ActionModel(sticking_parameters(model.params), effects=model.effects)
    st = _Statics(pressed)
    stepper = Stepper(pressed, pressed.rest_state(), keep_history=False)
    out = []
    for at in at_s:
        stepper.advance_table(float(at), t, f)
        if stepper.status != 0:
            raise InputError(f"model: the presses in time stopped: {stepper.message}")
        held = float(np.interp(at, t, f))
        out.append(_stop_return(st, stepper.y, held, threshold_m))
    return out


def _stop_return(st: _Statics, y: np.ndarray, held: float,
                 threshold_m: float) -> dict[str, Any]:
    """The quasi-static return from the state ``y`` (the key at its stop under ``held`` N,
    the first step's guess): ``stop_returns``' one return."""
    k = st.k
    stop = y[: k.NY].copy()
    stop[k.NQ : k.NY] = 0.0
    d_stop = st.keytop_rest - st.keytop_y(stop)
    pen = st.outputs(stop, st.sliding)[k.O_PEN]
    y_i, f_i, d_prev = stop, held, d_stop
    for i in range(1, RETURN_STEPS + 1):
        d_i = d_stop - threshold_m * i / RETURN_STEPS
        y_i, f_i, err = _advance(st, d_prev, d_i, y_i, y_i, f_i, None)
        if err > FORCE_TOL:
            raise InputError(f"model: {_why(st, y_i, y_i, f_i, d_i, 'return')}: no "
                             f"quasi-static equilibrium with every friction at its sliding "
                             f"limit, so the return from the stop is undefined")
        d_prev = d_i
    return {"up_weight": grams(f_i), "up_n": f_i, "stop_dip_m": float(d_stop),
            "up_dip_m": float(d_prev), "held_n": held,
            "penetration_m": {cid: float(p) for cid, p in zip(st.ids, pen, strict=True)}}


def _advance(st: _Statics, d_from: float, d_to: float, prev: np.ndarray, guess: np.ndarray,
             f0: float, hint: np.ndarray | None, depth: int = 0) -> tuple[np.ndarray, float,
                                                                           float]:
    """The press's step from ``prev`` (at ``d_from``) to ``d_to``; a step that finds no
    equilibrium is taken as two half steps (down to an eighth), as a slower press would
    take it. (The state's speeds are then its last part's increments.)"""
    y, f, err = st.step(d_to, prev, guess, f0, hint)
    if err <= FORCE_TOL or depth >= SPLITS:
        return y, f, err
    half = None if hint is None else np.r_[hint[:-1] / 2, hint[-1]]
    d_mid = (d_from + d_to) / 2
    y_mid, f_mid, e_mid = _advance(st, d_from, d_mid, prev, prev + (guess - prev) / 2, f0, half,
                                   depth + 1)
    if e_mid > FORCE_TOL:
        return y, f, err
    c = st.coords
    y2, f2, e2 = _advance(st, d_mid, d_to, y_mid, y_mid + (guess - prev) / 2, f_mid,
                          np.r_[y_mid[c] - prev[c], f_mid], depth + 1)
    return (y2, f2, e2) if e2 < err else (y, f, err)


def _changes(st: _Statics, dip: np.ndarray, down: list[np.ndarray],
             up: list[np.ndarray]) -> dict[str, str]:
    """Contacts that open or close along each press with friction: where each first
    changes (the index of the stroke's point, counted from the stroke's start)."""
    k = st.k
    out: dict[str, str] = {}
    for way, states in (("down", down), ("up", up)):
        pen = np.array([st.outputs(y, st.sliding)[k.O_PEN] for y in states]) > 0
        for j in range(pen.shape[1]):
            if pen[:, j].any() and not pen[:, j].all():
                first = int(np.flatnonzero(np.diff(pen[:, j]))[0]) + 1
                if way == "up":  # the up press runs from the stroke's end
                    first = int(np.flatnonzero(np.diff(pen[::-1, j]))[0]) + 1
                    first = len(states) - 1 - first
                state = "closed" if pen[first, j] else "open"
                out[f"{way} press, contact {st.ids[j]}"] = (
                    f"{state} from {dip[first] * 1e3:.2f} mm")
    return out


def _why(st: _Statics, path: np.ndarray, y: np.ndarray, force: float, dip: float,
         way: str) -> str:
    """Where a sliding equilibrium failed, and which contact let go (if one did)."""
    k = st.k
    held = st.outputs(path, st.frictionless)[k.O_FN] > 0
    now = st.outputs(y, st.sliding, force)[k.O_FN] > 0
    names = st.model.packed.contact_names
    opened = [f"contact {st.ids[i]} ({names[i]})" for i in np.flatnonzero(held & ~now)]
    where = f"{way} press at {dip * 1e3:.2f} mm of key-front dip"
    return f"{where}, {opened[0]} opens under friction" if opened else where


def _friction_shares(st: _Statics, y: np.ndarray, force: float) -> dict[str, float]:
    """Each joint's and contact's friction in grams at the key front (its power over the
    key front's), on the down press."""
    k, m = st.k, st.model
    out: dict[str, float] = {}
    co = st.outputs(y, st.sliding, force)
    for i, name in enumerate(m.packed.contact_names):
        p = abs(co[k.O_FT, i] * co[k.O_SLIP, i])
        if p > 0:
            out[f"contact {st.ids[i]} ({name})"] = float(grams(p / PRESS_SPEED))
    jf = st.sliding.jf
    for j, (coord, name) in enumerate(zip(k.JOINT_COORD, ("key", "whippen", "jack", "repetition",
                                                          "hammer", "key pin slider"),
                                          strict=True)):
        w = y[k.NQ + coord]
        if jf[j, 0] > 0 and w != 0 and m.active[coord]:
            torque = k.joint_torque(w, jf[j, 0], jf[j, 1], jf[j, 2], jf[j, 3])
            out[f"{name} pin"] = float(grams(abs(torque * w) / PRESS_SPEED))
    return out
