"""Effects: the flexible shank, key lift-off, and users' own effects."""

from __future__ import annotations

import math
import textwrap

import numpy as np
import pytest
from scipy.linalg import eigh
from typer.testing import CliRunner

from rig.cli import app
from rig.inputs.params import Parameters
from rig.model import kernel as k
from rig.model.action import ActionModel
from rig.model.effects import BUILTIN, Effect, RailLift, make, rail_lift
from rig.recordings import runfile

ROOT_X, HEAD_X = -0.0415, -0.1275  # shank root and head end in the hammer frame (m)


def hammer_fe_first_mode(n_el: int) -> float:
    """First bending frequency (Hz) of the hammer in free flight, pinned at its flange.

    Independent of the model's code: Euler-Bernoulli beam, Hermite cubic elements,
    clamped in the hammer base (a rigid arm turning about the flange pin), the head
    a rigid body (mass, rotary inertia, centre-of-mass offset) at the shank's end.
    DOFs: hammer rotation theta, then (w, w') per node from the root.
    """
    p = Parameters.default().tree
    beam, bodies = p["hammer_shank_beam"], p["bodies"]
    length, ei, rho_a = beam["length"], beam["E"] * beam["Jzz"], beam["density"] * beam["area"]
    n = 1 + 2 * (n_el + 1)  # theta, then (w, w') at each node from the root
    mass, stiff = np.zeros((n, n)), np.zeros((n, n))
    base = bodies["hammer_base"]
    mass[0, 0] += base["inertia"] + base["mass"] * float(np.dot(base["com"], base["com"]))
    le = length / n_el
    gx, gw = np.polynomial.legendre.leggauss(6)
    for e in range(n_el):
        dofs = [0, 1 + 2 * e, 2 + 2 * e, 3 + 2 * e, 4 + 2 * e]  # theta, w_i, s_i, w_j, s_j
        for xg, wg in zip(gx, gw, strict=True):
            s = 0.5 * (xg + 1)
            shape = np.array([1 - 3 * s**2 + 2 * s**3, le * (s - 2 * s**2 + s**3),
                              3 * s**2 - 2 * s**3, le * (-s**2 + s**3)])
            curv = np.array([-6 + 12 * s, le * (-4 + 6 * s), 6 - 12 * s, le * (-2 + 6 * s)]) / le**2
            x = ROOT_X - (e + s) * le  # the beam runs toward -x
            vel = np.concatenate([[x], shape])  # transverse velocity per DOF rate
            cur = np.concatenate([[0.0], curv])
            mass[np.ix_(dofs, dofs)] += rho_a * np.outer(vel, vel) * wg * le / 2
            stiff[np.ix_(dofs, dofs)] += ei * np.outer(cur, cur) * wg * le / 2
    clamp = [1, 2]  # w and w' at the root are held by the hammer base
    keep = [i for i in range(n) if i not in clamp]
    head = bodies["hammer_head"]
    cx, cy = head["com"]
    tip_w, tip_s = n - 2, n - 1
    # head angle = theta - w'(L) (beam axis along -x); head c.o.m. displacement from theta,
    # tip translation and head rotation
    phi = np.zeros(n)
    phi[0], phi[tip_s] = 1.0, -1.0
    ux = -cy * phi
    uy = cx * phi
    uy[0] += HEAD_X
    uy[tip_w] += 1.0
    mass += head["mass"] * (np.outer(ux, ux) + np.outer(uy, uy)) + head["inertia"] * np.outer(phi,
                                                                                            phi)
    lam = eigh(stiff[np.ix_(keep, keep)], mass[np.ix_(keep, keep)], eigvals_only=True)
    flexible = lam[lam > 1.0]
    return float(np.sqrt(flexible[0]) / (2 * math.pi))


def test_independent_fe_model_converges():
    f10, f40 = hammer_fe_first_mode(10), hammer_fe_first_mode(40)
    assert abs(f10 - f40) / f40 < 1e-3
    assert f40 == pytest.approx(270, rel=0.05)  # docs/model.md: 279.8 Hz for this geometry


def test_shank_first_mode_against_beam_theory_and_thesis(flex_model):
    ritz = flex_model.packed.shank_first_mode_rad_s / (2 * math.pi)
    fe = hammer_fe_first_mode(40)
    # the model's two-term Ritz beam (with rotary inertia and an axially elastic shank)
    # against the converged inextensible Euler-Bernoulli solution of the same hammer
    assert ritz == pytest.approx(fe, rel=0.01)
    assert ritz == pytest.approx(303, rel=0.10)  # the thesis's 303 Hz


