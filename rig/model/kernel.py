"""Compiled equations of motion of the planar grand-piano action.

Generalized coordinates (always 18; those of effects and laws that are off stay frozen):

    0 theta_k  key, ground -> key frame (rad)
    1 y_k      key pivot lift along the prismatic joint (m)      [key_liftoff]
    2 theta_w  whippen, ground -> whippen frame (rad)
    3 theta_j  jack, relative to the whippen (rad)
    4 theta_r  repetition lever, relative to the whippen (rad)
    5 theta_h  hammer, ground -> hammer frame (rad)
    6 u1       shank axial elastic coordinate (1)                [flexible_shank]
    7 v1       shank bending coordinate, x^2 term (1/m)          [flexible_shank]
    8 v2       shank bending coordinate, x^3 term (1/m^2)        [flexible_shank]
    9 z_b      bristle deflection of the first contact whose friction is a bristle
               law (m), the back check's by default              [bristle law]
   10-14       bristle deflections of the pins key, whippen, jack, repetition and
               hammer (rad)                                      [Dahl law at the pins]
   15-17       bristle deflections of further contacts with a bristle law (m)

Coordinates 10-17 exist for the Dahl friction option (``friction_law.joint`` and
``friction_law.contact`` ``dahl``: every friction element sticks, as a real action does;
docs/touch.md); off, they are frozen at zero and the model is as before.

The mass matrix is block diagonal (key | whippen, jack, repetition | hammer and
shank | each bristle); each block is assembled and solved on its own. State y = [q (18),
qdot (18)].

The bristle deflection z_b follows a first-order law, dz/dt = r(slip, z) (LuGre,
normalised by the normal force, see ``bristle_rate``). It is carried as a coordinate
whose rate relaxes to r: zdd = (r - zd) / tau, tau = ``sp[S_ZTAU]`` (20 us) while its
contact carries load, ``sp[S_ZOPEN]`` (1 ms) while it is open. That keeps the state
second-order, which the Rosenbrock integrator's Jacobian structure [[0, I], [JA, JB]]
needs, at a lag of tau behind the law.
Each body is a frame with origin org, angle phi and their Jacobians; forces
enter through J^T F, inertia as sum m Jc^T Jc + I Jphi Jphi^T, and velocity-product
terms through each frame's bias acceleration. Everything
is scalar code so numba compiles it; with NUMBA_DISABLE_JIT=1 the same code runs
as plain Python/numpy (the reference implementation of the benchmark).

Compiled with numpy's error model: a division by zero (a zero parameter) gives inf or
NaN, which the integrators report as a non-finite state, not an exception from inside a
blow. The functions called per step and per output row (``rhs``, ``sample_outputs``,
``energy``, and the Rosenbrock integrator's loop) allocate nothing (they work in the
arrays they are given), so they are compiled without numba's reference counting
(``_nrt=False``): counting the references of the model's and workspace's arrays took
9 % of a full blow (docs/performance.md).
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
from numba import njit

# numba's options for what runs per step and per output row: cached, numpy's error
# model, no reference counting (``_nrt``: numba's own flag, missing from its typing)
HOT: dict[str, Any] = {"cache": True, "error_model": "numpy", "_nrt": False}

NQ = 18
NY = 2 * NQ
NQ_MECH = 9  # the mechanism's coordinates (all but the bristles): what Python-level effects see
QK, QYK, QW, QJ, QR, QH, QU1, QV1, QV2, QZ = range(10)
QZ_PIN = 10  # the pins' bristle deflections: QZ_PIN + joint row (key ... hammer)
QZ_CONTACT = (QZ, 15, 16, 17)  # the coordinates of the contacts' bristles, in turn
NY_BASE = 20  # the state before the Dahl option's bristles (the error norms' count)
BLOCKS = ((0, 2), (2, 5), (5, 9))  # the mechanism's blocks; each bristle is its own

# frames
F_GROUND, F_PIVOT, F_KEY, F_WHIPPEN, F_JACK, F_REP, F_HAMMER, F_HEAD = range(8)
N_RIGID_FRAMES = 8  # shank section frames follow, one per shank feature

# feature kinds
K_LINE, K_CIRCLE, K_HYBRID = 1, 2, 3

# scalar parameter slots (sp)
S_G = 0
S_PG2X, S_PG2Y, S_PG3X, S_PG3Y = 1, 2, 3, 4
S_PW2X, S_PW2Y, S_PW3X, S_PW3Y = 5, 6, 7, 8
S_ROOTX, S_ROOTY = 9, 10  # shank root in the hammer frame
S_DX, S_DY, S_NX, S_NY = 11, 12, 13, 14  # shank axis and transverse unit vectors (hammer frame)
S_L, S_EA, S_EJ, S_BETA = 15, 16, 17, 18  # beam length, axial & bending stiffness, damping
S_KEYPX, S_KEYPY = 19, 20  # input force point on the key
S_PIVY0 = 21
S_JACK_T, S_REP_K, S_REP_TH0 = 22, 23, 24
S_LIFTOFF, S_FLEX = 25, 26
S_BRISTLE = 27  # 1 when one contact's friction is the bristle law (z_b moves)
S_ZTAU, S_ZOPEN = 28, 29  # bristle rate relaxation time; bristle recovery when open (s)
# 1 when the shank's axial coordinate is one-way coupled (see accelerations): the mechanism
# sees an axially rigid shank, u1 is driven by the axial force it transmits; S_AXW2 is the
# axial mode's EA L / M_u1u1 (1/s^2)
S_AXIAL_ONEWAY, S_AXW2 = 30, 31
N_SP = 32

# joint friction rows (jf): key, whippen, jack, repetition, hammer, key slider on its
# balance-rail pin (lift-off; force in N, speed in m/s) ; cols E, F1, F2, wt
JOINT_COORD = (QK, QW, QJ, QR, QH, QYK)

# contact law columns (cl)
L_A, L_B, L_C, L_D, L_MU_A, L_B1, L_B2, L_VT, L_ON, L_TYPE, L_P1, L_P2 = range(12)
# friction law (L_FLAW): Eq. 3.6's smoothed Coulomb law, or the bristle law (LuGre) with
# stiffness L_SIG0 (1/m, per newton of normal force), damping L_SIG1 (s/m) and static
# coefficient L_MU_S (L_MU_A stays the kinetic one, L_VT the Stribeck speed)
L_FLAW, L_SIG0, L_SIG1, L_MU_S = 12, 13, 14, 15
L_ZSLOT = 16  # the coordinate of the contact's bristle deflection (a bristle law's)
N_LAW = 17
FRICTION_SMOOTHED, FRICTION_BRISTLE = 0, 1
# pin-joint friction columns (jf) past E, F1, F2, w_t: the Dahl law (J_LAW 1) with
# normalised stiffness J_SIG0 (1/rad: the torque is E sig0 z) and damping J_SIG1 (s/rad)
J_LAW, J_SIG0, J_SIG1 = 4, 5, 6
N_JF = 7
# normal-law types (L_TYPE): the thesis's Hunt-Crossley fit; rate-independent hysteresis
# (L_P1 = loading/unloading ratio h, L_P2 = velocity scale); in series with a massless
# spring of stiffness L_P1 (a compliant string)
LAW_HUNT_CROSSLEY, LAW_HYSTERETIC, LAW_SERIES_SPRING = 0, 1, 2
# contact feature columns (cf[i, side, :])
C_KIND, C_FRAME, C_X, C_Y, C_NX, C_NY, C_R, C_A0, C_A1 = range(9)

# per-contact output columns
O_PEN, O_PENRATE, O_FN, O_FT, O_SLIP, O_PX, O_PY = range(7)
N_CONTACT_OUT = 7


@njit(cache=True, error_model="numpy", inline="always")
def _block(f):
    """Coordinate range [lo, hi) that moves frame f."""
    if f <= F_KEY:
        return 0, 2
    if f <= F_REP:
        return 2, 5
    return 5, 9


@njit(cache=True, error_model="numpy", inline="always")
def _shank_point(xi, q, qd, sp):
    """Centre of the shank's cross-section at xi from the root, in the hammer frame.

    Taylor shapes u = xi u1, v = xi^2 v1 + xi^3 v2, with the axial foreshortening
    s(xi) that bending causes. Returns position (px, py), velocity relative to the
    hammer (pdx, pdy), ds/dv1, ds/dv2 and the velocity-product term of s'' (quad).
    """
    # a one-way coupled axial coordinate does not move the mechanism's shank
    rigid_axial = sp[S_AXIAL_ONEWAY] > 0.5
    u1 = 0.0 if rigid_axial else q[QU1]
    v1 = q[QV1]
    v2 = q[QV2]
    du1 = 0.0 if rigid_axial else qd[QU1]
    dv1 = qd[QV1]
    dv2 = qd[QV2]
    dx, dy, nx, ny = sp[S_DX], sp[S_DY], sp[S_NX], sp[S_NY]
    xi2 = xi * xi
    xi3 = xi2 * xi
    xi4 = xi3 * xi
    xi5 = xi4 * xi
    s_fore = (2.0 / 3.0) * xi3 * v1 * v1 + 1.5 * xi4 * v1 * v2 + 0.9 * xi5 * v2 * v2
    ds1 = (4.0 / 3.0) * xi3 * v1 + 1.5 * xi4 * v2
    ds2 = 1.5 * xi4 * v1 + 1.8 * xi5 * v2
    a = xi * (1.0 + u1) - s_fore
    b = xi2 * v1 + xi3 * v2
    px = sp[S_ROOTX] + dx * a + nx * b
    py = sp[S_ROOTY] + dy * a + ny * b
    adot = xi * du1 - ds1 * dv1 - ds2 * dv2
    bdot = xi2 * dv1 + xi3 * dv2
    pdx = dx * adot + nx * bdot
    pdy = dy * adot + ny * bdot
    quad = (4.0 / 3.0) * xi3 * dv1 * dv1 + 3.0 * xi4 * dv1 * dv2 + 1.8 * xi5 * dv2 * dv2
    return px, py, pdx, pdy, ds1, ds2, quad


@njit(cache=True, error_model="numpy", inline="always")
def beam_section(xi, q, qd, sp, k, org, phi, w, vO, JO, Jp, aO, al, cs, ch, sh, need_cs):
    """Frame k = cross-section of the shank at distance xi from its root."""
    th = q[QH]
    wh = qd[QH]
    dx, dy, nx, ny = sp[S_DX], sp[S_DY], sp[S_NX], sp[S_NY]
    sg = dx * ny - dy * nx
    xi2 = xi * xi
    xi3 = xi2 * xi
    px, py, pdx, pdy, ds1, ds2, quad = _shank_point(xi, q, qd, sp)
    rpx = ch * px - sh * py
    rpy = sh * px + ch * py
    org[k, 0] = sp[S_PG3X] + rpx
    org[k, 1] = sp[S_PG3Y] + rpy
    slope = 2.0 * xi * q[QV1] + 3.0 * xi2 * q[QV2]
    phi[k] = th + sg * slope
    if need_cs:
        cs[k, 0] = math.cos(phi[k])
        cs[k, 1] = math.sin(phi[k])
    dslope = 2.0 * xi * qd[QV1] + 3.0 * xi2 * qd[QV2]
    w[k] = wh + sg * dslope
    for j in range(QH, QV2 + 1):
        JO[k, 0, j] = 0.0
        JO[k, 1, j] = 0.0
        Jp[k, j] = 0.0
    JO[k, 0, QH] = -rpy
    JO[k, 1, QH] = rpx
    Jp[k, QH] = 1.0
    if sp[S_FLEX] > 0.5:
        ex = ch * dx - sh * dy
        ey = sh * dx + ch * dy
        tx = ch * nx - sh * ny
        ty = sh * nx + ch * ny
        JO[k, 0, QU1] = ex * xi
        JO[k, 1, QU1] = ey * xi
        JO[k, 0, QV1] = -ex * ds1 + tx * xi2
        JO[k, 1, QV1] = -ey * ds1 + ty * xi2
        JO[k, 0, QV2] = -ex * ds2 + tx * xi3
        JO[k, 1, QV2] = -ey * ds2 + ty * xi3
        Jp[k, QV1] = sg * 2.0 * xi
        Jp[k, QV2] = sg * 3.0 * xi2
        rdx = ch * pdx - sh * pdy  # R pdot
        rdy = sh * pdx + ch * pdy
        vO[k, 0] = -wh * rpy + rdx
        vO[k, 1] = wh * rpx + rdy
        aO[k, 0] = -wh * wh * rpx - 2.0 * wh * rdy - ex * quad
        aO[k, 1] = -wh * wh * rpy + 2.0 * wh * rdx - ey * quad
    else:
        vO[k, 0] = -wh * rpy
        vO[k, 1] = wh * rpx
        aO[k, 0] = -wh * wh * rpx
        aO[k, 1] = -wh * wh * rpy
    al[k] = 0.0


@njit(cache=True, error_model="numpy", inline="always")
def _child_frame(k, parent, px, py, q_own, qd_own, org, phi, w, vO, JO, Jp, aO, al, cs, qi):
    """Frame k pinned at parent-frame point (px, py), turning by coordinate qi."""
    c = cs[parent, 0]
    s = cs[parent, 1]
    rx = c * px - s * py
    ry = s * px + c * py
    org[k, 0] = org[parent, 0] + rx
    org[k, 1] = org[parent, 1] + ry
    wp = w[parent]
    lo, hi = _block(k)
    for j in range(lo, hi):
        JO[k, 0, j] = JO[parent, 0, j] - ry * Jp[parent, j]
        JO[k, 1, j] = JO[parent, 1, j] + rx * Jp[parent, j]
        Jp[k, j] = Jp[parent, j]
    Jp[k, qi] += 1.0
    vO[k, 0] = vO[parent, 0] - wp * ry
    vO[k, 1] = vO[parent, 1] + wp * rx
    aO[k, 0] = aO[parent, 0] - al[parent] * ry - wp * wp * rx
    aO[k, 1] = aO[parent, 1] + al[parent] * rx - wp * wp * ry
    phi[k] = phi[parent] + q_own
    cs[k, 0] = math.cos(phi[k])
    cs[k, 1] = math.sin(phi[k])
    w[k] = wp + qd_own
    al[k] = al[parent]


@njit(cache=True, error_model="numpy", inline="always")
def kinematics(q, qd, sp, sec_xi, org, phi, w, vO, JO, Jp, aO, al, cs):
    """Fill every frame's pose, velocity, Jacobians and bias accelerations."""
    nf = org.shape[0]
    for k in range(nf):
        org[k, 0] = 0.0
        org[k, 1] = 0.0
        phi[k] = 0.0
        w[k] = 0.0
        vO[k, 0] = 0.0
        vO[k, 1] = 0.0
        aO[k, 0] = 0.0
        aO[k, 1] = 0.0
        al[k] = 0.0
    # Jacobian entries outside a frame's coordinate block stay zero from make_workspace
    # and are never read.
    # ground and key pivot (massless body when lift-off is on) do not turn
    for f in (F_GROUND, F_PIVOT):
        cs[f, 0] = 1.0
        cs[f, 1] = 0.0
    org[F_PIVOT, 1] = sp[S_PIVY0] + q[QYK]
    if sp[S_LIFTOFF] > 0.5:
        JO[F_PIVOT, 1, QYK] = 1.0
        vO[F_PIVOT, 1] = qd[QYK]
    _child_frame(F_KEY, F_PIVOT, 0.0, 0.0, q[QK], qd[QK], org, phi, w, vO, JO, Jp, aO, al, cs, QK)
    # whippen on its ground pivot
    org[F_WHIPPEN, 0] = sp[S_PG2X]
    org[F_WHIPPEN, 1] = sp[S_PG2Y]
    phi[F_WHIPPEN] = q[QW]
    cs[F_WHIPPEN, 0] = math.cos(q[QW])
    cs[F_WHIPPEN, 1] = math.sin(q[QW])
    w[F_WHIPPEN] = qd[QW]
    Jp[F_WHIPPEN, QW] = 1.0
    _child_frame(F_JACK, F_WHIPPEN, sp[S_PW2X], sp[S_PW2Y], q[QJ], qd[QJ],
                 org, phi, w, vO, JO, Jp, aO, al, cs, QJ)
    _child_frame(F_REP, F_WHIPPEN, sp[S_PW3X], sp[S_PW3Y], q[QR], qd[QR],
                 org, phi, w, vO, JO, Jp, aO, al, cs, QR)
    # hammer base on its ground pivot
    org[F_HAMMER, 0] = sp[S_PG3X]
    org[F_HAMMER, 1] = sp[S_PG3Y]
    phi[F_HAMMER] = q[QH]
    ch = math.cos(q[QH])
    sh = math.sin(q[QH])
    cs[F_HAMMER, 0] = ch
    cs[F_HAMMER, 1] = sh
    w[F_HAMMER] = qd[QH]
    Jp[F_HAMMER, QH] = 1.0
    # head: carried at the shank's free end (its frame origin is the shank tip)
    beam_section(sp[S_L], q, qd, sp, F_HEAD, org, phi, w, vO, JO, Jp, aO, al, cs, ch, sh, True)
    for s in range(sec_xi.shape[0]):
        beam_section(sec_xi[s], q, qd, sp, N_RIGID_FRAMES + s, org, phi, w, vO, JO, Jp, aO, al,
                      cs, ch, sh, True)


