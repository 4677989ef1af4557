"""The simulated drive against the thesis's measurements (Section 2.8, Appendix D).

Exact or independent answers: the ramp lag against the model's a1 coefficient, the step
response against scipy's continuous-time step of Eq. D.1; the thesis's figures (~8 ms
lag with the load-cell filter, ~25 ms to settle after a 10 N step, 6.5 % maximum error
on forte after an 8 ms shift) within the tolerances of docs/model.md.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from rig.inputs import config, profiles
from rig.inputs.params import Parameters
from rig.sim_backend.drive_model import VARIANTS, DriveResponse, ramp_lag_s
from rig.sim_backend.simrig import SimRig

DT = 0.0005           # the acquisition step (2 kHz)
SPC = 4               # samples per 2 ms control period
UNIT = 0.002          # Tw, Tp3 in 2 ms periods
FORTE = Path(__file__).parents[1] / "profiles" / "forte.yaml"
SINGLE = Parameters.default().get("actuator.process_model_all")


def drive(variant: str, demand: np.ndarray) -> np.ndarray:
    """The force at each 0.5 ms sample for a demand held over each 2 ms period."""
    m = DriveResponse(DT, variant)
    return np.concatenate([m.step(float(u), SPC) for u in demand])


def test_step_response_is_eq_d1_exactly() -> None:
    """Zero-order hold is exact for a step: the samples equal the continuous response."""
    K, Tw, z, Tp3 = (SINGLE[k] for k in ("K", "Tw", "zeta", "Tp3"))
    den = np.polymul([(Tw * UNIT) ** 2, 2 * z * Tw * UNIT, 1.0], [Tp3 * UNIT, 1.0])
    y = drive("single", np.full(50, 10.0))
    _, ref = signal.step(signal.lti([10.0 * K], den), T=DT * np.arange(y.size + 1))
    assert y == pytest.approx(ref[1:], abs=1e-6)


def test_ramp_lag_is_a1_plus_the_hold() -> None:
    """Behind a ramp held at 500 Hz the force (/K) lags by a1 = 2 zeta Tw + Tp3 plus half a
    control period (the hold's mean delay): 6.86 + 1.0 ms."""
    K = SINGLE["K"]
    tc = np.arange(0, 0.4, 0.002)
    y = drive("single", 100.0 * tc) / K          # 100 N/s
    t = DT * np.arange(1, y.size + 1)
    late = t > 0.2
    lag = np.mean(t[late] - y[late] / 100.0)
    exact = ramp_lag_s(K, SINGLE["Tw"] * UNIT, SINGLE["zeta"], SINGLE["Tp3"] * UNIT) + 0.001
    assert lag == pytest.approx(exact, abs=2e-6)
    assert exact == pytest.approx(0.00786, abs=1e-4)
    assert 0.006 <= lag <= 0.010   # the thesis's ~8 ms, filter included


def settling_s(y: np.ndarray, t: np.ndarray, band: float = 0.02) -> float:
    final = y[-1]
    outside = np.nonzero(np.abs(y - final) > band * abs(final))[0]
    return float(t[outside[-1] + 1])


def test_10_n_step_settles_in_about_25_ms() -> None:
    y = drive("single", np.r_[np.zeros(10), np.full(100, 10.0)])
    t = DT * np.arange(1, y.size + 1) - 0.020
    assert y[-1] == pytest.approx(10.0 * SINGLE["K"], rel=1e-6)
    settle = settling_s(y, t)
    assert 0.025 * 0.7 <= settle <= 0.025 * 1.3, settle  # measured 28 ms to the 2 % band
    # the decreasing model of the asymmetric variant takes ~8x as long to come down
    down = drive("asymmetric", np.r_[np.full(300, 10.0), np.zeros(300)])[300 * SPC:]
    t_down = DT * np.arange(1, down.size + 1)
    outside = np.nonzero(np.abs(down) > 0.2)[0]
    assert t_down[outside[-1] + 1] > 0.15


def forte_demand() -> tuple[np.ndarray, np.ndarray]:
    prof = profiles.load(FORTE)
    tc = np.arange(0, prof.duration, 0.002)
    return tc, prof.at(tc)


def test_forte_error_after_the_8_ms_shift_is_within_1_5x_the_thesis() -> None:
    """Demand = the forte profile over the drive's static gain (the calibrated map); the
    recorded force shifted 8 ms back against the profile: max error <= 1.5 x 6.5 %."""
    tc, desired = forte_demand()
    K = SINGLE["K"]
    y = drive("single", desired / K)
    t = DT * np.arange(1, y.size + 1)
    want = np.interp(t - 0.008, tc, desired)
    err = np.max(np.abs(y - want)) / desired.max()
    assert err <= 1.5 * 0.065, err
    assert err > 0.005   # a real error, not the identity
    # without the 8 ms shift it is several times larger (the lag dominates)
    assert np.max(np.abs(y - np.interp(t, tc, desired))) / desired.max() > 2 * err


def test_variants_are_selectable_and_differ_where_documented() -> None:
    tc, desired = forte_demand()
    single, asym, slew = (drive(v, desired) for v in VARIANTS)
    assert not np.allclose(single, asym, atol=0.1)           # rise/fall models
    assert slew == pytest.approx(single, abs=0.02)           # 375 N/s ramps are not limited
    # steps up to 10 N: step_size is the single model; a 30 N step rises slew-limited
    small = np.r_[np.zeros(5), np.full(40, 8.0)]
    assert drive("step_size", small) == pytest.approx(drive("single", small), abs=0.02)
    big = np.r_[np.zeros(5), np.full(40, 30.0)]
    s30, l30 = drive("single", big), drive("step_size", big)
    t = DT * np.arange(1, s30.size + 1) - 0.010
    half = 15.0 * SINGLE["K"]
    assert t[np.argmax(l30 >= half)] > t[np.argmax(s30 >= half)] + 0.002
    assert l30[-1] == pytest.approx(s30[-1], rel=1e-3)       # same static gain
    with pytest.raises(ValueError, match="variant"):
        DriveResponse(DT, "rise_fall")


@pytest.mark.parametrize("variant", VARIANTS)
def test_the_rig_config_selects_the_variant(variant: str) -> None:
    cfg = config.builtin_sim(sim={"drive_model": variant, "realtime": False})
    rig = SimRig(cfg)
    assert rig.drive.variant == variant
    assert config.builtin_sim().sim.drive_model == "single"
    with pytest.raises(ValueError, match="sim.drive_model"):
        config.builtin_sim(sim={"drive_model": "rise_fall"})


def test_the_fidelity_rows_of_the_drive_and_fingertip_hold() -> None:
    """benchmarks/fidelity_drive.py's rows (imported by benchmarks/fidelity.py)."""
    import importlib.util

    path = Path(__file__).parents[1] / "benchmarks" / "fidelity_drive.py"
    spec = importlib.util.spec_from_file_location("fidelity_drive", path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    rows = mod.rows()
    assert len(rows) == 6
    for r in rows:
        assert set(r) == {"quantity", "thesis", "section", "model", "deviation", "tolerance",
                          "ok"}
        assert r["ok"] is True, r
    # the asymmetric variant is the slow drive the issue measured: its rows fail
    assert not all(r["ok"] for r in mod.rows("asymmetric")[:3])
    assert "| drive lag" in mod.table(rows)


def test_synth_records_the_key_force_unless_asked_to_filter_again() -> None:
    """rig synth's record is the drive model's force (the filter is inside it); with
    load_cell_filter the 100 Hz 4-pole filter acts once more and the record lags the key
    force by its group delay, 2.6131 / (2 pi 100 Hz) = 4.16 ms."""
    from rig.analysis import synth
    from rig.model.action import ActionModel

    prof = profiles.load(FORTE)
    cfg = synth.default_rig()
    quiet = {"rng_seed": 1, "duration": 0.08, "noise_scale": 0.0}
    plain = synth.synth_trial(ActionModel(), prof, cfg, load_cell_filter=False, **quiet)
    again = synth.synth_trial(ActionModel(), prof, cfg, load_cell_filter=True, **quiet)
    key = plain.truth.channels["force"]
    t = plain.channels["time"]
    assert plain.channels["force"] == pytest.approx(key, abs=1e-6)
    ramp = (t > 0.04) & (t < 0.07)   # the forte ramp at the key (375 N/s x the drive's K)
    slope = np.polyfit(t[ramp], key[ramp], 1)[0]
    assert slope == pytest.approx(375.0 * SINGLE["K"], rel=5e-3)
    lag = np.mean(key[ramp] - again.channels["force"][ramp]) / slope
    assert lag == pytest.approx(2.6131 / (2 * np.pi * 100.0), abs=2e-4)
