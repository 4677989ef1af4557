"""How well the events found in measured channels (rig.analysis.events) agree with the
model's own, on the simulated rig's measurement-like channels.

    .venv/bin/python benchmarks/events.py      # about three minutes

Blows of 10, 15, 20, 24 (mezzo), 30 (forte), 35 and 40 N (ramps of 50-150 ms) and the
piano profile, each through `rig synth`'s chain (the drive, the load cell's noise, the
encoders' counts) for five truth models (the rigid base, a compliant string, key lift-off,
a flexible shank, the back-check law) and two seeds. Prints, per event and per shank
(rigid or flexible), how many trials it was found in, and the error's mean, standard
deviation and largest magnitude (ms), then where an event was missed or spurious.

    .venv/bin/python benchmarks/events.py --release   # the key's release, one minute

The key release instead: profiles/two-peak.yaml (the force let down from 24 N in 80 ms)
for 0.62 s, the five truth models and two seeds: found against the model's own, with
whether its interval holds it.
"""

from __future__ import annotations

import argparse
import collections
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BLOWS = [(10, 0.15), (15, 0.10), (20, 0.05), (35, 0.12), (40, 0.06)]
MODELS = {"base": [], "compliant_string": ["compliant_string"], "key_liftoff": ["key_liftoff"],
          "flexible_shank": ["flexible_shank"], "backcheck_law": ["backcheck_law"]}
NAMES = ("key_starts", "strike", "check", "key_bottom")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--release", action="store_true",
                    help="the key's release on the two-peak blow instead")
    args = ap.parse_args()
    if args.release:
        release(args.seeds)
        return
    from rig.analysis import events
    from rig.analysis import synth as sy
    from rig.inputs import profiles
    from rig.model.action import ActionModel

    tmp = Path(tempfile.mkdtemp())
    paths = [ROOT / "profiles/forte.yaml", ROOT / "profiles/piano.yaml",
             ROOT / "examples/hidden-string/mezzo.yaml"]
    for peak, ramp in BLOWS:
        p = tmp / f"f{peak}.yaml"
        p.write_text(f"name: f{peak}\nsegments:\n  - {{hold: 0.02}}\n"
                     f"  - {{ramp: {ramp}, to: {peak}}}\n  - {{hold: 0.3}}\n")
        paths.append(p)
    cfg = sy.default_rig()
    errs: dict[tuple[str, str], list[float]] = collections.defaultdict(list)
    odd: collections.Counter[str] = collections.Counter()
    trials = 0
    for mname, eff in MODELS.items():
        model = ActionModel(effects=eff)
        shank = "flexible" if "flexible_shank" in eff else "rigid"
        for path in paths:
            prof = profiles.load(path)
            for seed in range(args.seeds):
                st = sy.synth_trial(model, prof, cfg, seed, 0.35, seed % 2 == 1, 1.0)
                found = events.find(st.channels["time"], st.channels)
                trials += 1
                for name in NAMES:
                    truth = st.truth.events[name]
                    if name in found and np.isfinite(truth):
                        errs[(name, shank)].append((found[name] - truth) * 1e3)
                    elif name in found:
                        odd[f"{name} spurious ({mname}, {prof.name})"] += 1
                    elif np.isfinite(truth):
                        odd[f"{name} not found ({mname}, {prof.name})"] += 1
    print(f"{trials} trials: {len(MODELS)} models x {len(paths)} blows x {args.seeds} seeds")
    print(f"{'event':12s} {'shank':9s} {'found':>6s} {'mean ms':>8s} {'sd ms':>7s} "
          f"{'max |err| ms':>13s}")
    for (name, shank), e in sorted(errs.items()):
        a = np.array(e)
        print(f"{name:12s} {shank:9s} {a.size:6d} {a.mean():+8.3f} {a.std():7.3f} "
              f"{np.abs(a).max():13.3f}")
    for what, n in sorted(odd.items()):
        print(f"  {what}: {n}")


def release(seeds: int) -> None:
    """The key release found on the two-peak blow against the truth model's own."""
    from rig.analysis import events
    from rig.analysis import synth as sy
    from rig.inputs import profiles
    from rig.model.action import ActionModel

    prof = profiles.load(ROOT / "profiles/two-peak.yaml")
    print(f"{'model':18s} {'seed':>4s} {'found ms':>9s} {'truth ms':>9s} {'err ms':>7s} "
          f"{'interval ms':>17s} holds")
    for mname, eff in MODELS.items():
        for seed in range(seeds):
            st = sy.synth_trial(ActionModel(effects=eff), prof, sy.default_rig(), seed, 0.62,
                                seed % 2 == 1, 1.0)
            e = events.found(st.channels["time"], st.channels).get("key_release")
            truth = st.truth.events["key_release"]
            if e is None:
                print(f"{mname:18s} {seed:4d} {'-':>9s} {truth * 1e3:9.2f}")
                continue
            print(f"{mname:18s} {seed:4d} {e.time * 1e3:9.2f} {truth * 1e3:9.2f} "
                  f"{(e.time - truth) * 1e3:+7.2f} {e.low * 1e3:8.2f}-{e.high * 1e3:8.2f} "
                  f"{'yes' if e.low <= truth <= e.high else 'no'}")


if __name__ == "__main__":
    main()