@njit(cache=True, error_model="numpy", inline="always")
def _add_point_force(f, px, py, fx, fy, org, JO, Jp, Q):
    if f == F_GROUND:
        return
    rx = px - org[f, 0]
    ry = py - org[f, 1]
    mom = rx * fy - ry * fx
    lo, hi = _block(f)
    for j in range(lo, hi):
        Q[j] += JO[f, 0, j] * fx + JO[f, 1, j] * fy + Jp[f, j] * mom


@njit(cache=True, error_model="numpy", inline="always")
def _feature_world(cf, i, side, org, cs):
    f = int(cf[i, side, C_FRAME])
    c = cs[f, 0]
    s = cs[f, 1]
    x = cf[i, side, C_X]
    y = cf[i, side, C_Y]
    nx = cf[i, side, C_NX]
    ny = cf[i, side, C_NY]
    return f, org[f, 0] + c * x - s * y, org[f, 1] + s * x + c * y, c * nx - s * ny, s * nx + c * ny


@njit(cache=True, error_model="numpy", inline="always")
def contact_geometry(cf, i, org, phi, cs):
    """Penetration (m), unit normal from body 1 to body 2, and contact point."""
    k1 = int(cf[i, 0, C_KIND])
    k2 = int(cf[i, 1, C_KIND])
    f1, x1, y1, n1x, n1y = _feature_world(cf, i, 0, org, cs)
    f2, x2, y2, n2x, n2y = _feature_world(cf, i, 1, org, cs)
    r1 = cf[i, 0, C_R]
    r2 = cf[i, 1, C_R]
    if k1 == K_LINE:  # line on body 1, circle on body 2
        d = n1x * (x2 - x1) + n1y * (y2 - y1)
        pen = r2 - d
        nx, ny = n1x, n1y
        px = x2 - nx * (r2 - 0.5 * pen)
        py = y2 - ny * (r2 - 0.5 * pen)
    elif k2 == K_LINE:  # circle on body 1, line on body 2
        d = n2x * (x1 - x2) + n2y * (y1 - y2)
        pen = r1 - d
        nx, ny = -n2x, -n2y
        px = x1 + nx * (r1 - 0.5 * pen)
        py = y1 + ny * (r1 - 0.5 * pen)
    elif k1 == K_HYBRID:  # arc with tangent extensions on body 1, circle on body 2
        wx = x2 - x1
        wy = y2 - y1
        a0 = cf[i, 0, C_A0]
        a1 = cf[i, 0, C_A1]
        mid = 0.5 * (a0 + a1)
        # direction of the circle's centre in body 1, within pi of the arc's middle
        off = math.atan2(wy, wx) - phi[f1] - mid
        while off > math.pi:
            off -= 2.0 * math.pi
        while off < -math.pi:
            off += 2.0 * math.pi
        beta = mid + off
        if a0 <= beta <= a1:
            dist = math.sqrt(wx * wx + wy * wy)
            nx = wx / dist
            ny = wy / dist
        else:
            e = a0 if beta < a0 else a1
            nx = math.cos(e + phi[f1])
            ny = math.sin(e + phi[f1])
            dist = nx * wx + ny * wy
        pen = r1 + r2 - dist
        px = x2 - nx * (r2 - 0.5 * pen)
        py = y2 - ny * (r2 - 0.5 * pen)
    else:  # circle - circle
        wx = x2 - x1
        wy = y2 - y1
        dist = math.sqrt(wx * wx + wy * wy)
        nx = wx / dist
        ny = wy / dist
        pen = r1 + r2 - dist
        px = x1 + nx * (r1 - 0.5 * pen)
        py = y1 + ny * (r1 - 0.5 * pen)
    return f1, f2, pen, nx, ny, px, py


