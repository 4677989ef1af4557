"""Pack a parameter tree into the arrays the compiled kernel reads."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rig.errors import InputError
from rig.inputs.params import Parameters
from rig.model import kernel as k

BODY_FRAME = {
    "ground": k.F_GROUND,
    "massless_body": k.F_PIVOT,
    "key": k.F_KEY,
    "whippen": k.F_WHIPPEN,
    "jack": k.F_JACK,
    "repetition": k.F_REP,
    "hammer_base": k.F_HAMMER,
    "hammer_head": k.F_HEAD,
}
# the shank/head frame origin in the hammer frame (action-geometry.md)
HEAD_ORIGIN_IN_HAMMER = (-0.1275, 0.0)
JOINTS = ("key", "whippen", "jack", "repetition", "hammer")
N_GAUSS = 4  # exact for the beam's linear mass matrix (integrands up to xi^6)
# hammer_shank_axial.coupling: the shank's axial coordinate in the full equations, or driven
# one way by the axial force of an axially rigid mechanism (docs/model.md)
AXIAL_COUPLINGS = ("two_way", "one_way")


@dataclass(frozen=True)
class Packed:
    """The kernel's view of one model (kernel.Model, named arrays) plus names."""

    arrays: k.Model
    contact_ids: tuple[int, ...]
    contact_names: tuple[str, ...]
    n_frames: int
    shank_first_mode_rad_s: float

    @property
    def n_contacts(self) -> int:
        return len(self.contact_ids)


def _kind(kind: str) -> int:
    if "hybrid" in kind:
        return k.K_HYBRID
    if "circle" in kind:
        return k.K_CIRCLE
    if "line" in kind:
        return k.K_LINE
    raise InputError(f"contact feature kind {kind!r} is not line, circle or hybrid")


def _feature(params: Parameters, ref: str, sections: list[float], shank_len: float) -> np.ndarray:
    body, point = ref.split(".")
    spec = params.get(f"points.{body}.{point}")
    row = np.zeros(9)
    row[k.C_KIND] = _kind(spec["kind"])
    x, y = spec["at"]
    nx, ny = spec.get("normal", [0.0, 0.0])
    if body == "hammer_shank":
        # a point of the shank rides on the cross-section at distance xi from the root
        xi = shank_len - x
        sections.append(xi)
        row[k.C_FRAME] = k.N_RIGID_FRAMES + len(sections) - 1
        x = 0.0
    else:
        row[k.C_FRAME] = BODY_FRAME[body]
    row[k.C_X], row[k.C_Y] = x, y
    norm = float(np.hypot(nx, ny))
    if norm > 0:
        nx, ny = nx / norm, ny / norm
    row[k.C_NX], row[k.C_NY] = nx, ny
    row[k.C_R] = spec.get("radius", 0.0)
    if "arc" in spec:
        row[k.C_A0], row[k.C_A1] = spec["arc"]
    return row


FRICTION_LAWS = ("smoothed", "bristle", "dahl")
JOINT_FRICTION_LAWS = ("smoothed", "dahl")


def static_coefficient(mu_a: float, b1: float, b2: float) -> float:
    """The peak of Eq. 3.6's coefficient over the slip speed (its static friction)."""
    r = np.linspace(0.0, 10.0, 20001)
    return float(mu_a * np.max(np.tanh(r) + b1 * r / (1.0 + b2 * r**4)))


def _positive(spec: dict, where: str, fields: tuple[str, ...]) -> None:
    for field in fields:
        v = spec.get(field)
        if not (isinstance(v, (int, float)) and not isinstance(v, bool) and float(v) > 0.0
                and math.isfinite(float(v))):
            raise InputError(f"friction_law.{where}.{field}: expected a positive value, "
                             f"got {v!r}")


