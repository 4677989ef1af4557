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

Method: quasi-static equilibria. At each key-front dip of the stroke the mechanism's
generalized forces are solved to zero (every active coordinate and the key force, with the
key front held at that dip). The friction laws (Eq. 3.6 and 3.8) are taken at their sliding
limit -- the kinetic coefficient A (contacts) and torque E (pins), each opposing the slip
that the press makes -- by evaluating them at a vanishing press speed with their threshold
speeds shrunk far below it: the regularised laws then act as Coulomb friction, the
technician's slow press, instead of the viscous-like law they are at speeds below v_t.
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
# a pin turning slower than this fraction of the key (per key-front dip) turns only as the
# felts around it compress (the jack and repetition lever on the whippen before let-off):
# it sticks, and its friction does no work
STICK_FRACTION = 0.05
SHRINK = 1e-9  # the friction laws' threshold speeds times this: sliding (Coulomb) limit
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
        }


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
        self.coords = np.array([i for i in np.flatnonzero(model.active) if i != k.QZ])
        # each coordinate's size in the integrator's terms (the shank's bending coordinates
        # are 1e3-1e4 times an angle's): the solver's variable scaling, the residual's units
        self.scale = model.atol[self.coords] / model.atol[k.QK]
        base = model.packed.arrays
        self.sliding = self._arrays(base, friction=True)
        self.frictionless = self._arrays(base, friction=False)
        sp = base.sp
        self.pivot_y0 = float(sp[k.S_PIVY0])
        self.px, self.py = float(sp[k.S_KEYPX]), float(sp[k.S_KEYPY])
        self.rest = model.rest_state()
        self.keytop_rest = self.keytop_y(self.rest)
        self.dy = np.zeros(k.NY)
        self.ids = list(model.packed.contact_ids)
        # the striking felt's centre in the head frame and the strain gauge (as ActionModel)
        tree = model.build.params.tree
        from rig.model.action import HEAD_STRIKE_POINT

        self.head_pt = np.array(tree["points"]["hammer_head"][HEAD_STRIKE_POINT]["at"], float)
        beam = tree["hammer_shank_beam"]
        self.gauge = np.array([beam["length"] - beam["strain_gauge_at"][0],
                               beam["strain_gauge_at"][1]])

    def _arrays(self, base: Any, friction: bool) -> Any:
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
            # the bristle law slides with the kinetic coefficient A: Eq. 3.6's sliding limit
            cl[:, k.L_FLAW] = k.FRICTION_SMOOTHED
            cl[:, k.L_VT] *= SHRINK
            jf[:, 3] *= SHRINK
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


def measure(model: ActionModel) -> Touch:
    """The touch figures of ``model`` (docs/touch.md)."""
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
    down, up = np.empty(len(dip)), np.empty(len(dip))
    yd, yu, fd, fu, f_prev = states[0].copy(), states[0].copy(), forces[0], forces[0], forces[0]
    worst, failed = 0.0, ""
    for i in range(len(dip)):
        v = tangent[i] * PRESS_SPEED
        for c in k.JOINT_COORD[1:]:  # pins that turn only as the felts give: stuck
            if abs(tangent[i, c]) < STICK_FRACTION * abs(tangent[i, k.QK]):
                v[c] = 0.0
        yd, fd, ed = _solve_from(st, dip[i], (states[i], yd), forces[i] + fd - f_prev, v)
        yu, fu, eu = _solve_from(st, dip[i], (states[i], yu), forces[i] + fu - f_prev, -v)
        f_prev = forces[i]
        down[i], up[i] = fd, fu
        worst = max(worst, ed, eu)
        if not failed and max(ed, eu) > 1e-6:
            failed = _why(st, states[i], yd if ed > 1e-6 else yu, fd if ed > 1e-6 else fu,
                          dip[i], "down" if ed > 1e-6 else "up")
        if i == mid:
            shares = _friction_shares(st, yd, fd)
    if worst > 1e-6:
        raise InputError(f"model: {failed}: no quasi-static equilibrium with every friction "
                         f"at its sliding limit, so the touch weights are undefined")
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
                 friction_shares_g=shares,
                 method={"g0_m_s2": G0, "model_gravity_m_s2": g, "step_m": STEP_M,
                         "first_m": FIRST_M, "press_speed_m_s": PRESS_SPEED,
                         "threshold_factor": SHRINK, "worst_residual": worst,
                         "mid_stroke_dip_m": float(dip[mid]),
                         "down_stroke_at_dip_m": float(dip[int(np.argmax(down))]),
                         "up_stroke_at_dip_m": float(dip[int(np.argmin(up))])})


def _solve_from(st: _Statics, dip: float, guesses: tuple[np.ndarray, ...], f0: float,
                qd: np.ndarray) -> tuple[np.ndarray, float, float]:
    """The sliding equilibrium at ``dip`` from the first guess that converges (the
    frictionless state there, then the previous point's sliding state)."""
    best: tuple[np.ndarray, float, float] | None = None
    for guess in guesses:
        got = st.solve(dip, guess, f0, st.sliding, qd)
        if best is None or got[2] < best[2]:
            best = got
        if got[2] <= 1e-9:
            break
    assert best is not None
    return best


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