def test_ring_down_after_the_strike_at_the_first_mode(flex_model, forte_flex):
    ev, t = forte_flex.events, forte_flex.time
    strain = forte_flex.channels["shank_strain"]
    window = (t > ev["string_release"] + 0.0005) & (t < ev["check"])
    sig = strain[window] - strain[window].mean()
    spec = np.abs(np.fft.rfft(sig * np.hanning(sig.size), 16 * sig.size))
    freq = np.fft.rfftfreq(16 * sig.size, t[1] - t[0])
    peak = freq[np.argmax(spec)]
    ritz = flex_model.packed.shank_first_mode_rad_s / (2 * math.pi)
    assert peak == pytest.approx(ritz, rel=0.10)
    ring = np.ptp(sig)
    later = (t > ev["check"] + 0.05) & (t < ev["check"] + 0.1)
    assert ring > 500e-6  # hundreds of microstrain ring after the strike ...
    assert np.ptp(strain[later]) < 0.1 * ring  # ... and settle once the back check holds it


def test_forte_with_flexible_shank(forte_rigid, forte_flex):
    ev, t = forte_flex.events, forte_flex.time
    tip = forte_flex.channels["shank_tip_deflection"]
    around = (t > ev["strike"] - 0.002) & (t < ev["string_release"] + 0.002)
    largest = np.abs(tip[around]).max()
    assert 0.5e-3 < largest < 0.02 * 0.086  # of the order of the thesis's 1.5 mm, < 2 % of L
    assert np.abs(tip).max() < 0.02 * 0.086
    for name in ("key_angle", "whippen_angle", "jack_angle", "repetition_angle"):
        rigid, flex = forte_rigid.channels[name], forte_flex.channels[name]
        assert np.abs(flex - rigid)[t < ev["strike"]].max() < 0.03 * np.ptp(rigid), name
    # the head's speed during the string contact (strike-aligned) is what flexibility changes
    tau = np.linspace(0.0, ev["string_release"] - ev["strike"], 100)
    v_flex = np.interp(ev["strike"] + tau, t, forte_flex.channels["hammer_head_velocity"])
    v_rigid = np.interp(forte_rigid.events["strike"] + tau, forte_rigid.time,
                        forte_rigid.channels["hammer_head_velocity"])
    assert np.abs(v_flex - v_rigid).max() > 0.02 * forte_flex.strike_speed


def scuffing(result) -> float:
    """Travel (m) of the string contact point along the string during the strike."""
    on = result.contact("contact_force", 12) > 0
    x = result.contact("contact_point_x", 12)[on]
    return float(np.ptp(x))


def test_flexibility_changes_the_head_scuffing(forte_rigid, forte_flex):
    assert scuffing(forte_flex) > 1.5 * scuffing(forte_rigid)


@pytest.fixture(scope="module")
def liftoff_model():
    return ActionModel(effects=["key_liftoff"])


@pytest.fixture(scope="module")
def revolute_rest():
    return ActionModel().rest_state()


@pytest.mark.parametrize("scale", [1.0, 0.5])
def test_lift_off_key_rests_where_the_revolute_key_does(scale, forte, revolute_rest):
    """Thesis 4.2: the rail is placed so that the key rests at the revolute key's height."""
    model = ActionModel(effects=[{"key_liftoff": {"stiffness_scale": scale}}])
    rest = model.rest_state()
    assert abs(rest[k.QYK]) < 1e-6  # the pivot at y0 within 1 um
    assert rest[k.QK] == pytest.approx(revolute_rest[k.QK], abs=1e-6)
    assert np.abs(model.accelerations(rest)).max() < 1e-6
    # independent of the solver: left alone from Table 3.2's angles, it settles there
    settled = model.stepper(model._table_state()).advance(0.6, 0.0).states[-1]
    assert abs(settled[k.QYK]) < 1e-6
    # and a blow starts from a key on its rail at rest height
    assert np.abs(model.simulate(forte, duration=0.02).channels["key_lift"]).max() < 1e-6
    rail = model.describe()["balance_rail"]
    assert model.build.params.get("points.ground.Pg1.at")[1] == rail["y_m"]
    assert rail["offset_m"] == pytest.approx(rail["y_m"] - Parameters.default().get(
        "points.ground.Pg1.at")[1], abs=1e-15)