def _friction_law(law: np.ndarray, cid: int, name: str, bristle: dict, dahl: dict) -> None:
    """Fill the friction-law columns of contact ``cid``'s law row."""
    if name not in FRICTION_LAWS:
        raise InputError(f"friction_law.contact.{cid}: expected one of {FRICTION_LAWS}, "
                         f"got {name!r}")
    if name == "smoothed" or law[k.L_MU_A] <= 0.0:
        law[k.L_FLAW] = k.FRICTION_SMOOTHED
        return
    if name == "dahl":
        # Dahl's law: the bristle law with one coefficient, Eq. 3.6's kinetic A (no static
        # hump: it sticks up to A f_n and slides at A f_n, Coulomb's law as rig touch takes it)
        _positive(dahl, "dahl", ("presliding", "damping_time"))
        law[k.L_FLAW] = k.FRICTION_BRISTLE
        law[k.L_MU_S] = law[k.L_MU_A]
        law[k.L_SIG0] = law[k.L_MU_A] / dahl["presliding"]
        law[k.L_SIG1] = law[k.L_SIG0] * dahl["damping_time"]
        return
    mu_s = static_coefficient(law[k.L_MU_A], law[k.L_B1], law[k.L_B2])
    for field in ("presliding", "damping_time", "relax_time", "release_time"):
        if not float(bristle[field]) > 0.0:
            raise InputError(f"friction_law.bristle.{field}: expected a positive value, "
                             f"got {bristle[field]!r}")
    law[k.L_FLAW] = k.FRICTION_BRISTLE
    law[k.L_MU_S] = mu_s
    law[k.L_SIG0] = mu_s / bristle["presliding"]
    law[k.L_SIG1] = law[k.L_SIG0] * bristle["damping_time"]