@njit(cache=True, error_model="numpy", inline="always")
def friction_coefficient(slip, mu_a, b1, b2, vt):
    """Smoothed Coulomb law, Eq. 3.6 (odd in the slip speed)."""
    r = slip / vt
    return mu_a * (math.tanh(r) + b1 * r / (1.0 + b2 * r * r * r * r))


@njit(cache=True, error_model="numpy", inline="always")
def bristle_coefficient(slip, mu_a, mu_s, vt):
    """Steady sliding coefficient g(v) = A + (mu_s - A) exp(-(v/v_t)^2) of the bristle law
    (the Stribeck curve of LuGre; equal to Eq. 3.6's A once |v| >> v_t)."""
    r = slip / vt
    return mu_a + (mu_s - mu_a) * math.exp(-r * r)


@njit(cache=True, error_model="numpy", inline="always")
def bristle_rate(slip, z, mu_a, mu_s, vt, sig0):
    """dz/dt of the bristle law: slip - sig0 |slip| z / g(slip) (LuGre, per newton).

    At zero slip z stands still whatever the load: the contact sticks, and the friction
    force fn sig0 z holds any tangential load up to fn mu_s without creeping."""
    return slip - sig0 * abs(slip) * z / bristle_coefficient(slip, mu_a, mu_s, vt)