def test_rail_placement_follows_the_felt_stiffness_not_its_damping(liftoff_model):
    soft = ActionModel(effects=[{"key_liftoff": {"stiffness_scale": 0.5}}])
    damped = ActionModel(effects=[{"key_liftoff": {"damping": 10.0}}])
    assert damped.balance_rail == liftoff_model.balance_rail  # damping: no force at rest
    assert soft.balance_rail is not None and liftoff_model.balance_rail is not None
    # a softer felt sinks further under the same key: its rail sits higher
    assert soft.balance_rail["y_m"] > liftoff_model.balance_rail["y_m"]


def release_time(profile) -> float:
    """When the key force starts to fall from its peak (s)."""
    return float(profile.time[np.flatnonzero(profile.force == profile.peak)[-1]])


def lift_phases(model, profile) -> dict[str, RailLift]:
    """The key's rail lift when its front bottoms (from 2 ms before until the force is
    released) and when it falls back (from then on)."""
    res = model.simulate(profile)
    released = release_time(profile)
    return {"bottoming": rail_lift(res, res.events["key_bottom"] - 0.002, released),
            "fall-back": rail_lift(res, released)}


def test_key_lifts_off_when_it_bottoms_and_when_it_falls_back(forte, piano):
    # with the thesis's repetition-spring preload: the regulated spring loads the capstan
    # less, and the piano blow's key then rises 0.04 mm clear of the felt when it bottoms
    # (docs/model.md, "Effect: key lift-off")
    model = ActionModel(Parameters.default().set("repetition_spring.regulation", 0.0),
                        effects=["key_liftoff"])
    loud, soft = lift_phases(model, forte), lift_phases(model, piano)
    # Leaving the rail means rising clear of the rail felt's rest compression; the felt
    # then carries no force. Forte does so when its front bottoms and when it falls back
    # (its back lands on the back rail and the key pivots up off the balance rail).
    for phase in ("bottoming", "fall-back"):
        assert loud[phase].clearance > 0.0 and loud[phase].airborne > 0.0, phase
    # A piano blow (key <= 0.25 m/s) meets its front punching slowly: the punching's
    # rebound does not lift the key clear of the felt, and lifts it less than forte.
    # (How high a key falls back depends on how the force is released: docs/model.md.)
    assert soft["bottoming"].clearance < 0.0
    assert soft["bottoming"].height < loud["bottoming"].height


def test_rail_lift_needs_the_lift_channel(forte_rigid):
    with pytest.raises(ValueError, match="key_lift"):
        rail_lift(forte_rigid)


USER_EFFECT = '''
import numpy as np
from rig.model.effects import Effect, EffectParameter, Signature

class SofterStringFelt(Effect):
    """Scales the hammer-string felt's stiffness (a compiled-path effect)."""
    name = "softer_string_felt"
    summary = "hammer felt softer than the thesis's fit"
    parameters = (EffectParameter("scale", "1", 0.3, (0.01, 10.0), True, "stiffness scale"),)
    signature = Signature(("hammer_angle",), ("string contact",), "shape")

    def apply(self, build):
        for coef in ("a", "b", "c"):
            build.params.set(f"contacts.12.{coef}",
                             build.params.get(f"contacts.12.{coef}") * self.values["scale"])

class HammerAirDrag(Effect):
    """A viscous torque on the hammer (a Python generalized force)."""
    name = "hammer_air_drag"
    summary = "viscous drag on the hammer"
    parameters = (EffectParameter("c", "N m s/rad", 2e-3, (0.0, 1.0), True, "drag"),)

    def generalized_force(self, t, q, qd):
        f = np.zeros(9)
        f[5] = -self.values["c"] * qd[5]
        return f
'''


def test_user_effect_from_a_file_changes_the_blow_and_is_recorded(tmp_path, forte,
                                                                   forte_rigid):
    (tmp_path / "my_effects.py").write_text(textwrap.dedent(USER_EFFECT))
    (tmp_path / "model.yaml").write_text(
        "effects:\n  - my_effects.py:SofterStringFelt: {scale: 0.3}\n")
    model = ActionModel.from_yaml(tmp_path / "model.yaml")
    res = model.simulate(forte)
    assert res.events["string_release"] - res.events["strike"] > 1.2 * (
        forte_rigid.events["string_release"] - forte_rigid.events["strike"])
    path = runfile.write_result(tmp_path / "r.h5", res)
    recorded = runfile.read(path).metadata["model"]["effects"]
    assert recorded[0]["name"] == "softer_string_felt"
    assert recorded[0]["values"] == {"scale": 0.3}
    assert recorded[0]["class"].endswith(":SofterStringFelt")