def pack(params: Parameters, *, liftoff: bool = False, flexible_shank: bool = False) -> Packed:
    """Arrays for the kernel; ``liftoff``/``flexible_shank`` switch the built-in effects."""
    t = params.tree
    sp = np.zeros(k.N_SP)
    sp[k.S_G] = t["gravity"]
    g = t["points"]["ground"]
    sp[k.S_PG2X], sp[k.S_PG2Y] = g["Pg2"]["at"]
    sp[k.S_PG3X], sp[k.S_PG3Y] = g["Pg3"]["at"]
    w = t["points"]["whippen"]
    sp[k.S_PW2X], sp[k.S_PW2Y] = w["Pw2"]["at"]
    sp[k.S_PW3X], sp[k.S_PW3Y] = w["Pw3"]["at"]
    beam = t["hammer_shank_beam"]
    length = beam["length"]
    # the shank runs from its root (glued in the flange) toward the head: -x of the hammer frame
    sp[k.S_ROOTX] = HEAD_ORIGIN_IN_HAMMER[0] + length
    sp[k.S_ROOTY] = HEAD_ORIGIN_IN_HAMMER[1]
    sp[k.S_DX], sp[k.S_DY] = -1.0, 0.0
    sp[k.S_NX], sp[k.S_NY] = 0.0, 1.0
    sp[k.S_L] = length
    sp[k.S_EA] = beam["E"] * beam["area"]
    sp[k.S_EJ] = beam["E"] * beam["Jzz"]
    sp[k.S_KEYPX], sp[k.S_KEYPY] = t["key_input"]["point"]
    sp[k.S_PIVY0] = t["key_pivot"]["y0"]
    sp[k.S_JACK_T] = t["springs"]["jack_torque"] * t["springs_sign"]["jack"]
    sp[k.S_REP_K] = t["springs"]["repetition"]["k"]
    # the spring's free angle, moved by the repetition-spring regulation (chosen-parameters)
    sp[k.S_REP_TH0] = (t["springs"]["repetition"]["theta0"]
                       + t["repetition_spring"]["regulation"])
    sp[k.S_LIFTOFF] = 1.0 if liftoff else 0.0
    sp[k.S_FLEX] = 1.0 if flexible_shank else 0.0

    bristle = t["friction_law"]["bristle"]
    sp[k.S_ZTAU] = bristle["relax_time"]
    sp[k.S_ZOPEN] = bristle["release_time"]
    laws = t["friction_law"]["contact"]
    dahl = t["friction_law"].get("dahl", {})
    joint_laws = t["friction_law"].get("joint", {})

    sections: list[float] = []
    cf_rows, cl_rows, ids, names = [], [], [], []
    vt = t["friction_threshold"]["contact_vt"]
    for c in t["contacts"]:
        cid = int(c["id"])
        ids.append(cid)
        names.append(str(c["name"]))
        cf_rows.append(
            [_feature(params, c["first"], sections, length),
             _feature(params, c["second"], sections, length)]
        )
        law = np.zeros(k.N_LAW)
        law[k.L_A], law[k.L_B], law[k.L_C], law[k.L_D] = c["a"], c["b"], c["c"], c["D"]
        law[k.L_MU_A], law[k.L_B1], law[k.L_B2] = c["A"], c["B1"], c["B2"]
        law[k.L_VT] = vt.get(cid, 0.01)
        on = cid != 14 or liftoff  # contact 14 (balance rail) exists only with lift-off
        law[k.L_ON] = 1.0 if on else 0.0
        law[k.L_TYPE] = k.LAW_HUNT_CROSSLEY
        _friction_law(law, cid, laws.get(cid, "smoothed"), bristle, dahl)
        cl_rows.append(law)
    cf = np.array(cf_rows, dtype=float)
    cl = np.array(cl_rows, dtype=float)
    bristle_on = (cl[:, k.L_FLAW] == k.FRICTION_BRISTLE) & (cl[:, k.L_ON] > 0.5)
    n_bristle = int(np.count_nonzero(bristle_on))
    if n_bristle > len(k.QZ_CONTACT):
        raise InputError(f"friction_law.contact: at most {len(k.QZ_CONTACT)} contacts may use "
                         f"a bristle law (the model has {len(k.QZ_CONTACT)} contact bristle "
                         f"coordinates), got {n_bristle}")
    # the bristle law's contact (the back check's) keeps the first coordinate, z_b; the
    # Dahl option's contacts take the others
    order = sorted((int(c) for c in np.flatnonzero(bristle_on)),
                   key=lambda c: laws.get(ids[c], "smoothed") != "bristle")
    for slot, c in zip(k.QZ_CONTACT, order, strict=False):
        cl[c, k.L_ZSLOT] = slot
    sp[k.S_BRISTLE] = 1.0 if n_bristle else 0.0

    jf = np.zeros((6, k.N_JF))
    wt = t["friction_threshold"]["joint_wt"]
    for name in joint_laws:
        if name not in JOINTS:
            raise InputError(f"friction_law.joint.{name}: expected one of the pins "
                             f"{tuple(JOINTS)}")
    for i, name in enumerate(JOINTS):
        spec = t["joint_friction"][name]
        jf[i, :4] = spec["E"], spec["F1"], spec["F2"], wt[name]
        law = joint_laws.get(name, "smoothed")
        if law not in JOINT_FRICTION_LAWS:
            raise InputError(f"friction_law.joint.{name}: expected one of "
                             f"{JOINT_FRICTION_LAWS}, got {law!r}")
        if law == "dahl" and spec["E"] > 0.0:
            # Dahl's law at the pin: torque E sig0 z, sig0 = 1 / the presliding angle
            _positive(dahl, "dahl", ("presliding_angle", "damping_time"))
            jf[i, k.J_LAW] = 1.0
            jf[i, k.J_SIG0] = 1.0 / dahl["presliding_angle"]
            jf[i, k.J_SIG1] = jf[i, k.J_SIG0] * dahl["damping_time"]
    pin = t["key_pin_friction"]
    jf[5, :4] = pin["force"], 0.0, 0.0, pin["speed_scale"]

    b = t["bodies"]
    me_rows = []
    for name, frame in (("key", k.F_KEY), ("whippen", k.F_WHIPPEN), ("jack", k.F_JACK),
                        ("repetition", k.F_REP), ("hammer_base", k.F_HAMMER),
                        ("hammer_head", k.F_HEAD)):
        me_rows.append([frame, b[name]["mass"], b[name]["inertia"], *b[name]["com"]])
    if not flexible_shank:
        # rigid shank: its own mass properties, carried by the head/shank frame
        s = b["hammer_shank"]
        me_rows.append([k.F_HEAD, s["mass"], s["inertia"], *s["com"]])
    me = np.array(me_rows, dtype=float)

    xg, wg = np.polynomial.legendre.leggauss(N_GAUSS)
    xi = 0.5 * length * (xg + 1.0)
    wxi = 0.5 * length * wg
    rho = beam["density"]
    beam_pts = np.column_stack([xi, rho * beam["area"] * wxi, rho * beam["Jzz"] * wxi])

    n_frames = k.N_RIGID_FRAMES + len(sections) + 1  # + scratch frame for beam particles
    arrays = k.Model(sp, np.array(sections, dtype=float), cf, cl, jf, me, beam_pts)
    omega1 = 0.0
    if flexible_shank:
        coupling = t["hammer_shank_axial"]["coupling"]
        if coupling not in AXIAL_COUPLINGS:
            raise InputError(f"hammer_shank_axial.coupling: expected one of "
                             f"{', '.join(AXIAL_COUPLINGS)}, got {coupling!r}")
        mh, kh = _hammer_block(arrays, n_frames, params)
        omega1 = shank_first_mode(mh, kh)
        if omega1 > 0:
            sp[k.S_BETA] = 2.0 * t["hammer_shank_damping"]["ratio"] / omega1
        if coupling == "one_way":
            sp[k.S_AXIAL_ONEWAY] = 1.0
            # the axial mode's effective mass: u1's with the hammer and the bending free to
            # react (the Schur complement of the hammer block), i.e. the 5.2 kHz mode
            rest = [0, 2, 3]
            m_axial = mh[1, 1] - mh[1, rest] @ np.linalg.solve(mh[np.ix_(rest, rest)],
                                                               mh[rest, 1])
            sp[k.S_AXW2] = sp[k.S_EA] * sp[k.S_L] / m_axial
    return Packed(arrays, tuple(ids), tuple(names), n_frames, omega1)