@njit(cache=True, error_model="numpy", inline="always")
def normal_force(pen, pen_rate, a, b, c, d):
    """Eq. 3.2-3.3: f = (a x^3 + b x^2 + c x)(1 + D xdot), never pulling."""
    if pen <= 0.0:
        return 0.0
    f = (a * pen * pen * pen + b * pen * pen + c * pen) * (1.0 + d * pen_rate)
    return f if f > 0.0 else 0.0


@njit(cache=True, error_model="numpy", inline="always")
def normal_force_law(pen, pen_rate, law):
    """Normal force (N) of one contact under its law row (see LAW_* types)."""
    kind = int(law[L_TYPE])
    a, b, c = law[L_A], law[L_B], law[L_C]
    if kind == LAW_HYSTERETIC:
        # loading follows (1 + h) f_fit, unloading (1 - h) f_fit, whatever the speed
        if pen <= 0.0:
            return 0.0
        f = (a * pen * pen * pen + b * pen * pen + c * pen) * (
            1.0 + law[L_P1] * math.tanh(pen_rate / law[L_P2]))
        return f if f > 0.0 else 0.0
    if kind == LAW_SERIES_SPRING:
        # felt (penetration x_f) in series with a spring k: f_fit(x_f) = k (pen - x_f)
        if pen <= 0.0:
            return 0.0
        k = law[L_P1]
        xf = pen * 0.5
        for _ in range(30):
            g = a * xf * xf * xf + b * xf * xf + c * xf - k * (pen - xf)
            dg = 3.0 * a * xf * xf + 2.0 * b * xf + c + k
            step = g / dg
            xf -= step
            if xf < 0.0:
                xf = 0.0
            elif xf > pen:
                xf = pen
            if abs(step) < 1e-15:
                break
        f = k * (pen - xf) * (1.0 + law[L_D] * pen_rate)
        return f if f > 0.0 else 0.0
    return normal_force(pen, pen_rate, a, b, c, law[L_D])