def test_user_generalized_force_runs_through_scipy(tmp_path, forte, forte_rigid):
    (tmp_path / "drag.py").write_text(textwrap.dedent(USER_EFFECT))
    model = ActionModel(effects=[f"{tmp_path / 'drag.py'}:HammerAirDrag"])
    assert model.integrator.name == "scipy-LSODA"
    res = model.simulate(forte, duration=0.12)
    assert res.success
    assert res.strike_speed < 0.98 * forte_rigid.strike_speed


def test_model_yaml_cli_and_python_agree(tmp_path, forte):
    (tmp_path / "m.yaml").write_text("effects:\n  - flexible_shank: {damping_ratio: 0.02}\n"
                                     "  - key_liftoff\nparameters:\n  contacts: {4: {D: 3.0}}\n")
    model = ActionModel.from_yaml(tmp_path / "m.yaml")
    assert model.effect_names == ["flexible_shank", "key_liftoff"]
    assert model.build.params.get("hammer_shank_damping.ratio") == 0.02
    assert model.build.params.get("contacts.4.D") == 3.0
    assert set(model.coordinates) >= {"y_k", "u1", "v1", "v2"}
    out = tmp_path / "cli.h5"
    result = CliRunner().invoke(app, ["simulate", "profiles/piano.yaml", "--model",
                                      str(tmp_path / "m.yaml"), "--out", str(out),
                                      "--duration", "0.15"])
    assert result.exit_code == 0, result.output
    meta = runfile.read(out).metadata
    assert [e["name"] for e in meta["model"]["effects"]] == ["flexible_shank", "key_liftoff"]
    assert "shank_strain" in runfile.read(out).trials[0].channels
    assert "D: 3.0" in meta["parameters"]


@pytest.mark.parametrize("spec, expected", [
    ("no_such_effect", "not in the library"),
    ("missing.py:Thing", "not found"),
    ({"flexible_shank": {"E": -1.0}}, "outside its physical bounds"),
    ({"flexible_shank": {"colour": 1.0}}, "unknown parameter"),
    ("json:loads", "not a subclass of rig Effect"),
])
def test_bad_effects_are_refused(spec, expected):
    with pytest.raises(ValueError, match=expected):
        make(spec)


def test_every_library_effect_documents_itself():
    for name, cls in BUILTIN.items():
        assert cls.name == name and cls.summary and cls.signature.text
        assert issubclass(cls, Effect)
        for p in cls.parameters:
            assert p.units and p.bounds[0] <= p.default <= p.bounds[1]


@pytest.fixture(scope="module")
def short_base(forte):
    return ActionModel().simulate(forte, duration=0.15)


def shift_ms(res, base, name="strike"):
    return (res.events[name] - base.events[name]) * 1e3


def test_drive_dynamics_delays_and_load_cell_filter_advances_the_blow(forte, short_base):
    late = ActionModel(effects=[{"drive_dynamics": {"delay": 0.004}}]).simulate(forte, 0.15)
    early = ActionModel(effects=[{"load_cell_filter": {"cutoff": 100.0}}]).simulate(forte, 0.15)
    assert 4.0 < shift_ms(late, short_base) < 8.0  # dead time plus the low-pass's lag
    # a 4-pole Butterworth at 100 Hz delays by 2.6131 / (2 pi 100) s = 4.16 ms
    assert shift_ms(early, short_base) == pytest.approx(-4.16, abs=0.05)


def test_key_encoder_misreads_only_the_key_while_it_lifts(forte):
    lift_only = ActionModel(effects=["key_liftoff"]).simulate(forte, 0.15)
    misread = ActionModel(effects=["key_encoder_misread"]).simulate(forte, 0.15)
    np.testing.assert_allclose(misread.channels["hammer_angle"],
                               lift_only.channels["hammer_angle"], atol=1e-12)
    lift = lift_only.channels["key_lift"] - lift_only.channels["key_lift"][0]
    err = misread.channels["key_angle"] - lift_only.channels["key_angle"]
    np.testing.assert_allclose(err, 63.0 * lift, atol=1e-12)
    assert np.abs(err).max() > 1e-3


