"""How long the Kawai KG-3C's hammer stays at the string, against the model's (docs/real-data.md).

    python examples/kawai-kg3c/dwell.py kawai.h5 [TRIAL ...] [--string N_PER_M]

For each trial of an imported run (examples/kawai-kg3c/map.yaml; the single fast strokes
3-6 and 15 by default), driven by the key's measured motion as `rig compare --input
motion` drives it:

- real: the first run of samples after the stroke's onset at which the hammer sensor reads
  its top (it saturates a few mm below the string, so the real hammer-string contact lies
  within this interval and lasts at most as long);
- base: the default model's first hammer-string contact (contact 12), from its start to
  its end;
- string: the same with the library's compliant string at ``--string`` N/m (what `rig
  diagnose` fits on this recording).

A contact longer than the real saturated interval cannot be the real hammer's.
"""

from __future__ import annotations

import argparse

import numpy as np

from rig.analysis import measurement as ms
from rig.model.action import ActionModel

WINDOW_S = 0.1  # the strike lies within the first 0.1 s of a fast stroke
TOP_TOL_M = 5e-6  # a saturated reading wanders this far below the top (0.3-2.4 um seen)


def saturated(meas: ms.Measurement) -> tuple[float, float]:
    """First and last time of the first run of samples after the onset at which the hammer
    sensor reads its top (its saturated reading, within ``TOP_TOL_M``)."""
    h = meas.channels["hammer_shank_rise"]
    top = float(np.max(h)) - TOP_TOL_M
    at = np.nonzero((h >= top) & (meas.time > 0.0))[0]
    end = at[0]
    while end + 1 < h.size and h[end + 1] >= top:
        end += 1
    return float(meas.time[at[0]]), float(meas.time[end])


def contact(model: ActionModel, meas: ms.Measurement) -> tuple[float, float]:
    """Start and end of the model's first hammer-string contact, driven by the key's
    measured motion."""
    res = ms.simulate(model, meas, "motion", WINDOW_S)
    on = res.contact("contact_penetration", 12) > 0
    d = np.diff(on.astype(int))
    start = res.time[np.nonzero(d == 1)[0] + 1]
    end = res.time[np.nonzero(d == -1)[0] + 1]
    return float(start[0]), float(end[0])


def rows(run: str, trials: list[int], string: float) -> list[tuple[int, tuple[float, float],
                                                              tuple[float, float],
                                                              tuple[float, float]]]:
    """(trial, real saturated interval, base contact, string contact) per trial, in s."""
    base = ActionModel()
    soft = ActionModel(effects=[{"compliant_string": {"stiffness": string}}])
    out = []
    for k in trials:
        meas = ms.load(run, [k], input="motion")[0]
        out.append((k, saturated(meas), contact(base, meas), contact(soft, meas)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run")
    ap.add_argument("trials", nargs="*", type=int)
    ap.add_argument("--string", type=float, default=1700.0, help="string stiffness, N/m")
    a = ap.parse_args()

    def span(iv: tuple[float, float]) -> str:
        return f"{iv[0] * 1e3:6.1f}{iv[1] * 1e3:7.1f}{(iv[1] - iv[0]) * 1e3:6.1f}"

    print(f"{'':<6}{'real sensor at its top':>19}   {'base model contact':>19}   "
          f"{f'string {a.string:.4g} N/m':>19}")
    print(f"{'trial':<6}" + f"{'from':>6}{'to':>7}{'ms':>6}   " * 3)
    for k, real, b, s in rows(a.run, a.trials or [3, 4, 5, 6, 15], a.string):
        print(f"{k:<6}{span(real)}   {span(b)}   {span(s)}")


if __name__ == "__main__":
    main()