@njit(cache=True, error_model="numpy", inline="always")
def contacts(cf, cl, org, phi, cs, w, vO, JO, Jp, Q, cout, full, q, qd, ztau, zopen,
             forces=True):
    """Add every contact's normal and friction force to Q; fill cout per contact.

    With ``full`` false, separated contacts get only their penetration (the
    integrator's fast path); with ``full`` true every output column is filled.
    With ``forces`` false Q is left alone (sampled outputs need no dynamics).
    q, qd: the coordinates and their rates, for the bristle deflections (a contact with a
    bristle law has its own, coordinate cl[i, L_ZSLOT]). With ``forces`` each bristle's
    equation goes into Q too: its rate relaxes to the law's dz/dt within ``ztau`` while
    its contact carries load, and the bristles recover within ``zopen`` while it is open
    (which keeps the stiff -1/ztau out of the Jacobian there, so explicit steps stay
    possible).
    """
    for i in range(cl.shape[0]):
        zs = int(cl[i, L_ZSLOT])
        if zs > 0 and forces:  # the open contact's bristles recover (overwritten if loaded)
            Q[zs] = (-q[zs] / zopen - qd[zs]) / zopen
        if cl[i, L_ON] < 0.5:
            for j in range(N_CONTACT_OUT):
                cout[i, j] = 0.0
            continue
        f1, f2, pen, nx, ny, px, py = contact_geometry(cf, i, org, phi, cs)
        cout[i, O_PEN] = pen
        if pen <= 0.0 and not full:
            cout[i, O_FN] = 0.0
            cout[i, O_FT] = 0.0
            continue
        v1x = vO[f1, 0] - w[f1] * (py - org[f1, 1])
        v1y = vO[f1, 1] + w[f1] * (px - org[f1, 0])
        v2x = vO[f2, 0] - w[f2] * (py - org[f2, 1])
        v2y = vO[f2, 1] + w[f2] * (px - org[f2, 0])
        rvx = v2x - v1x
        rvy = v2y - v1y
        pen_rate = -(nx * rvx + ny * rvy)
        tx = -ny
        ty = nx
        slip = tx * rvx + ty * rvy
        fn = normal_force_law(pen, pen_rate, cl[i])
        ft = 0.0
        if fn > 0.0 and cl[i, L_FLAW] == FRICTION_BRISTLE:
            vt = cl[i, L_VT]
            zb = q[zs]
            zbd = qd[zs]
            if forces:
                Q[zs] = (bristle_rate(slip, zb, cl[i, L_MU_A], cl[i, L_MU_S], vt, cl[i, L_SIG0])
                         - zbd) / ztau
            # bristle damping only near sticking (else it would add viscous friction)
            r = slip / vt
            ft = -fn * (cl[i, L_SIG0] * zb + cl[i, L_SIG1] * math.exp(-r * r) * zbd)
        elif fn > 0.0 and cl[i, L_MU_A] > 0.0:
            mu = friction_coefficient(slip, cl[i, L_MU_A], cl[i, L_B1], cl[i, L_B2], cl[i, L_VT])
            ft = -fn * mu
        if fn > 0.0 and forces:
            fx = fn * nx + ft * tx
            fy = fn * ny + ft * ty
            _add_point_force(f2, px, py, fx, fy, org, JO, Jp, Q)
            _add_point_force(f1, px, py, -fx, -fy, org, JO, Jp, Q)
        cout[i, O_PENRATE] = pen_rate
        cout[i, O_FN] = fn
        cout[i, O_FT] = ft
        cout[i, O_SLIP] = slip
        cout[i, O_PX] = px
        cout[i, O_PY] = py


@njit(cache=True, error_model="numpy", inline="always")
def joint_torque(omega, e, f1, f2, wt):
    """Eq. 3.8 pin-joint friction torque (opposes the joint's relative speed)."""
    r = omega / wt
    return e * (math.tanh(r) + f1 * r / (1.0 + f2 * r * r * r * r))


@njit(cache=True, error_model="numpy", inline="always")
def mass_element(f, m, inertia, cx, cy, g, cs, w, JO, Jp, aO, al, M, Q):
    rx = cs[f, 0] * cx - cs[f, 1] * cy
    ry = cs[f, 1] * cx + cs[f, 0] * cy
    wf = w[f]
    acx = aO[f, 0] - al[f] * ry - wf * wf * rx
    acy = aO[f, 1] + al[f] * rx - wf * wf * ry
    lo, hi = _block(f)
    for a in range(lo, hi):
        ja_x = JO[f, 0, a] - ry * Jp[f, a]
        ja_y = JO[f, 1, a] + rx * Jp[f, a]
        Q[a] -= m * (ja_x * acx + ja_y * (acy + g)) + inertia * Jp[f, a] * al[f]
        for b in range(lo, hi):
            jb_x = JO[f, 0, b] - ry * Jp[f, b]
            jb_y = JO[f, 1, b] + rx * Jp[f, b]
            M[a, b] += m * (ja_x * jb_x + ja_y * jb_y) + inertia * Jp[f, a] * Jp[f, b]