def test_backcheck_law_changes_only_the_check(forte, short_base):
    stiff = ActionModel(effects=[{"backcheck_law": {"stiffness_scale": 5.0, "friction": 0.1}}])
    res = stiff.simulate(forte, 0.15)
    t = res.time
    before = t < short_base.events["check"] - 1e-3
    after = t > short_base.events["check"] + 5e-3
    diff = np.abs(res.channels["hammer_angle"] - short_base.channels["hammer_angle"])
    assert diff[before].max() < 1e-9
    assert diff[after].max() > 1e-3


def test_felt_hysteresis_and_compliant_string_change_the_string_contact(forte, short_base):
    soft = ActionModel(effects=[{"compliant_string": {"stiffness": 2e4}}]).simulate(forte, 0.15)
    base_contact = short_base.events["string_release"] - short_base.events["strike"]
    assert soft.events["string_release"] - soft.events["strike"] > 1.5 * base_contact
    hyst = ActionModel(effects=["felt_hysteresis"]).simulate(forte, 0.15)
    assert hyst.success
    assert abs(shift_ms(hyst, short_base, "check")) > 1.0


def test_contact_laws_against_their_definitions():
    from rig.model import kernel as kk

    a, b, c, d = 1.81e10, 8.19e7, 1.16e4, 0.8
    law = np.zeros(kk.N_LAW)
    law[[kk.L_A, kk.L_B, kk.L_C, kk.L_D]] = a, b, c, d

    def fit(x):
        return a * x**3 + b * x**2 + c * x

    law[kk.L_TYPE], law[kk.L_P1], law[kk.L_P2] = kk.LAW_HYSTERETIC, 0.3, 1e-3
    assert kk.normal_force_law(4e-4, 0.5, law) == pytest.approx(1.3 * fit(4e-4), rel=1e-6)
    assert kk.normal_force_law(4e-4, -0.5, law) == pytest.approx(0.7 * fit(4e-4), rel=1e-6)
    law[kk.L_TYPE], law[kk.L_P1] = kk.LAW_SERIES_SPRING, 5e4
    f = kk.normal_force_law(1e-3, 0.0, law)
    felt = 1e-3 - f / 5e4  # the felt's share of the penetration
    assert f == pytest.approx(fit(felt), rel=1e-9)
    assert f < fit(1e-3)  # in series: softer than the felt alone


def test_key_pin_friction_damps_the_lift(liftoff_model, forte):
    free = lift_phases(liftoff_model, forte)
    held = lift_phases(ActionModel(effects=[{"key_liftoff": {"pin_friction": 2.0}}]), forte)
    assert held["bottoming"].height < free["bottoming"].height - 5e-5
    assert held["fall-back"].height < 0.5 * free["fall-back"].height


def test_kernel_edits_invalidate_dependent_caches(tmp_path):
    """numba keys caches per file: rig.model drops integrator caches older than the kernel."""
    import os
    from pathlib import Path

    import rig.model as rm

    cache = Path(rm.__file__).parent / "__pycache__"
    kernel = Path(rm.__file__).parent / "kernel.py"
    fake = cache / "integrators.fake-1.py311.nbi"
    cache.mkdir(exist_ok=True)
    fake.write_bytes(b"")
    old = kernel.stat().st_mtime - 100
    os.utime(fake, (old, old))
    rm._drop_stale_caches()
    assert not fake.exists()


STATE_EFFECT = '''
import numpy as np
from rig.model.effects import Effect, EffectParameter, EffectState

class HammerMaxwell(Effect):
    """A spring from the hammer to a relaxing rest angle z (a Maxwell element)."""
    name = "hammer_maxwell"
    summary = "viscoelastic restraint of the hammer"
    parameters = (EffectParameter("k", "N m/rad", 0.0, (0.0, 10.0), True, "stiffness"),
                  EffectParameter("tau", "s", 0.01, (1e-4, 1.0), True, "relaxation time"))
    states = (EffectState("rest_angle", "rad", 1e-10, 0.5),)

    def generalized_force(self, t, q, qd, z):
        f = np.zeros(9)
        f[5] = -self.values["k"] * (q[5] - z[0])
        return f

    def state_derivative(self, t, q, qd, z):
        return np.array([(q[5] - z[0]) / self.values["tau"]])
'''


