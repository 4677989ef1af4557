"""Accuracy of the full model's default tolerances, and what limits its steps.

    .venv/bin/python benchmarks/accuracy.py           # forte blow, a few seconds
    .venv/bin/python benchmarks/accuracy.py --sweep   # nine blows, about a minute

Runs the forte blow with the full model (flexible shank + key lift-off) at the
default tolerances, with the shank's axial-rate tolerance set from its axial
mode instead (a looser choice), with the axial coordinate one-way coupled
(``hammer_shank_axial.coupling: one_way``, an approximation of the equations), and
against a reference (the full equations) at rtol 1e-10 with
every absolute tolerance / 1000. Prints each run's RHS calls and its largest and
RMS error per channel against the reference (and the largest strain error per
phase of the blow), then, for the default run, which state component's error
set the step sizes in each phase and how the attempted steps split between
explicit and implicit ones.

``--sweep``: forte, piano and two-peak, each at 0.8, 1.0 and 1.2 times its force, at
the default tolerances and with the axial pair set from the axial mode (u1 5e-10, its
rate that times the mode's 3.3e4 rad/s: 15 % fewer RHS calls on forte): RHS calls and
the largest strain error against each blow's reference, over the whole blow and up to
50 ms after the check (the blow proper; later the fall-back's contacts shift the
ringing strain, up to 2.7e-4, by about a microsecond, which sets the whole-blow
maximum).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from rig.inputs.profiles import Profile
    from rig.model.action import SimResult

ROOT = Path(__file__).resolve().parents[1]
EFFECTS = ["flexible_shank", "key_liftoff"]
CHANNELS = ["shank_strain", "shank_tip_deflection", "hammer_angle", "whippen_angle",
            "key_angle", "key_lift"]
PHASES = [(0.0, 0.1, "descent and strike"), (0.1, 0.3, "held"), (0.3, 0.45, "release"),
          (0.45, 0.6, "fall-back")]
AXIAL_MODE = 3.3e4  # rad/s, the shank's 5.2 kHz axial mode
SWEEP = [(name, scale) for name in ("forte", "piano", "two-peak") for scale in (0.8, 1.0, 1.2)]


def sweep() -> None:
    """The default and the axial-mode tolerances on nine blows (``--sweep``)."""
    from rig.inputs import profiles
    from rig.model import kernel as k

    # u1's atol x 0.5 and its rate's = that x the axial mode (2000 1/s -> 3.3e4 1/s)
    variants = {"default": {}, "axial pair from the mode":
                {k.QU1: 0.5, k.NQ + k.QU1: 0.5 * AXIAL_MODE / 2000.0}}
    print("blow            | " + " | ".join(f"{v}: RHS calls, strain error max (blow proper)"
                                            for v in variants))
    worst: dict[str, list[float]] = {v: [] for v in variants}
    calls = dict.fromkeys(variants, 0.0)
    for name, scale in SWEEP:
        base = profiles.load(ROOT / "profiles" / f"{name}.yaml")
        profile = profiles.from_points(np.c_[base.time, base.force * scale].tolist(),
                                       name=f"{name} x{scale}")
        ref, _, _ = run(profile, 1e-10, {i: 1e-3 for i in range(2 * k.NQ)})
        proper = ref.time < ref.events["check"] + 0.05
        line = f"{profile.name:15s}"
        for v, scales in variants.items():
            res, _, _ = run(profile, 1e-6, scales)
            e = np.abs(res.channels["shank_strain"] - ref.channels["shank_strain"])
            worst[v].append(float(e.max()))
            calls[v] += res.stats["rhs"]
            line += f" | {res.stats['rhs']:6.0f}  {e.max():.1e} ({e[proper].max():.1e})"
        print(line, flush=True)
    for v in variants:
        w = np.array(worst[v])
        print(f"{v}: {calls[v]:.0f} RHS calls in all; strain error max {w.max():.1e}, "
              f"median {np.median(w):.1e}, above 2e-6 (the gauge's noise) in "
              f"{(w > 2e-6).sum()} of {len(w)}")


def run(profile: Profile, rtol: float, atol_scale: dict[int, float] | None = None,
        trace: bool = False, coupling: str = "two_way") -> tuple[SimResult, np.ndarray, int]:
    """The blow at rtol with absolute tolerances scaled; the step trace if asked;
    ``coupling``: the shank's axial coordinate (hammer_shank_axial.coupling)."""
    from rig.inputs.params import Parameters
    from rig.model.action import ActionModel
    from rig.model.integrators_stiff import Rosenbrock

    params = Parameters.default().set("hammer_shank_axial.coupling", coupling)
    model = ActionModel(params, effects=EFFECTS)
    num = model.params.tree["numerics"]
    integ = Rosenbrock(rtol=rtol, max_step=num["max_step"])
    model.integrator = integ
    for i, f in (atol_scale or {}).items():
        model.atol[i] *= f
    rows: list[np.ndarray] = []
    if trace:
        advance = integ.advance

        def traced(*a: Any, **kw: Any) -> Any:
            integ._trace = np.zeros((200000, 5))
            out = advance(*a, **kw)
            rows.append(integ._trace[integ._trace[:, 1] > 0].copy())
            return out

        integ.advance = traced  # type: ignore[method-assign]
    res = model.simulate(profile)
    return res, (np.vstack(rows) if rows else np.zeros((0, 5))), integ.n_jac