@njit(cache=True, error_model="numpy", inline="always")
def _solve(M, b, x, lo, n):
    """Solve the diagonal block [lo, n) by Gaussian elimination with partial pivoting.

    M and b are overwritten.
    """
    for c in range(lo, n):
        p = c
        big = abs(M[c, c])
        for r in range(c + 1, n):
            if abs(M[r, c]) > big:
                big = abs(M[r, c])
                p = r
        if p != c:
            for k in range(lo, n):
                tmp = M[c, k]
                M[c, k] = M[p, k]
                M[p, k] = tmp
            tmp = b[c]
            b[c] = b[p]
            b[p] = tmp
        for r in range(c + 1, n):
            fac = M[r, c] / M[c, c]
            if fac != 0.0:
                for k in range(c, n):
                    M[r, k] -= fac * M[c, k]
                b[r] -= fac * b[c]
    for r in range(n - 1, lo - 1, -1):
        acc = b[r]
        for k in range(r + 1, n):
            acc -= M[r, k] * x[k]
        x[r] = acc / M[r, r]


@njit(cache=True, error_model="numpy")
def n_extra_bristles(cl, jf):
    """How many of the Dahl option's bristle coordinates (10-17) move in this model."""
    n = 0
    for i in range(cl.shape[0]):
        if cl[i, L_ZSLOT] > QZ + 0.5:
            n += 1
    for j in range(jf.shape[0]):
        if jf[j, J_LAW] > 0.5:
            n += 1
    return n


def bristle_coords(cl: np.ndarray, jf: np.ndarray) -> list[int]:
    """The Dahl option's bristle coordinates (10-17) that move in this model."""
    out = [int(z) for z in cl[:, L_ZSLOT] if z > QZ + 0.5]
    out += [QZ_PIN + j for j in range(jf.shape[0]) if jf[j, J_LAW] > 0.5]
    return sorted(out)


class Model(NamedTuple):
    """The kernel's view of one model (rig.model.assembly.pack builds it)."""

    sp: np.ndarray      # scalar parameters, slots S_*
    sec_xi: np.ndarray  # shank sections carrying contact features: distance from the root (m)
    cf: np.ndarray      # contact features [contact, side, C_*]
    cl: np.ndarray      # contact laws [contact, L_*]
    jf: np.ndarray      # pin-joint friction [joint (JOINT_COORD), (E, F1, F2, w_t)]
    me: np.ndarray      # rigid mass elements [element, (frame, m, I, cx, cy)]
    beam: np.ndarray    # the shank's Gauss points [point, (xi, m dxi, rho J dxi)]


class Workspace(NamedTuple):
    """Scratch arrays for one evaluation (make_workspace allocates them once per run)."""

    org: np.ndarray   # frame origins (m)
    phi: np.ndarray   # frame angles (rad)
    w: np.ndarray     # frame angular velocities (rad/s)
    vO: np.ndarray    # origin velocities (m/s)
    JO: np.ndarray    # origin Jacobians [frame, xy, coordinate]
    Jp: np.ndarray    # angle Jacobians [frame, coordinate]
    aO: np.ndarray    # origin bias accelerations
    al: np.ndarray    # angle bias accelerations
    cs: np.ndarray    # cos, sin of each frame's angle
    M: np.ndarray     # mass matrix
    Q: np.ndarray     # generalized forces
    cout: np.ndarray  # per-contact outputs [contact, O_*]
    qdd: np.ndarray   # generalized accelerations
    qx: np.ndarray    # extra generalized forces (set by Python-level effects)
    jb: np.ndarray    # a shank particle's Jacobian columns (x, y, angle)


def make_workspace(n_frames: int, n_contacts: int) -> Workspace:
    """Scratch arrays for one evaluation (allocated once per integration)."""
    return Workspace(
        np.zeros((n_frames, 2)), np.zeros(n_frames), np.zeros(n_frames),
        np.zeros((n_frames, 2)), np.zeros((n_frames, 2, NQ)), np.zeros((n_frames, NQ)),
        np.zeros((n_frames, 2)), np.zeros(n_frames), np.zeros((n_frames, 2)),
        np.zeros((NQ, NQ)), np.zeros(NQ), np.zeros((n_contacts, N_CONTACT_OUT)),
        np.zeros(NQ), np.zeros(NQ), np.zeros((3, 4)),
    )


@njit(cache=True, error_model="numpy", inline="always")
def _shank_inertia(q, qd, sp, beam, g, ch, sh, M, Q, jb):
    """Mass matrix, gravity and velocity-product terms of the flexible shank's Gauss
    particles (xi, mass, rotary inertia) on the hammer block.

    The same sums as a particle frame per Gauss point through mass_element, done in
    the hammer frame: rotation leaves the dot products unchanged, so only gravity
    needs the hammer's angle (R^T y = (sin, cos)).
    """
    wh = qd[QH]
    dx, dy, nx, ny = sp[S_DX], sp[S_DY], sp[S_NX], sp[S_NY]
    sg = dx * ny - dy * nx
    jx = jb[0]
    jy = jb[1]
    jp = jb[2]
    for p in range(beam.shape[0]):
        xi = beam[p, 0]
        m = beam[p, 1]
        inertia = beam[p, 2]
        xi2 = xi * xi
        xi3 = xi2 * xi
        px, py, pdx, pdy, ds1, ds2, quad = _shank_point(xi, q, qd, sp)
        # bias acceleration and gravity direction, hammer frame
        ax = -wh * wh * px - 2.0 * wh * pdy - dx * quad + g * sh
        ay = -wh * wh * py + 2.0 * wh * pdx - dy * quad + g * ch
        # Jacobian columns for (theta_h, u1, v1, v2)
        jx[0] = -py
        jy[0] = px
        jp[0] = 1.0
        jx[1] = dx * xi
        jy[1] = dy * xi
        jp[1] = 0.0
        jx[2] = -dx * ds1 + nx * xi2
        jy[2] = -dy * ds1 + ny * xi2
        jp[2] = sg * 2.0 * xi
        jx[3] = -dx * ds2 + nx * xi3
        jy[3] = -dy * ds2 + ny * xi3
        jp[3] = sg * 3.0 * xi2
        for i in range(4):
            Q[QH + i] -= m * (jx[i] * ax + jy[i] * ay)
            for j in range(i, 4):
                M[QH + i, QH + j] += m * (jx[i] * jx[j] + jy[i] * jy[j]) + inertia * jp[i] * jp[j]
    # only the upper triangle got the particles; the rigid bodies' terms are symmetric
    for i in range(1, 4):
        for j in range(i):
            M[QH + i, QH + j] = M[QH + j, QH + i]