def shank_first_mode(mh: np.ndarray, kh: np.ndarray) -> float:
    """First bending frequency (rad/s) of the hammer pinned at its flange, in free flight,
    from the hammer block's mass and stiffness matrices (``_hammer_block``)."""
    lam = np.linalg.eigvals(np.linalg.solve(mh, kh)).real
    lam = np.sort(lam[lam > 1e-6])
    return float(np.sqrt(lam[0])) if lam.size else 0.0


def _hammer_block(arrays: k.Model, n_frames: int,
                  params: Parameters) -> tuple[np.ndarray, np.ndarray]:
    """Mass and stiffness matrices of the hammer block (theta_h, u1, v1, v2) at rest:
    the linearization about the rest angle, mass from the kernel, stiffness from the beam's
    strain energy."""
    sp = arrays.sp
    ws = k.make_workspace(n_frames, arrays.cf.shape[0])
    y = np.zeros(k.NY)
    y[k.QH] = params.get("initial_state.theta_h")
    org, phi, w, vO, JO, Jp, aO, al, cs, M, Q, cout, qdd, _qx, _jb = ws
    k.kinematics(y[: k.NQ], y[k.NQ :], sp, arrays.sec_xi, org, phi, w, vO, JO, Jp, aO, al, cs)
    idx = [k.QH, k.QU1, k.QV1, k.QV2]
    mm = np.zeros((k.NQ, k.NQ))
    qq = np.zeros(k.NQ)
    for e in range(arrays.me.shape[0]):
        f, m, inertia, cx, cy = arrays.me[e]
        k.mass_element(int(f), m, inertia, cx, cy, 0.0, cs, w, JO, Jp, aO, al, mm, qq)
    kf = org.shape[0] - 1
    ch, sh = math.cos(y[k.QH]), math.sin(y[k.QH])
    for p in range(arrays.beam.shape[0]):
        k.beam_section(arrays.beam[p, 0], y[: k.NQ], y[k.NQ :], sp, kf, org, phi, w, vO, JO, Jp,
                        aO, al, cs, ch, sh, False)
        k.mass_element(kf, arrays.beam[p, 1], arrays.beam[p, 2], 0.0, 0.0, 0.0, cs, w, JO, Jp,
                        aO, al, mm, qq)
    mh = mm[np.ix_(idx, idx)]
    ln, ea, ej = sp[k.S_L], sp[k.S_EA], sp[k.S_EJ]
    kh = np.zeros((4, 4))
    kh[1, 1] = ea * ln
    kh[2:, 2:] = ej * np.array([[4 * ln, 6 * ln**2], [6 * ln**2, 12 * ln**3]])
    return mh, kh