def main() -> None:
    from rig.inputs import profiles
    from rig.model import kernel as k

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--profile", default=str(ROOT / "profiles" / "forte.yaml"))
    ap.add_argument("--sweep", action="store_true",
                    help="nine blows (three profiles x three force scales), default "
                         "tolerances against the axial pair set from the axial mode")
    args = ap.parse_args()
    if args.sweep:
        sweep()
        return
    profile = profiles.load(args.profile)
    ref, _, _ = run(profile, 1e-10, {i: 1e-3 for i in range(2 * k.NQ)})
    print(f"reference (rtol 1e-10, atol / 1000): {ref.stats['steps']:.0f} steps, "
          f"strike {ref.events['strike'] * 1e3:.4f} ms at {ref.strike_speed:.5f} m/s")
    variants = {"default tolerances": ({}, "two_way"),
                "du1 rate x axial mode": ({k.NQ + k.QU1: AXIAL_MODE / 2000.0}, "two_way"),
                "one-way axial coupling": ({}, "one_way")}
    traced = None
    for name, (scale, coupling) in variants.items():
        default = not scale and coupling == "two_way"
        res, rows, n_jac = run(profile, 1e-6, scale, trace=default, coupling=coupling)
        if default:
            traced = (rows, n_jac)
        print(f"\n{name}: {res.stats['steps']:.0f} steps, {res.stats['rhs']:.0f} RHS calls; "
              f"strike {abs(res.events['strike'] - ref.events['strike']) * 1e6:.2f} us off, "
              f"speed {abs(res.strike_speed / ref.strike_speed - 1) * 100:.4f} % off")
        for c in CHANNELS:
            e = np.abs(res.channels[c] - ref.channels[c])
            print(f"  {c:22s} max {e.max():.2e}  rms {np.sqrt(np.mean(e ** 2)):.2e}")
        e = np.abs(res.channels["shank_strain"] - ref.channels["shank_strain"])
        print("  largest strain error by phase: " + ", ".join(
            f"{label} {e[(ref.time >= a) & (ref.time < b)].max():.1e}" for a, b, label in PHASES))
    assert traced is not None
    rows, n_jac = traced
    names = ["key", "key_lift", "whippen", "jack", "repetition", "hammer", "u1", "v1", "v2",
             "z_b"]
    assert len(names) == k.NQ
    names += ["d" + n for n in names]
    explicit = rows[:, 4] < 0
    print(f"\ndefault run: {len(rows)} attempted steps, {explicit.sum()} explicit "
          f"(Dormand-Prince, 6 RHS each), {(~explicit).sum()} implicit (ROS34PW2, 3-4 RHS "
          f"each), {n_jac} Jacobians")
    for a, b, label in PHASES:
        sel = rows[(rows[:, 0] >= a) & (rows[:, 0] < b)]
        ids, counts = np.unique(sel[:, 3].astype(int), return_counts=True)
        order = np.argsort(-counts)[:3]
        top = ", ".join(f"{names[ids[i]]} {counts[i] / len(sel) * 100:.0f} %" for i in order)
        print(f"  {label:20s} {len(sel):5d} attempts ({(sel[:, 4] < 0).sum():4d} explicit); "
              f"error set by: {top}")


if __name__ == "__main__":
    main()