@njit(cache=True, error_model="numpy", inline="always")
def _inertia(q, qd, g, model, ws):
    """Kinematics, then M and Q with gravity and velocity-product terms (all bodies)."""
    sp, sec_xi, cf, cl, jf, me, beam = model
    org, phi, w, vO, JO, Jp, aO, al, cs, M, Q, cout, qdd, qx, jb = ws
    kinematics(q, qd, sp, sec_xi, org, phi, w, vO, JO, Jp, aO, al, cs)
    for a in range(NQ):
        Q[a] = 0.0
    # the bristles' rows are set whole by accelerations: only the mechanism's to clear
    for a in range(QZ):
        for b in range(QZ):
            M[a, b] = 0.0
    # rigid mass elements: frame, m, I, cx, cy
    for e in range(me.shape[0]):
        mass_element(int(me[e, 0]), me[e, 1], me[e, 2], me[e, 3], me[e, 4], g,
                      cs, w, JO, Jp, aO, al, M, Q)
    if sp[S_FLEX] > 0.5:
        _shank_inertia(q, qd, sp, beam, g, cs[F_HAMMER, 0], cs[F_HAMMER, 1], M, Q, jb)


@njit(cache=True, error_model="numpy", inline="always")
def accelerations(t, y, f_key, model, ws, full):
    """Generalized accelerations for state y under key force f_key (N, downward)."""
    sp, sec_xi, cf, cl, jf, me, beam = model
    org, phi, w, vO, JO, Jp, aO, al, cs, M, Q, cout, qdd, qx, jb = ws
    q = y[:NQ]
    qd = y[NQ : 2 * NQ]
    _inertia(q, qd, sp[S_G], model, ws)
    if sp[S_FLEX] > 0.5:
        ea = sp[S_EA]
        ej = sp[S_EJ]
        ln = sp[S_L]
        beta = sp[S_BETA]
        u1 = q[QU1] + beta * qd[QU1]
        v1 = q[QV1] + beta * qd[QV1]
        v2 = q[QV2] + beta * qd[QV2]
        if sp[S_AXIAL_ONEWAY] < 0.5:
            Q[QU1] -= ea * ln * u1
        Q[QV1] -= ej * (4.0 * ln * v1 + 6.0 * ln * ln * v2)
        Q[QV2] -= ej * (6.0 * ln * ln * v1 + 12.0 * ln * ln * ln * v2)
    # contacts
    contacts(cf, cl, org, phi, cs, w, vO, JO, Jp, Q, cout, full, q, qd, sp[S_ZTAU], sp[S_ZOPEN])
    # pin-joint friction and springs
    for jn in range(6):
        c = JOINT_COORD[jn]
        if jf[jn, J_LAW] > 0.5:
            # Dahl's law: the torque E sig0 z of the pin's bristles, deflected by the
            # pin's turning; they hold any torque below E without turning on, and slide
            # at E (dz/dt = w - |w| sig0 z); damped near sticking only
            zs = QZ_PIN + jn
            wj = qd[c]
            r = wj / jf[jn, 3]
            Q[c] -= jf[jn, 0] * (jf[jn, J_SIG0] * q[zs] + jf[jn, J_SIG1] * math.exp(-r * r)
                                 * qd[zs])
            Q[zs] = (wj - abs(wj) * jf[jn, J_SIG0] * q[zs] - qd[zs]) / sp[S_ZTAU]
        else:
            Q[c] -= joint_torque(qd[c], jf[jn, 0], jf[jn, 1], jf[jn, 2], jf[jn, 3])
    Q[QJ] += sp[S_JACK_T]
    Q[QR] -= sp[S_REP_K] * (q[QR] - sp[S_REP_TH0])
    # finger / motor force on the key top, straight down
    kx = cs[F_KEY, 0] * sp[S_KEYPX] - cs[F_KEY, 1] * sp[S_KEYPY]
    ky = cs[F_KEY, 1] * sp[S_KEYPX] + cs[F_KEY, 0] * sp[S_KEYPY]
    _add_point_force(F_KEY, org[F_KEY, 0] + kx, org[F_KEY, 1] + ky, 0.0, -f_key, org, JO, Jp, Q)
    for a in range(NQ):
        Q[a] += qx[a]
    # frozen coordinates
    if sp[S_LIFTOFF] < 0.5:
        M[QYK, QYK] = 1.0
        Q[QYK] = 0.0
    if sp[S_FLEX] < 0.5:
        for c in range(QU1, QV2 + 1):
            M[c, c] = 1.0
            Q[c] = 0.0
    oneway = sp[S_FLEX] > 0.5 and sp[S_AXIAL_ONEWAY] > 0.5
    mu_h = mu_v1 = mu_v2 = q_u = 0.0
    if oneway:
        # the mechanism moves as if the shank were axially rigid: take u1's row and column
        # out of the hammer block, keeping the row for the axial force it transmits
        mu_h = M[QU1, QH]
        mu_v1 = M[QU1, QV1]
        mu_v2 = M[QU1, QV2]
        q_u = Q[QU1]
        for c in (QH, QV1, QV2):
            M[QU1, c] = 0.0
            M[c, QU1] = 0.0
        M[QU1, QU1] = 1.0
        Q[QU1] = 0.0
    # the bristle deflections: unit mass, each its own block, their equations set in Q
    # above (by contacts and the pins' loop); the first contact's is frozen (Q 0) without a
    # bristle law, and so are the others without theirs (no law writes their Q)
    for blk in range(3):
        _solve(M, Q, qdd, BLOCKS[blk][0], BLOCKS[blk][1])
    for c in range(QZ, NQ):
        M[c, c] = 1.0
        qdd[c] = Q[c]
    if oneway:
        # u1's own equation, M_uu u1'' + EA L (u1 + beta u1') = Q_u - sum_j M_uj qdd_j, with
        # the rigid mechanism's accelerations: a linear oscillator driven by the quasi-static
        # axial strain s = (Q_u - sum_j M_uj qdd_j) / (EA L)
        s_qs = (q_u - mu_h * qdd[QH] - mu_v1 * qdd[QV1] - mu_v2 * qdd[QV2]) / (
            sp[S_EA] * sp[S_L])
        qdd[QU1] = sp[S_AXW2] * (s_qs - q[QU1] - sp[S_BETA] * qd[QU1])
    return qdd