def test_user_effect_adds_a_state_with_its_own_dynamics(tmp_path, forte, forte_rigid):
    (tmp_path / "maxwell.py").write_text(textwrap.dedent(STATE_EFFECT))
    ref = f"{tmp_path / 'maxwell.py'}:HammerMaxwell"
    free = ActionModel(effects=[ref])
    rest = free.rest_state()
    assert rest.shape == (k.NY + 1,) and rest[k.NY] == pytest.approx(rest[5], abs=1e-9)
    y0 = rest.copy()
    y0[k.NY] = 0.5
    step = free.stepper(y0)
    step.advance(0.05, 0.0)
    res = step.result()
    z = res.channels["hammer_maxwell_rest_angle"]
    exact = rest[5] + (0.5 - rest[5]) * np.exp(-res.time / 0.01)
    np.testing.assert_allclose(z, exact, atol=1e-6)
    assert res.units["hammer_maxwell_rest_angle"] == "rad"
    held = ActionModel(effects=[{ref: {"k": 0.5, "tau": 0.1}}]).simulate(forte, duration=0.07)
    assert held.success and held.strike_speed < 0.97 * forte_rigid.strike_speed


def test_an_integrators_edit_invalidates_the_stiff_integrators_cache(tmp_path):
    """integrators_stiff's compiled code inlines integrators' compiled helpers (force_at,
    the Hermite interpolant): an edit of integrators.py (kernel.py older) drops its caches
    too; caches newer than every callee stay."""
    import os

    import rig.model as rm

    cache = tmp_path / "__pycache__"
    cache.mkdir()
    t0 = 1_700_000_000.0
    for name, t in (("kernel.py", t0), ("integrators.py", t0 + 1000)):
        (tmp_path / name).write_text("")
        os.utime(tmp_path / name, (t, t))
    files = {"stiff_stale": ("integrators_stiff.f-1.py311.nbi", t0 + 500),
             "stiff_fresh": ("integrators_stiff.f-2.py311.nbi", t0 + 2000),
             "explicit_ok": ("integrators.f-3.py311.nbi", t0 + 500)}  # calls only the kernel
    for fname, t in files.values():
        (cache / fname).write_bytes(b"")
        os.utime(cache / fname, (t, t))
    rm._drop_stale_caches(tmp_path)
    left = {p.name for p in cache.iterdir()}
    assert left == {files["stiff_fresh"][0], files["explicit_ok"][0]}


def test_an_integrator_block_without_a_name_keeps_the_default_integrator(tmp_path):
    from rig.model.action import ActionModel

    m = tmp_path / "m.yaml"
    m.write_text("integrator: {rtol: 1.0e-5}\n")
    model = ActionModel.from_yaml(m)
    assert model.integrator.name == ActionModel().integrator.name == "rosenbrock"
    assert model.integrator.rtol == 1.0e-5
    m.write_text("integrator: {name: dopri54, rtol: 1.0e-5}\n")
    assert ActionModel.from_yaml(m).integrator.name == "dopri54"


@pytest.mark.parametrize("delay_samples", [0.0, 0.25, 0.5, 0.8, 1.0, 3.37, 6.0, -0.4, -2.6])
def test_a_delay_shifts_a_tone_without_changing_its_amplitude(delay_samples: float) -> None:
    """drive_dynamics' dead time (and load_cell_filter's advance): a 2 kHz record of 50 and
    250 Hz tones comes out shifted by the delay to within 2 and 40 us, its amplitude kept
    to 0.05 % (linear interpolation between samples lost 8 % at 250 Hz half-way between
    samples, an amount that varied with the delay's fraction of a sample)."""
    from rig.model.effects import _shift

    dt = 1 / 2000
    t = np.arange(0, 0.4, dt)
    steady = (t > 0.05) & (t < 0.35)  # away from the held ends and the start transient
    for f, within_s in ((50.0, 2e-6), (250.0, 4e-5)):
        x = np.sin(2 * np.pi * f * t)
        y = _shift(t, x, delay_samples * dt)
        want = np.sin(2 * np.pi * f * (t - delay_samples * dt))
        slope = 2 * np.pi * f  # the tone's largest slope: amplitude error per second of time
        assert np.max(np.abs(y[steady] - want[steady])) < slope * within_s, (f, delay_samples)
        ratio = np.sqrt(np.mean(y[steady] ** 2) / np.mean(want[steady] ** 2))
        assert ratio == pytest.approx(1.0, abs=5e-4)