@njit(**HOT)
def rhs(t, y, f_key, model, ws, dy):
    """dy/dt of the state under key force f_key."""
    qdd = accelerations(t, y, f_key, model, ws, False)
    for a in range(NQ):
        dy[a] = y[NQ + a]
        dy[NQ + a] = qdd[a]


# sampled output columns (besides the state): see sample_outputs
X_HEAD_VX, X_HEAD_VY, X_HEAD_X, X_HEAD_Y, X_KEYTOP_Y, X_TIP_DEFL, X_STRAIN, X_KEY_LIFT = range(8)
N_X = 8


@njit(**HOT)
def sample_outputs(model, ws, Y, F, head_pt, gauge, out, cout_all):
    """Derived channels for each state row of Y under key forces F.

    head_pt: striking-felt centre in the head frame; gauge: (xi from root, y) of
    the strain gauge. out[X_*, row] gets the derived values and cout_all[O_*, row,
    contact] every contact's outputs (channel-major, so each channel is contiguous).
    """
    sp, sec_xi, cf, cl, jf, me, beam = model
    org, phi, w, vO, JO, Jp, aO, al, cs, M, Q, cout, qdd, qx, jb = ws
    for r in range(Y.shape[0]):
        y = Y[r]
        kinematics(y[:NQ], y[NQ : 2 * NQ], sp, sec_xi, org, phi, w, vO, JO, Jp, aO, al, cs)
        contacts(cf, cl, org, phi, cs, w, vO, JO, Jp, Q, cout, True, y[:NQ], y[NQ : 2 * NQ],
                 sp[S_ZTAU], sp[S_ZOPEN], False)
        for i in range(cout.shape[0]):
            for j in range(N_CONTACT_OUT):
                cout_all[j, r, i] = cout[i, j]
        hx = cs[F_HEAD, 0] * head_pt[0] - cs[F_HEAD, 1] * head_pt[1]
        hy = cs[F_HEAD, 1] * head_pt[0] + cs[F_HEAD, 0] * head_pt[1]
        out[X_HEAD_VX, r] = vO[F_HEAD, 0] - w[F_HEAD] * hy
        out[X_HEAD_VY, r] = vO[F_HEAD, 1] + w[F_HEAD] * hx
        out[X_HEAD_X, r] = org[F_HEAD, 0] + hx
        out[X_HEAD_Y, r] = org[F_HEAD, 1] + hy
        ky = cs[F_KEY, 1] * sp[S_KEYPX] + cs[F_KEY, 0] * sp[S_KEYPY]
        out[X_KEYTOP_Y, r] = org[F_KEY, 1] + ky
        ln = sp[S_L]
        out[X_TIP_DEFL, r] = ln * ln * y[QV1] + ln * ln * ln * y[QV2]
        xi = gauge[0]
        yg = gauge[1]
        u1 = y[QU1]
        curv = 2.0 * y[QV1] + 6.0 * xi * y[QV2]
        out[X_STRAIN, r] = u1 + 0.5 * u1 * u1 - yg * curv + 0.5 * yg * yg * curv * curv
        out[X_KEY_LIFT, r] = y[QYK]


@njit(**HOT)
def energy(y, model, ws):
    """Kinetic, gravitational and elastic (shank) energy (J) of state y."""
    sp, sec_xi, cf, cl, jf, me, beam = model
    org, phi, w, vO, JO, Jp, aO, al, cs, M, Q, cout, qdd, qx, jb = ws
    q = y[:NQ]
    qd = y[NQ : 2 * NQ]
    _inertia(q, qd, 0.0, model, ws)
    kin = 0.0
    for a in range(NQ_MECH):
        for b in range(NQ_MECH):
            kin += 0.5 * qd[a] * M[a, b] * qd[b]
    g = sp[S_G]
    pot = 0.0
    for e in range(me.shape[0]):
        f = int(me[e, 0])
        pot += me[e, 1] * g * (org[f, 1] + cs[f, 1] * me[e, 3] + cs[f, 0] * me[e, 4])
    elastic = 0.0
    if sp[S_FLEX] > 0.5:
        k = org.shape[0] - 1
        ch = math.cos(q[QH])
        sh = math.sin(q[QH])
        for p in range(beam.shape[0]):
            beam_section(beam[p, 0], q, qd, sp, k, org, phi, w, vO, JO, Jp, aO, al, cs, ch, sh,
                          False)
            pot += beam[p, 1] * g * org[k, 1]
        ln = sp[S_L]
        v1 = q[QV1]
        v2 = q[QV2]
        elastic = 0.5 * sp[S_EA] * ln * q[QU1] * q[QU1] + 0.5 * sp[S_EJ] * (
            4.0 * ln * v1 * v1 + 12.0 * ln * ln * v1 * v2 + 12.0 * ln * ln * ln * v2 * v2)
    return kin, pot, elastic
