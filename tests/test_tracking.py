"""Issue 18: learning the feedforward across trials (ILC) and load-cell feedback.

Offline against the simulated drive chain (rig.control.offline: the drive model and
the load cell's noise; the drive is a force source, so the action does not change the
key force) for speed."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from rig.control import feedback, ilc, offline, plant
from rig.errors import InputError
from rig.inputs import config, profiles
from rig.loop import backends

CFG = config.from_mapping({"name": "t", "backend": "sim", "drive": {"port": "sim"}})
HZ = 500.0
NOISE = CFG.sim.load_cell_noise_n


def grid(name: str) -> tuple[profiles.Profile, np.ndarray, np.ndarray]:
    p = profiles.load(f"profiles/{name}.yaml", force_limit=CFG.limits.max_force_n)
    t = np.arange(int(np.ceil(p.duration * HZ - 1e-9)) + 1) / HZ
    return p, np.array([p.at(x) for x in t]), np.array([p.at(x + 0.008) for x in t])


def learn(name: str, variant: str, trials: int = 5, factor: float = 1.0, noise: float = NOISE,
          jitter: float = 0.0, drift: float = 0.0, seed: int = 1, pi: bool = False,
          models=None, minimax: bool = True):
    p, r, u0 = grid(name)
    lrn = ilc.Learner.start(r, u0, ilc.LearningFilter.default(HZ, 0.008, factor), CFG.limits,
                            HZ, noise_n=noise, step=factor, models=models,
                            controller=feedback.LoadCellPI() if pi else None, minimax=minimax)
    rng = np.random.default_rng(seed)
    keys, tables = [], []
    for k in range(trials):
        tables.append(lrn.u.copy())
        res = offline.play(lrn.u, variant=variant, noise_n=noise, jitter_s=jitter,
                           gain=1.0 - drift * k / max(trials - 1, 1), rng=rng,
                           controller=feedback.LoadCellPI() if pi else None, reference=r)
        if not pi:
            assert res.limited == 0  # no learned demand is cut by the loop's limiter
        keys.append(ilc.errors(r, res.key_force, p.peak))
        lrn.update(res.measured, res.demand, res.lateness)
        if lrn.stopped:
            break
    return p, lrn, keys, tables


def best_key(lrn, keys):
    _, best = lrn.result()
    return best, keys[int(best["trial"]) - 1]


@pytest.mark.parametrize("name", ["forte", "two-peak"])
@pytest.mark.parametrize("variant", ["single", "step_size"])
@pytest.mark.slow
def test_learns_the_key_force_to_within_2_percent_in_five_trials(variant, name):
    p, lrn, keys, _ = learn(name, variant)
    best, k = best_key(lrn, keys)
    assert lrn.history[0]["max_pct"] > 6.0  # the open-loop 8 ms advance: the thesis's ~6.5 %
    # issue 18: the true key force within 2 % (max) and 1 % (RMS) of the peak
    assert k["max_pct"] <= 2.0 and k["rms_pct"] <= 1.0
    # the load cell (noise included: 0.22 N is 0.9 % of two-peak's 24 N; its maximum over
    # 300 cycles alone is ~3 sigma = 2.8 %): within 3 % + 1 sigma and RMS 1.2 %
    assert best["max_pct"] <= 3.0 + 100 * NOISE / p.peak and best["rms_pct"] <= 1.2


@pytest.mark.parametrize("name", ["forte", "two-peak"])
@pytest.mark.slow
def test_learns_the_asymmetric_drive_through_its_rise_fall_model(name):
    # the drive switches between the thesis's rise and fall models with the demand's
    # direction (issue 18's case a): a linear update did not learn it (forte 32.8 % ->
    # 15.5 %, two-peak not improved); the Newton-type update through the rise/fall model
    p, lrn, keys, _ = learn(name, "asymmetric")
    best, k = best_key(lrn, keys)
    assert keys[0]["max_pct"] > 12.0
    assert "rise/fall" in lrn.notes[0]               # the model that explains the trial
    # issue 18's 2 % key maximum: no demand whose drive mode switches at most twice reaches
    # it on forte (the two-switch bound is 2.14 %,
    # test_no_release_with_one_mode_switch_reaches_2_percent_on_forte); the minimax plan's
    # release that brakes twice (four switches, each a reversal of >= PLAN_SWITCH_N) does:
    # forte 0.96-1.10 % on seeds 1-5 of this test, RMS 0.39-0.50 % (one brake: 2.25-2.41 %,
    # Newton steps alone 3.05-5.19 %); two-peak 0.90-1.11 % on seeds 1-3
    assert k["max_pct"] <= 2.0 and k["rms_pct"] <= 0.6
    assert best["rms_pct"] <= 1.2


def test_the_linear_p_type_update_does_not_learn_the_asymmetric_drive():
    # what the model-based update is for: the P-type update (models=()) stays far off
    _, lrn, keys, _ = learn("forte", "asymmetric", models=())
    assert "P-type" in lrn.notes[0]
    assert best_key(lrn, keys)[1]["max_pct"] > 10.0


@pytest.mark.parametrize("variant", ["single", "asymmetric"])
@pytest.mark.slow
def test_piano_learning_does_not_make_the_key_force_worse(variant):
    # peak 1.2 N, 5x the load cell's noise: the error is mostly noise; the noise-aware update
    # learns only what stands out of it (averaging trials played with the same table)
    p, lrn, keys, _ = learn("piano", variant)
    best, k = best_key(lrn, keys)
    floor = 100 * NOISE / p.peak                      # 1 x noise = 18.3 % of the peak
    assert k["max_pct"] <= keys[0]["max_pct"] + 0.1 * floor
    assert k["rms_pct"] <= keys[0]["rms_pct"] + 0.05 * floor
    assert k["max_pct"] <= floor and k["rms_pct"] <= 0.5 * floor
    assert any("within the noise" in n for n in lrn.notes)


@pytest.mark.slow
def test_every_learned_table_is_within_the_limits():
    for variant in ("single", "asymmetric"):
        _, lrn, _, tables = learn("forte", variant)
        dt = 1 / HZ
        for u in tables + [lrn.u]:
            assert u.min() >= 0 and u.max() <= CFG.limits.max_force_n
            steps = np.abs(np.diff(np.r_[0.0, u, 0.0]))
            assert steps.max() <= CFG.limits.max_rate_n_per_s * dt + 1e-9


def test_limit_table_clips_force_and_rate():
    lim = config.Limits(max_force_n=10.0, max_rate_n_per_s=1000.0)
    out = ilc.limit_table(np.array([-5.0, 50.0, 50.0, 50.0, 0.0]), lim, 0.002)
    np.testing.assert_allclose(out, [0.0, 2.0, 4.0, 4.0, 2.0])  # and 0 reachable after it


@pytest.mark.slow
def test_a_diverging_gain_is_stopped_and_the_best_trial_kept():
    p, lrn, _, tables = learn("forte", "single", trials=8, factor=6.0)
    assert lrn.stopped is not None and "kept trial" in lrn.stopped
    best_u, best = lrn.result()
    assert best["rms_n"] == min(h["rms_n"] for h in lrn.history)
    np.testing.assert_array_equal(best_u, tables[int(best["trial"]) - 1])
    np.testing.assert_array_equal(lrn.u, best_u)  # the next trial plays the best table


@pytest.mark.parametrize("case", [{"noise": 2 * NOISE}, {"jitter": 0.001}, {"drift": 0.10}])
@pytest.mark.slow
def test_forte_learning_is_robust(case):
    # twice the noise, 1 ms jitter, the drive's gain drifting down 10 % over the 5 trials:
    # still learns (a later trial is the best) to within twice the nominal criteria
    _, lrn, keys, _ = learn("forte", "single", **case)
    best, k = best_key(lrn, keys)
    assert best["trial"] > 1 and lrn.stopped is None
    assert best["max_pct"] <= 6.0 and best["rms_pct"] <= 2.0
    assert k["max_pct"] <= 4.0 and k["rms_pct"] <= 2.0


@pytest.mark.slow
def test_with_a_jittering_loop_the_plan_gives_way_to_the_newton_step():
    # 1 ms of write jitter (offline.play's lateness, as the loop records it): the plan's
    # sharp release (a 10 N dip) is what the timing moves most, so with the lateness given
    # the learner weighs it (bound.timed_error) and takes the Newton steps; every trial
    # after the first then stays within twice the criteria (seeds 1-4: key max 2.1-3.3 %
    # per trial over 7 trials; without the lateness the plan is played and single trials
    # reach 3.6-6.8 %)
    _, lrn, keys, _ = learn("forte", "single", jitter=0.001, seed=2)
    assert lrn.jitter_s == pytest.approx(np.sqrt(1 / 6) * 1e-3, rel=0.15)   # 0, .5, 1 ms
    assert not any("minimax plan" in n for n in lrn.notes)
    assert max(k["max_pct"] for k in keys[1:]) <= 4.0
    assert any("planned_max_n" in h for h in lrn.history)   # the plan was weighed
    # the same trials without the lateness: jitter_s stays 0 and the plan is played
    p, r, u0 = grid("forte")
    blind = ilc.Learner.start(r, u0, ilc.LearningFilter.default(HZ, 0.008), CFG.limits, HZ,
                              noise_n=NOISE)
    res = offline.play(blind.u, jitter_s=0.001, rng=np.random.default_rng(2))
    blind.update(res.measured, res.demand)
    assert blind.jitter_s == 0.0 and "minimax plan" in blind.notes[-1]


@pytest.mark.slow
def test_timing_spread_matches_the_simulated_drive_with_late_writes():
    # bound.timing_spread (the lifted model's columns scaled by the lateness) against the
    # 2 kHz simulated drive (rig.sim_backend) whose writes come 0, 0.5 or 1 ms late, the
    # force read at the nominal ticks: the spread of 400 draws at each cycle
    from rig.control import bound, plant
    from rig.sim_backend.drive_model import DriveResponse

    d = 1.5 * _bell(80, 40)        # steps up to 3.1 N per cycle
    n, spc = d.size, 4
    rng = np.random.default_rng(7)
    runs = []
    for _ in range(400):
        drive = DriveResponse(1.0 / 2000.0, "single")
        late = rng.integers(0, 3, size=n)
        f = np.zeros(n * spc + 1)
        last = 0.0
        s = 0
        for j in range(n):
            while s < j * spc + late[j]:
                f[s + 1] = drive.step(last, 1)[0]
                s += 1
            last = d[j]
        while s < n * spc:
            f[s + 1] = drive.step(last, 1)[0]
            s += 1
        runs.append(f[np.arange(n) * spc])
    seen = np.std(runs, axis=0)
    predicted = bound.timing_spread(plant.thesis_models()[0], d, HZ, np.sqrt(1 / 6) * 1e-3)
    assert predicted.max() == pytest.approx(seen.max(), rel=0.1)    # 0.200 against 0.206 N
    assert np.corrcoef(predicted, seen)[0, 1] > 0.98
    assert bound.timing_spread(plant.thesis_models()[0], d, HZ, 0.0).max() == 0.0


@pytest.mark.slow
def test_a_drifting_gain_is_re_estimated_and_extrapolated():
    _, lrn, _, _ = learn("forte", "single", drift=0.10)
    gains = [h["model_gain"] for h in lrn.history]
    np.testing.assert_allclose(gains, [1.0, 0.975, 0.95, 0.925, 0.9], atol=0.006)
    assert lrn.history[-1]["predicted_gain"] == pytest.approx(0.875, abs=0.006)
    _, steady, _, _ = learn("forte", "single")      # no drift: no extrapolation
    assert all(h["predicted_gain"] == h["model_gain"] for h in steady.history
               if "predicted_gain" in h)


@pytest.mark.slow
def test_load_cell_pi_with_learning_is_not_worse_than_learning_alone():
    # issue 18 case c: the PI compares the load cell with the profile (target_n), and the
    # update inverts the closed loop (LoadCellPI.lifted). The minimax plan is for the open
    # loop, so the same Newton-type learning without it is what the PI is compared with
    _, alone, k_alone, _ = learn("forte", "single", minimax=False)
    _, both, k_both, _ = learn("forte", "single", pi=True)
    _, planned, k_planned, _ = learn("forte", "single")
    ka, kb = best_key(alone, k_alone)[1], best_key(both, k_both)[1]
    # before: 4.5 % with the PI against 1.9 % without. Now within 0.75 % of learning alone
    # (measured 1.9-2.4 % against 1.8-2.0 %: the PI feeds the load cell's noise to the key)
    assert kb["max_pct"] <= 3.0 and kb["rms_pct"] <= 1.0
    assert kb["max_pct"] <= ka["max_pct"] + 0.75
    # the open loop with the plan is better still (0.87 % against 2.36 % with the PI)
    assert best_key(planned, k_planned)[1]["max_pct"] < kb["max_pct"]


def test_q_filter_is_zero_phase():
    t = np.arange(500) / HZ
    x = np.sin(2 * np.pi * 5 * t)
    y = ilc.q_filter(x, 100.0, HZ)
    assert np.abs(y[50:-50] - x[50:-50]).max() < 0.01  # a 5 Hz wave passes with no lag
    noise = np.random.default_rng(0).standard_normal(2000)
    assert ilc.q_filter(noise, 20.0, HZ).std() < 0.4


def test_learning_filter_from_a_motor_record():
    rec = {"fit": {"sensitivity": 0.8, "lag_s": 0.012}, "content_hash": "sha256:abc"}
    f = ilc.LearningFilter.from_record(rec, HZ)
    assert f.gain == pytest.approx(1 / 0.8) and f.lead == 6 and "sha256:abc" in f.source


def test_load_cell_pi_improves_forte_tracking():
    p, r, u0 = grid("forte")
    open_ = offline.play(u0, rng=np.random.default_rng(1))
    pi = offline.play(u0, controller=feedback.LoadCellPI(), rng=np.random.default_rng(1))
    e0 = ilc.errors(r, open_.key_force, p.peak)
    e1 = ilc.errors(r, pi.key_force, p.peak)
    assert e1["rms_pct"] < 0.5 * e0["rms_pct"]


def test_load_cell_pi_anti_windup():
    ctl = feedback.LoadCellPI(max_force_n=60.0, integral_limit_n=5.0)
    ctl.reset()
    for j in range(2000):   # the key does not follow at all (e.g. the drive saturated)
        ctl(j / HZ, 30.0, 0.0)
    assert ctl.integral == pytest.approx(5.0)
    ctl.reset()
    for j in range(2000):   # demand far above max force: the integral does not grow
        ctl(j / HZ, 80.0, 0.0)
    assert ctl.integral == 0.0


# ---- the real CLI: rig run --learn in a subprocess, then a later rig run uses the record ----

def _rig(args: list[str], cwd) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "rig", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=900, check=False)


@pytest.mark.slow
def test_rig_run_learn_saves_a_record_that_a_later_run_uses(tmp_path):
    from rig.control import records
    from rig.recordings import runfile
    from rig.services import run as run_svc

    (tmp_path / "rig.yaml").write_text(
        "name: learn\nbackend: sim\ndrive: {port: sim}\nsim: {realtime: false, seed: 4}\n"
        f"loop: {{rest_s: 0.05, settle_s: 0.05}}\ndata_folder: {tmp_path / 'data'}\n")
    forte = str(Path("profiles/forte.yaml").resolve())
    res = _rig(["run", forte, "--rig", "rig.yaml", "--learn", "2", "--lockstep", "-o",
                "f.h5"], tmp_path)
    assert res.returncode == 0, res.stderr
    assert "trial  max error %  RMS error %" in res.stdout
    # no load-cell record on this rig: its drawn offset is learned into the table, said so
    assert "note: the load cell has no calibration record" in res.stdout
    # the update used, and each trial's model
    assert "model-based (Newton-type, noise-aware, minimax plan)" in res.stdout
    assert "thesis single model" in res.stdout
    saved = list((tmp_path / "data" / "learned").glob("forte-*.json"))
    assert len(saved) == 1
    rec = records.read(saved[0])
    assert len(rec["trials"]) == 2 and rec["profile"]["content_hash"].startswith("sha256:")
    open_loop = run_svc.tracking_error(tmp_path / "f-learn1.h5")
    later = _rig(["run", forte, "--rig", "rig.yaml", "--lockstep", "-o", "later.h5"], tmp_path)
    assert later.returncode == 0, later.stderr
    assert later.stdout.splitlines()[0].startswith(f"using the learned feedforward {saved[0]}")
    err = run_svc.tracking_error(tmp_path / "later.h5")
    assert err["max_error_pct"] < 0.5 * open_loop["max_error_pct"]  # the learned error
    meta = runfile.read(tmp_path / "later.h5").metadata
    assert meta["learned_feedforward"]["content_hash"] == rec["content_hash"]
    assert meta["run"]["compensation"]["kind"] == "learned"
    off = _rig(["run", forte, "--rig", "rig.yaml", "--lockstep", "--no-learned", "-o",
                "off.h5"], tmp_path)
    assert off.returncode == 0 and "learned" not in off.stdout.splitlines()[0]


@pytest.mark.slow
def test_learning_on_a_calibrated_load_cell_reaches_its_noise_floor(tmp_path):
    # issue 41: on the simulated rig with seed 102 the load cell's true offset is +2.4 N;
    # uncalibrated, the force reads 2.4 N where the profile asks for 0 N, an error no push
    # removes (10.27 % in trial 1, 34 % in trial 2, measured). After `rig calibrate
    # loadcell` the second trial is at the noise floor: the maximum of 301 readings with
    # 0.22 N noise is about 3.3 sigma, 0.73 N, 2.4 % of the 30 N peak (measured 2.46 %).
    from rig.services import calibrate as cal_svc
    from rig.services import learn as learn_svc

    cfg = config.from_mapping({"name": "t", "backend": "sim", "drive": {"port": "sim"},
                               "sim": {"realtime": False, "seed": 102},
                               "loop": {"rest_s": 0.05, "settle_s": 0.05},
                               "data_folder": str(tmp_path)})
    cal_svc.calibrate_loadcell(cfg, [0, 1, 2, 3, 4, 5, 4, 3, 2, 1, 0])
    lines: list[str] = []
    rep = learn_svc.learn(Path("profiles/forte.yaml"), cfg, 2, out=tmp_path / "f.h5",
                          lockstep=True, on_line=lines.append)
    assert not any(learn_svc.UNCALIBRATED_LOAD_CELL in s for s in lines)
    first, second = (t["max_pct"] for t in rep.history[:2])
    assert second < 3.5 < first, (first, second)


def test_the_drive_model_reads_the_force_part_of_the_way_through_the_last_hold():
    # the loop at tick j reads the acquisition's sample before the tick (one sample period
    # old): the learner's model at read_age_s = 0.5 ms is the simulated drive (stepped at
    # 2 kHz, rig.sim_backend.drive_model) sampled at 4 j - 1, to rounding, rising and
    # falling; the same model read at the tick misses it by the force's rate x 0.5 ms
    import dataclasses

    from rig.sim_backend.drive_model import DriveResponse

    rng = np.random.default_rng(3)
    d = np.clip(np.cumsum(rng.normal(0.0, 2.0, 200)), 0.0, None)
    for base, variant in zip(plant.thesis_models(), ("single", "asymmetric"), strict=True):
        m = dataclasses.replace(base, read_age_s=0.0005)
        drive = DriveResponse(0.0005, variant)
        f = np.maximum(np.r_[0.0, np.concatenate([drive.step(float(x), 4) for x in d])], 0.0)
        sampled = np.r_[0.0, f[4 * np.arange(1, d.size) - 1]]
        assert np.abs(m.simulate(d, HZ) - sampled).max() < 1e-9
        assert np.abs(base.simulate(d, HZ) - sampled).max() > 0.05
        # the lifted matrix is the same linear map, where the force stays above 0
        up = 20.0 + np.cumsum(rng.normal(0.0, 0.5, 200))
        assert np.abs(m.lifted(m.modes(up), HZ) @ up - m.simulate(up, HZ)).max() < 1e-9
    # a whole cycle old: the force at the tick before
    whole = dataclasses.replace(plant.thesis_models()[0], read_age_s=1.0 / HZ)
    up = np.full(20, 10.0)
    assert whole.simulate(up, HZ)[1:] == pytest.approx(
        plant.thesis_models()[0].simulate(up, HZ)[:-1], abs=1e-12)
    with pytest.raises(InputError, match="read_age_s"):
        dataclasses.replace(whole, read_age_s=0.003).simulate(up, HZ)


@pytest.mark.slow
def test_the_learners_drive_model_explains_the_simulated_load_cell(tmp_path):
    # the learner's models (rig.services.learn.drive_models) read the force as the learner
    # reads it (load_cell_at_cycles, one 2 kHz sample before each tick): on the simulated
    # rig with a noise-free load cell, calibrated, the thesis's single model explains a
    # forte trial to 0.1 mN; read at the tick, it missed forte's ramps by their rate x
    # 0.5 ms (measured 0.118 N RMS, -0.19 N on the rise, +0.38 N on the release)
    import dataclasses

    from rig.services import calibrate as cal_svc
    from rig.services import learn as learn_svc
    from rig.services import run as run_svc

    cfg = config.from_mapping({"name": "t", "backend": "sim", "drive": {"port": "sim"},
                               "sim": {"realtime": False, "seed": 7, "load_cell_noise_n": 0},
                               "loop": {"rest_s": 0.05, "settle_s": 0.05},
                               "data_folder": str(tmp_path)})
    cal_svc.calibrate_loadcell(cfg, [0, 1, 2, 3, 4, 5, 4, 3, 2, 1, 0])
    p = profiles.load(Path("profiles/forte.yaml"), force_limit=cfg.limits.max_force_n)
    rep = run_svc.run(p, cfg, out=tmp_path / "f.h5", lockstep=True)
    n = learn_svc.grid(p, HZ).size
    y = learn_svc.load_cell_at_cycles(rep.path, n)
    d = learn_svc.measured_force(rep.path, n, "demand")
    models = learn_svc.drive_models(cfg, None)
    assert all(m.read_age_s == pytest.approx(0.0005) for m in models)
    assert plant.fit(models, d, y, HZ).rms_residual_n < 0.002
    at_tick = [dataclasses.replace(m, read_age_s=0.0) for m in models]
    assert plant.fit(at_tick, d, y, HZ).rms_residual_n > 0.05


def test_a_record_is_found_only_for_the_same_profile_rig_and_motor_calibration(tmp_path):
    import json

    from rig.control import records

    cfg = config.from_mapping({"name": "t", "backend": "sim", "drive": {"port": "sim"},
                               "data_folder": str(tmp_path)})
    p, r, u0 = grid("forte")
    err = {"max_pct": 2.0, "rms_pct": 0.5, "max_n": 0.6, "rms_n": 0.15, "trial": 1.0}
    rec = records.build(cfg, p, [], u0, [err], err, {"gain_n_per_n": 1.0}, None)
    path = records.write(cfg, rec)
    found = records.find(cfg, p, [])
    assert found is not None and found[1] == path
    ff, comp = records.demand_source(found[0])
    assert ff(p, 0.1) == pytest.approx(u0[50]) and ff(p, -0.01) == 0.0 and ff(p, 10.0) == 0.0
    assert comp["kind"] == "learned" and comp["record"] == rec["content_hash"]
    moved = tmp_path / "moved.yaml"
    moved.write_text("name: forte\nsegments:\n  - {hold: 0.02}\n  - {ramp: 0.08, to: 29}\n"
                     "  - {hold: 0.2}\n  - {ramp: 0.04, to: 0}\n  - {hold: 0.26}\n")
    other = profiles.load(moved, force_limit=60.0)
    assert records.find(cfg, other, []) is None            # a new profile: relearn
    motor = [{"sensor": "motor", "content_hash": "sha256:new"}]
    assert records.find(cfg, p, motor) is None             # a new motor calibration: relearn
    seed = config.from_mapping({"name": "t", "backend": "sim", "drive": {"port": "sim"},
                                "data_folder": str(tmp_path), "sim": {"seed": 5}})
    assert records.find(seed, p, []) is None               # another (simulated) rig
    body = json.loads(path.read_text())
    body["feedforward_n"][10] += 1.0
    path.write_text(json.dumps(body))
    with pytest.warns(UserWarning, match="content_hash does not match"):
        assert records.find(cfg, p, []) is None            # an altered record is not used


def test_the_ni_path_plays_a_learned_table_with_load_cell_feedback():
    # the loop's cycle as rig run does it (tick, feedforward hook, controller hook, limiter,
    # volts, write) on the NI backend: nidaqmx's own classes on the recording fake
    # interpreter of tests/ni_fake.py, the DAQmx writes asserted
    from ni_fake import FakeInterpreter

    from rig import loadcell, motor_torque
    from rig.control import records

    cfg = config.from_mapping({"backend": "ni", "drive": {"port": "/dev/ttyS0"}})
    out = cfg.channels.drive_output.physical_channel
    p, r, u0 = grid("forte")
    err = {"max_pct": 2.0, "rms_pct": 0.5, "max_n": 0.6, "rms_n": 0.15, "trial": 1.0}
    rec = records.build(cfg, p, [], u0, [err], err, {}, None)
    ff, _ = records.demand_source(rec)
    ctl = feedback.LoadCellPI()
    fake = FakeInterpreter()
    with fake.installed():
        d = backends.open_daq(cfg)
        try:
            d.arm()
            reader = backends.open_reader(d.reader_spec())
            try:
                reader.start()
                lc = cfg.channels.load_cell
                sens = loadcell.nominal_sensitivity(lc)
                limiter = motor_torque.Limiter(cfg.limits, 1 / HZ)
                scaling = motor_torque.TorqueScaling.from_config(cfg.drive_scaling,
                                                                 cfg.channels.drive_output)
                ctl.reset()
                for j in range(60):
                    tick = d.wait_for_tick()
                    assert (tick.index, tick.missed) == (j, 0)
                    reader.publish_feedback(4 * j, sens * 0.5 * u0[j])  # the key at half
                    _, ratio = d.feedback_ratio()
                    measured = float(loadcell.to_newtons(ratio, sens, 0.0))
                    demand, _ = limiter(ctl(j / HZ, ff(p, j / HZ), measured))
                    before = len(fake.of("write_analog_scalar_f64"))
                    d.write_volts(scaling.volts(demand))
                    writes = fake.of("write_analog_scalar_f64")
                    assert len(writes) == before + 1    # one write a cycle, on the loop's task
                    assert writes[-1].task == "rig-drive"
                    assert writes[-1].args["value"] == pytest.approx(scaling.volts(demand))
                    assert writes[-1].args["timeout"] == pytest.approx(1 / HZ)
                    assert fake.ao[out] == pytest.approx(scaling.volts(demand))
                assert demand > u0[59]   # the PI pushes harder than the table when the key lags
                assert fake.ao[out] != 0.0
            finally:
                reader.close()
        finally:
            d.close()
    last = fake.of("write_analog_scalar_f64")[-1]
    assert (last.task, last.args["value"], last.args["timeout"]) == ("rig-drive", 0.0, 1.0)
    assert fake.ao[out] == 0.0 and all(t.closed for t in fake.tasks.values())


@pytest.mark.slow
def test_ctrl_c_during_learning_keeps_what_was_learned(tmp_path, monkeypatch):
    import os
    import signal

    from rig.control import records
    from rig.recordings import runfile
    from rig.services import learn as learn_svc
    from rig.services import run as run_svc

    cfg = config.from_mapping({"name": "t", "backend": "sim", "drive": {"port": "sim"},
                               "sim": {"realtime": False},
                               "loop": {"rest_s": 0.05, "settle_s": 0.05},
                               "data_folder": str(tmp_path)})
    real = run_svc.run
    calls = []

    def run_then_ctrl_c(*a, **kw):
        calls.append(kw["out"])
        if len(calls) == 2:   # Ctrl-C in the middle of the second learning trial
            kw["on_cycle"] = lambda ctx: (os.kill(os.getpid(), signal.SIGINT)
                                          if ctx.tick == 150 else None)
        return real(*a, **kw)

    monkeypatch.setattr(run_svc, "run", run_then_ctrl_c)
    lines: list[str] = []
    rep = learn_svc.learn(Path("profiles/forte.yaml"), cfg, 4, out=tmp_path / "f.h5",
                          lockstep=True, on_line=lines.append)
    assert len(calls) == 2 and "interrupted (Ctrl-C)" in (rep.stopped or "")
    assert runfile.read(calls[1]).status.startswith("aborted: interrupted")
    assert rep.record is not None and len(rep.record["trials"]) == 1
    assert records.find(cfg, learn_svc.profiles.load(Path("profiles/forte.yaml")), [])[1] == \
        rep.record_path
    assert any(line.startswith("learning stopped: trial 2") for line in lines)


# ---- the learner's pieces: the drive model, its Jacobian, the fit, the solvers, the PI ----

def test_the_learners_drive_model_is_the_simulated_drive():
    from rig.control import plant

    single, risefall = plant.thesis_models()
    p, r, u0 = grid("two-peak")
    for variant, model in (("single", single), ("asymmetric", risefall)):
        res = offline.play(u0, variant=variant, noise_n=0.0)
        np.testing.assert_allclose(model.simulate(u0, HZ), res.key_force, atol=1e-9)


@pytest.mark.parametrize("which", [0, 1])
def test_the_jacobian_matches_finite_differences(which):
    from rig.control import plant

    model = plant.thesis_models()[which]
    n = 120
    d = np.r_[np.linspace(0, 20, 50), np.full(20, 20.0), np.linspace(20, 0, 50)]
    d[50:70] += np.linspace(0, 1, 20)   # still rising through the "hold"
    J = model.jacobian(d, HZ)
    assert np.allclose(np.triu(J), 0.0)  # strictly causal: y_j from d_0 .. d_{j-1}
    for j in (10, 45, 60, 100):          # inside a rising or falling stretch: modes kept
        h = 1e-6
        dp = d.copy()
        dp[j] += h
        fd = (model.simulate(dp, HZ) - model.simulate(d, HZ)) / h
        np.testing.assert_allclose(J[:, j], fd, atol=1e-5)
    assert J.shape == (n, n)


def test_a_localized_error_the_sum_of_squares_hides_is_learned():
    # issue 41: a release corner 0.5 N high over 12 cycles (noise 0.22 N) adds 3 N^2 to a
    # 301-cycle trial's sum of squares, inside the discrepancy principle's 2.4 N^2 margin
    # at most trials' noise; the multiresolution test finds it (its 12-cycle mean is 7.9
    # standard errors out) and the update fits it
    rng = np.random.default_rng(3)
    n, nv = 301, 0.22 ** 2
    tau = ilc.discrepancy_tau(n)
    bump = np.zeros(n)
    bump[150:162] = 0.5
    T = np.eye(n)
    w = rng.normal(0.0, 0.22, n) * 0.9      # a quiet draw: the sum of squares alone passes
    e = bump + w
    assert float(e @ e) <= tau * n * nv     # the global criterion would keep the table
    assert not ilc.within_noise(e, nv, tau)
    du, lam = ilc.noise_aware_step(T, e, nv, tau)
    assert np.isfinite(lam)
    # the smallest update that leaves the noise (T = I: a uniform shrink of e): what is
    # left is within the noise both ways, and the corner moved by its share of e
    assert ilc.within_noise(e - T @ du, nv, tau)
    assert du[150:162].mean() > 0.15 > abs(du[:140].mean())


def test_the_local_noise_test_keeps_its_level_on_noise_alone():
    n, nv = 301, 0.22 ** 2
    tau = ilc.discrepancy_tau(n)
    alarms = sum(not ilc.within_noise(np.random.default_rng(500 + s).normal(0.0, 0.22, n),
                                      nv, tau) for s in range(400))
    # 5 % by design (Bonferroni, both tests): measured 20 of these 400 (the sum of
    # squares alone: 10)
    assert alarms <= 0.08 * 400


def test_fit_picks_the_model_that_explains_the_trial_and_its_gain():
    from rig.control import plant

    models = plant.thesis_models()
    p, r, u0 = grid("forte")
    res = offline.play(u0, variant="asymmetric", gain=0.9, rng=np.random.default_rng(2))
    f = plant.fit(models, res.demand, res.measured, HZ)
    assert f.model is models[1] and f.gain == pytest.approx(0.9, abs=0.005)
    assert f.rms_residual_n == pytest.approx(NOISE, rel=0.15)   # all but the noise
    res = offline.play(u0, variant="single", rng=np.random.default_rng(2))
    assert plant.fit(models, res.demand, res.measured, HZ).model is models[0]


def test_noise_aware_step_fits_down_to_the_noise_and_not_below():
    rng = np.random.default_rng(0)
    n = 200
    T = np.tril(rng.standard_normal((n, n)), -1) * 0.1 + np.eye(n, k=-1)
    e = np.sin(np.arange(n) / 10.0) + 0.2 * rng.standard_normal(n)
    tau = ilc.discrepancy_tau(n)
    du, lam = ilc.noise_aware_step(T, e, 0.04, tau)
    assert np.isfinite(lam) and lam > 0
    np.testing.assert_allclose(du, np.linalg.solve(T.T @ T + lam * np.eye(n), T.T @ e),
                               atol=1e-6)

    def held(lam_: float) -> tuple[float, float]:   # (sum of squares, local) over bounds
        r = e - T @ np.linalg.solve(T.T @ T + lam_ * np.eye(n), T.T @ e)
        return (np.sum(r ** 2) / (tau * n * 0.04),
                ilc.local_excess(r, 0.04) / ilc.local_bound(n))

    # the residual is within the noise both ways, and a 2 % larger lam is not: the
    # smoothest update the noise allows (here the local test binds: e_0 is out of reach)
    assert max(held(lam)) <= 1 + 1e-6 and max(held(1.02 * lam)) > 1
    noise_only = 0.2 * rng.standard_normal(n)   # an error the noise explains: no update
    du, lam = ilc.noise_aware_step(T, noise_only, 0.04 * 1.2, tau)
    assert lam == float("inf") and not du.any()


def test_bounded_solve_is_the_bounded_least_squares_solution():
    from scipy.optimize import lsq_linear

    rng = np.random.default_rng(1)
    n = 80
    T = np.tril(rng.standard_normal((n, n))) * 0.2 + np.eye(n)
    e = 3 * rng.standard_normal(n)
    lo, hi = -np.abs(rng.standard_normal(n)), np.full(n, 1.5)
    x = ilc.bounded_solve(T, e, 0.3, lo, hi)
    ref = lsq_linear(np.vstack([T, np.sqrt(0.3) * np.eye(n)]), np.r_[e, np.zeros(n)],
                     bounds=(lo, hi), tol=1e-12, lsq_solver="exact").x
    np.testing.assert_allclose(x, ref, atol=1e-7)
    assert (x <= lo + 1e-12).any() and (x >= hi - 1e-12).any()   # both bounds active


def test_the_closed_loop_jacobian_of_the_pi_matches_finite_differences():
    from rig.control import plant

    model = plant.thesis_models()[0]
    p, r, u0 = grid("forte")
    pi = feedback.LoadCellPI()
    y0, d0, free = model.simulate_loop(u0, HZ, pi, 1.0, 50.0, r)
    F, C = pi.lifted(r.size)
    np.testing.assert_array_equal(F, np.eye(r.size))   # the PI's target is the profile
    T = plant.closed_loop(model.jacobian(d0, HZ), F, C, free)
    for j in (30, 60, 120):
        up = u0.copy()
        up[j] += 1e-5
        fd = (model.simulate_loop(up, HZ, pi, 1.0, 50.0, r)[0] - y0) / 1e-5
        np.testing.assert_allclose(T[:, j], fd, atol=1e-4)
    pi.target_n = None   # without the profile the PI's target is the delayed feedforward
    F2, _ = pi.lifted(r.size)
    assert not np.allclose(F2, np.eye(r.size))


def test_load_cell_pi_compares_with_the_profile_when_the_loop_gives_it():
    ctl = feedback.LoadCellPI()
    ctl.reset()
    ctl.target_n = 10.0
    out = ctl(0.0, 3.0, 10.0)        # on target: the feedforward passes unchanged
    assert out == pytest.approx(3.0) and ctl.integral == 0.0
    out = ctl(0.002, 3.0, 8.0)
    assert out == pytest.approx(3.0 + ctl.kp * 2.0)
    assert ctl.integrating == [True, True]


def test_long_tables_use_the_p_type_update():
    n = ilc.MAX_MODEL_POINTS + 1
    r = np.r_[np.linspace(0, 10, n // 2), np.linspace(10, 0, n - n // 2)]
    lrn = ilc.Learner.start(r, r, ilc.LearningFilter.default(HZ, 0.008), CFG.limits, HZ,
                            noise_n=NOISE)
    assert not lrn.model_based
    lrn.update(0.9 * r)
    assert "P-type" in lrn.notes[-1] and lrn.u[n // 2] > r[n // 2]


def _mismatched(m: float = 0.3):
    from rig.control import plant

    def bad(p):
        return plant.ProcessModel(p.K * (1 - m / 3), p.Tw * (1 + m), p.zeta, p.Tp3 * (1 + m))
    return tuple(plant.DriveModel(d.name + " (mismatched)", bad(d.rise), bad(d.fall))
                 for d in plant.thesis_models())


def test_refine_identifies_the_drives_dynamics_from_one_trial():
    from rig.control import plant

    p, r, u0 = grid("two-peak")
    res = offline.play(u0, variant="asymmetric", rng=np.random.default_rng(3))
    f = plant.fit(_mismatched()[1:], res.demand, res.measured, HZ)
    assert f.rms_residual_n > 3 * NOISE                # the wrong models miss the trial
    g = plant.refine(f, res.demand, res.measured, HZ)
    assert g.model.name.endswith("(identified)")
    assert g.rms_residual_n < 1.15 * NOISE             # the identified one: only the noise
    true = plant.thesis_models()[1]
    assert g.model.fall.Tw == pytest.approx(true.fall.Tw, rel=0.1)


@pytest.mark.slow
def test_a_learner_with_wrong_models_identifies_the_drive_and_learns():
    # the learner's models 30 % slower and 10 % weaker than the (asymmetric) drive
    p, lrn, keys, _ = learn("two-peak", "asymmetric", models=_mismatched())
    best, k = best_key(lrn, keys)
    assert "(identified)" in lrn.notes[0]
    assert k["max_pct"] <= 4.0 and k["rms_pct"] <= 1.0


class _TargetRecorder:
    """A controller with ``target_n``: records what rig run's loop gives it."""

    name = "target_recorder"

    def __init__(self) -> None:
        self.target_n: float | None = None
        self.seen: list[tuple[float, float | None]] = []

    def reset(self) -> None:
        pass

    def __call__(self, t: float, feedforward_n: float, measured_n: float) -> float:
        self.seen.append((t, self.target_n))
        return feedforward_n


@pytest.mark.slow
def test_rig_runs_loop_gives_a_controller_the_profile_as_target(tmp_path):
    from rig.services import run as run_svc

    cfg = config.from_mapping({"name": "t", "backend": "sim", "drive": {"port": "sim"},
                               "sim": {"realtime": False},
                               "loop": {"rest_s": 0.05, "settle_s": 0.05},
                               "data_folder": str(tmp_path)})
    ctl = _TargetRecorder()
    rep = run_svc.run(Path("profiles/forte.yaml"), cfg, out=tmp_path / "t.h5", lockstep=True,
                      controller=ctl)
    assert rep.complete
    p = profiles.load("profiles/forte.yaml")
    inside = [(t, v) for t, v in ctl.seen if 0 <= t <= p.duration]
    assert len(inside) > 250
    for t, v in inside:
        assert v == pytest.approx(p.at(t))


def test_the_pi_is_designed_from_the_motor_calibration_in_use():
    # K = the record's sensitivity, dead time = its lag + one cycle, lead = the lag in
    # cycles; without a record, the thesis's model at the run's rate
    pi = feedback.LoadCellPI()
    rec = {"fit": {"sensitivity": 0.8, "lag_s": 0.012}, "content_hash": "sha256:abc"}
    pi.design_from(rec, 500.0, 45.0)
    wc = 1.0 / (4.0 * 0.014)
    assert pi.kp == pytest.approx(0.2 / 0.8) and pi.ki == pytest.approx(wc / 0.8)
    assert pi.lead == 6 and pi.max_force_n == 45.0
    assert pi.design["source"] == "motor calibration sha256:abc"
    pi.design_from(None, 1000.0, 50.0)
    assert pi.kp == pytest.approx(0.2 / ilc.DEFAULT_GAIN_K) and pi.lead == 8
    assert pi.ki == pytest.approx(25.0 / ilc.DEFAULT_GAIN_K) and pi.dt == 0.001
    assert pi.design["source"].startswith("thesis single model")


@pytest.mark.slow
def test_rig_run_designs_its_pi_from_the_motor_calibration_and_records_it(tmp_path,
                                                                          monkeypatch):
    from rig.calibration import records as cal_records
    from rig.recordings import runfile
    from rig.services import calibrate as cal_svc
    from rig.services import learn as learn_svc
    from rig.services import run as run_svc

    cfg = config.from_mapping({"name": "t", "backend": "sim", "drive": {"port": "sim"},
                               "sim": {"realtime": False, "seed": 4},
                               "loop": {"rest_s": 0.05, "settle_s": 0.05,
                                        "controller": "rig.control.feedback:LoadCellPI"},
                               "data_folder": str(tmp_path)})
    forte = Path("profiles/forte.yaml")
    before = run_svc.run(forte, cfg, out=tmp_path / "before.h5", lockstep=True)
    meta = runfile.read(before.path).metadata["run"]
    assert meta["controller"] == "load_cell_pi"
    assert meta["controller_design"]["source"].startswith("thesis single model")
    result, path, _ = cal_svc.calibrate_motor(cfg)
    after = run_svc.run(forte, cfg, out=tmp_path / "after.h5", lockstep=True)
    design = runfile.read(after.path).metadata["run"]["controller_design"]
    rec_hash = cal_records.read(path)["content_hash"]
    assert design["source"] == f"motor calibration {rec_hash}"
    assert design["gain_k"] == pytest.approx(result.fit["sensitivity"])
    assert design["dead_time_s"] == pytest.approx(result.fit["lag_s"] + 0.002)
    assert design["kp"] == pytest.approx(0.2 / result.fit["sensitivity"])
    # --learn designs the learner's copy of the PI (its lifted form) the same way
    seen = []
    real = feedback.LoadCellPI.design_from

    def spy(self, rec, hz, max_force):
        seen.append(None if rec is None else rec["content_hash"])
        return real(self, rec, hz, max_force)

    monkeypatch.setattr(feedback.LoadCellPI, "design_from", spy)
    learn_svc.learn(forte, cfg, 1, out=tmp_path / "l.h5", lockstep=True)
    assert len(seen) >= 2 and set(seen) == {rec_hash}   # the learner's copy and the loop's


@pytest.mark.slow
def test_a_nearly_noise_free_load_cell_does_not_make_the_rise_fall_inversion_chatter():
    # with almost no noise the discrepancy principle allows an almost exact inverse; the
    # Levenberg-Marquardt damping keeps each step where the rise/fall modes it assumed
    # hold (without it: 29-35 % after 5 trials, the demand changing direction ~190 times).
    # The plan trades RMS for maximum error here (trial 2: key max 1.55 %, RMS 0.37 %;
    # later 0.94 %, 0.43 %): not diverging, since the maximum fell (the RMS rule alone
    # stopped it at trial 4)
    _, lrn, keys, _ = learn("forte", "asymmetric", noise=0.005)
    assert lrn.stopped is None
    assert best_key(lrn, keys)[1]["max_pct"] <= 5.0
    assert np.sum(np.diff(np.sign(np.diff(lrn.u))) != 0) < 120   # ~190 without the damping


# ---- the offline bound: the best any feedforward can reach on the drive model ----

def _feasible_reference(model, n: int = 60):
    """A demand within the limits (rises at 5 N per cycle, holds, falls) and the model's
    key force for it: a reference some demand tracks exactly."""
    d = np.r_[np.linspace(0, 20, 5), np.full(20, 20.0), np.linspace(18, 0, 10), np.zeros(n - 35)]
    return d, np.maximum(model.simulate(d, HZ), 0.0)


@pytest.mark.parametrize("which", [0, 1])
def test_fixed_modes_bound_is_zero_for_a_reference_a_demand_tracks(which):
    from rig.control import bound, plant

    model = plant.thesis_models()[which]
    d, r = _feasible_reference(model)
    b = bound.fixed_modes(model, r, model.modes(d), CFG.limits, HZ)
    assert b.max_error_n < 1e-5 and b.dual_bound_n < 1e-5   # the LP finds it
    step = CFG.limits.max_rate_n_per_s / HZ
    assert b.demand.min() >= 0 and np.abs(np.diff(np.r_[0.0, b.demand])).max() <= step + 1e-12


def test_fixed_modes_bound_of_a_step_no_demand_can_follow():
    # r jumps to 10 N at cycle 1: y_1 = G[1, 0] d_0 with d_0 <= 10 N (the rate limit), so
    # no demand has an error below 10 - 10 G[1, 0] (and the bound is what it plays)
    from rig.control import bound, plant

    model = plant.thesis_models()[0]
    r = np.r_[0.0, np.full(49, 10.0)]
    b = bound.fixed_modes(model, r, np.ones(50, bool), CFG.limits, HZ)
    g10 = model.lifted(np.ones(50, bool), HZ)[1, 0]
    assert b.max_error_n >= 10.0 - 10.0 * g10 - 1e-9
    assert b.max_error_n == pytest.approx(b.dual_bound_n, abs=1e-6)


@pytest.mark.slow
def test_best_demand_finds_the_modes_of_a_trackable_rise_fall_reference():
    from rig.control import bound, plant

    model = plant.thesis_models()[1]
    d, r = _feasible_reference(model, 40)
    b = bound.best_demand(model, r, CFG.limits, HZ, time_limit_s=60)
    assert b.max_error_n < 1e-3 and b.dual_bound_n <= b.max_error_n + 1e-9
    wrong = bound.fixed_modes(model, r, np.ones(40, bool), CFG.limits, HZ)   # never falling
    assert wrong.max_error_n > 0.1


@pytest.mark.slow
def test_no_release_with_one_mode_switch_reaches_2_percent_on_forte():
    # the offline bound (benchmarks/tracking_bound.py): with the rise/fall drive, any
    # demand that rises and then falls (one mode switch, from any cycle around the release)
    # leaves >= 2.5 % of forte's peak on the true key force, noise-free and with the exact
    # model; the single model's bound is 0.8 % (issue 18's 2 % is reachable there)
    from rig.control import bound, plant

    p, r, _ = grid("forte")
    single, risefall = plant.thesis_models()
    n = r.size
    errs = [bound.fixed_modes(risefall, r, np.arange(n) < k, CFG.limits, HZ).max_error_n
            for k in range(136, 152, 2)]
    assert 100 * min(errs) / p.peak == pytest.approx(2.536, abs=0.01)
    assert 100 * bound.fixed_modes(single, r, np.ones(n, bool), CFG.limits,
                                   HZ).max_error_n / p.peak < 0.85


# ---- the minimax plan the learner takes when it beats the Newton step ----

def _bell(n: int = 60, width: int = 30):
    """A force pulse (20 N over ``width`` cycles, falling at up to 2.1 N per cycle), rest."""
    j = np.arange(n)
    return np.where(j < width, 10.0 * (1 - np.cos(2 * np.pi * j / width)), 0.0)


def test_falling_runs_and_schedule():
    from rig.control import bound

    r = np.r_[0.0, 1, 2, 3, 2, 1, 1, 1, 2, 1, 0, 0, 0, 0, 0, 0]
    # it falls at cycles 4-5 and 9-10; from lead cycles before to 2 lead after, [start, end)
    assert bound.falling_runs(r, 0) == ((4, 6), (9, 11))
    assert bound.falling_runs(r, 1) == ((3, 13),)          # they meet: one interval
    assert bound.falling_runs(np.arange(5.0), 2) == ()
    np.testing.assert_array_equal(bound.schedule(6, ((1, 3), (4, 5))),
                                  [True, False, False, True, False, True])


@pytest.mark.slow
def test_planned_finds_the_best_single_fall_schedule_of_a_brute_force_scan():
    # from the reference's fall and from two bad starts (falling too late and never rising
    # again; falling too early and briefly), the coordinate search reaches the best
    # schedule of a scan over one falling interval [a, c); that one brakes (rises again
    # before the end: the fast rising model stops the slow falling one's swing), ~40 %
    # below the best that does not
    from rig.control import bound, plant

    model = plant.thesis_models()[1]
    r = _bell()
    n = r.size
    scan = {}
    for a in range(9, 23, 2):
        for c in range(a + 2, n + 1):
            try:
                scan[(a, c)] = bound.fixed_modes(model, r, bound.schedule(n, ((a, c),)),
                                                 CFG.limits, HZ).max_error_n
            except InputError:    # no demand plays it (a fall from 0)
                continue
    no_brake = min(v for (a, c), v in scan.items() if c == n)
    assert min(scan.values()) < 0.7 * no_brake
    for start in (bound.falling_runs(r, 4), ((21, n),), ((11, 17),)):
        b = bound.planned(model, r, CFG.limits, HZ, start)
        assert b.max_error_n <= min(scan.values()) * (1 + 1e-6)
        assert b.falls[0][1] < n and b.programmes >= 2
        np.testing.assert_array_equal(b.rising, bound.schedule(n, b.falls))


def test_planned_may_cut_a_release_into_two_falls_each_switch_a_real_reversal():
    # max_falls = 2: the search may cut the fall by a rise (a release that brakes on its
    # way down, then at its end: four mode switches); on the bell it more than halves the
    # maximum error of one brake; every switch is a change of at least switch_n in its
    # direction, and the simulated drive plays the demand with the model's error
    from rig.control import bound, offline, plant

    model = plant.thesis_models()[1]
    r = _bell()
    start = bound.falling_runs(r, 4)
    one = bound.planned(model, r, CFG.limits, HZ, start, max_falls=1, switch_n=0.01)
    two = bound.planned(model, r, CFG.limits, HZ, start, max_falls=2, switch_n=0.01)
    assert len(one.falls) == 1 and len(two.falls) == 2
    assert two.max_error_n < 0.5 * one.max_error_n
    change = np.diff(np.r_[0.0, two.demand])
    m = two.rising
    at = np.flatnonzero(np.r_[not m[0], m[1:] != m[:-1]])
    assert at.size == 4
    assert np.all(np.where(m[at], change[at], -change[at]) >= 0.01 - 1e-9)
    played = offline.play(two.demand, variant="asymmetric", noise_n=0.0, limits=CFG.limits)
    assert np.abs(r - played.key_force).max() == pytest.approx(two.max_error_n, abs=1e-6)
    # on the same schedule, a larger reversal asked of every switch costs maximum error
    # (the programme's optimum; it shrinks the feasible set)
    lp = [bound.fixed_modes(model, r, two.rising, CFG.limits, HZ, switch_n=s).dual_bound_n
          for s in (0.01, 2.0)]
    assert lp[1] > lp[0] + 0.01


def test_planned_with_smooth_stays_within_its_error_and_calms_the_demand():
    from rig.control import bound, plant

    model = plant.thesis_models()[0]
    p, r, _ = grid("forte")
    falls = bound.falling_runs(r, 4)
    sharp = bound.planned(model, r, CFG.limits, HZ, falls)
    calm = bound.planned(model, r, CFG.limits, HZ, falls, smooth=0.05)
    assert calm.max_error_n <= 1.05 * sharp.max_error_n + 1e-4   # + the solver's tolerance
    tv = [np.abs(np.diff(np.r_[0.0, b.demand])).sum() for b in (sharp, calm)]
    assert tv[1] <= tv[0] + 1e-6
    assert np.abs(r - np.maximum(model.simulate(calm.demand, HZ), 0)).mean() < \
        np.abs(r - np.maximum(model.simulate(sharp.demand, HZ), 0)).mean()


def test_settle_makes_rounding_level_changes_exact_holds():
    from rig.control import plant

    u = np.r_[0.0, 5.0, 10.0, 10.0 + 1e-15, 10.0, 10.0 - 4e-15, 10.0, 5.0, 0.0]
    out = ilc.settle(u, 10.0)
    np.testing.assert_array_equal(out, [0.0, 5.0, 10.0, 10.0, 10.0, 10.0, 10.0, 5.0, 0.0])
    # the asymmetric drive's mode follows the last change however small: with u, the hold
    # plays the falling model from cycle 5; settled, the rising one until the release
    risefall = plant.thesis_models()[1]
    assert not risefall.modes(u)[5] and risefall.modes(out)[5]
    # a change that holding would push past the rate limit is kept
    v = np.r_[0.0, 1e-12, 10.0 + 1e-12]
    np.testing.assert_array_equal(ilc.settle(v, 10.0), v)
    np.testing.assert_array_equal(ilc.settle(np.r_[0.0, 1e-3, 2.0], 10.0), [0.0, 1e-3, 2.0])


@pytest.mark.slow
def test_the_learner_takes_the_plan_only_where_it_beats_the_newton_step():
    # asymmetric forte: the plan (the release falling, then braking) is taken and plays
    # better than the Newton steps alone (minimax=False); with load-cell feedback in the
    # loop it is not planned (the programmes model the open loop)
    _, lrn, k_plan, _ = learn("forte", "asymmetric", trials=3)
    _, newton, k_newton, _ = learn("forte", "asymmetric", trials=3, minimax=False)
    assert any("minimax plan" in n for n in lrn.notes)
    assert not any("minimax" in n for n in newton.notes)
    h = [x for x in lrn.history if "planned_max_n" in x]
    assert h and all(x["minimax"] == 1.0 for x in h)
    assert max(x["max_pct"] for x in k_plan[1:]) < min(x["max_pct"] for x in k_newton[1:]) - 0.5
    _, pi, _, _ = learn("forte", "asymmetric", trials=2, pi=True)
    assert not any("minimax" in n for n in pi.notes)


def test_the_noise_margin_is_two_sigma_of_the_difference_of_two_trials():
    # two trials with the same error e and independent noise: their mean squares differ by
    # more than _margin in ~2.3 % of pairs (one-sided 2 sigma), the error's cross term
    # with the noise included (the noise's square alone would give ~0.4 sigma too little)
    n, sigma = 300, 0.22
    rng = np.random.default_rng(5)
    e = 0.15 * np.sin(np.arange(n) / 7.0) * np.sqrt(2)      # RMS 0.15 N
    lrn = ilc.Learner.start(np.ones(n), np.ones(n), ilc.LearningFilter.default(HZ, 0.008),
                            CFG.limits, HZ, noise_n=sigma)
    rms = float(np.sqrt(np.mean(e ** 2) + sigma ** 2))
    ms = np.mean((e[None, :] + sigma * rng.standard_normal((20000, n))) ** 2, axis=1)
    d = ms[::2] - ms[1::2]
    assert np.mean(d > lrn._margin(rms)) == pytest.approx(0.0228, abs=0.004)


def test_a_trial_that_replays_the_best_table_is_never_worse():
    n = 300
    lrn = ilc.Learner.start(np.ones(n), np.ones(n), ilc.LearningFilter.default(HZ, 0.008),
                            CFG.limits, HZ, noise_n=0.22)
    lrn.best, lrn.best_u = {"rms_n": 0.25}, lrn.u.copy()
    assert not lrn._worse_than_best(5.0)          # the same table: only the noise differs
    lrn.u = lrn.u * 1.01
    assert lrn._worse_than_best(5.0)
    assert not lrn._worse_than_best(0.26)         # within 3 sigma of the noise


# ---- issue 41: the kept table and the restart from it ----

def _errs(*pairs: tuple[float, float]) -> list[dict[str, float]]:
    return [{"rms_n": r, "max_n": m} for r, m in pairs]


def _spread(lrn):
    return lambda rms: lrn._margin(rms)


def test_the_kept_trial_is_the_lowest_maximum_within_the_noise_spread_of_the_lowest_rms():
    n, sigma = 300, 0.22
    lrn = ilc.Learner.start(np.ones(n), np.ones(n), ilc.LearningFilter.default(HZ, 0.008),
                            CFG.limits, HZ, noise_n=sigma)
    m = _spread(lrn)
    # the spread at RMS 0.25 N: 2 sigma of the difference of two trials' mean squares
    band = np.sqrt(0.25 ** 2 + 2 * np.sqrt(2 * (2 * sigma ** 4 + 4 * sigma ** 2
                                                  * (0.25 ** 2 - sigma ** 2)) / n)) - 0.25
    assert m(0.25) == pytest.approx((0.25 + band) ** 2 - 0.25 ** 2)
    # issue 41's run (N; forte's peak 30 N): trial 5 within the noise of trial 3 by its RMS
    # but with a higher maximum error had replaced it; trial 3 is kept
    forte = _errs((3.6, 3.56), (1.2, 2.57), (0.252, 0.846), (0.30, 1.13), (0.267, 1.455))
    assert [ilc.kept_trial(forte[:k], m) for k in range(1, 6)] == [0, 1, 2, 2, 2]
    # within the spread: the lower maximum wins, even with a (slightly) higher RMS; of
    # equal maxima the later
    assert ilc.kept_trial(_errs((0.25, 0.9), (0.25 + 0.5 * band, 0.8)), m) == 1
    assert ilc.kept_trial(_errs((0.25, 0.8), (0.25 + 0.5 * band, 0.8)), m) == 1
    assert ilc.kept_trial(_errs((0.25 + 0.5 * band, 0.8), (0.25, 0.9)), m) == 0
    # beyond the spread: a noise-lucky maximum of a trial worse in RMS is not kept, and a
    # trial clearly lower in RMS is kept whatever its maximum (it starts a new pool)
    assert ilc.kept_trial(_errs((0.25, 0.9), (0.25 + 1.5 * band, 0.5)), m) == 0
    assert ilc.kept_trial(_errs((0.25 + 1.5 * band, 0.5), (0.25, 0.9)), m) == 1
    # the pool is measured from the lowest RMS, not from the kept trial: a chain of trials
    # each within the spread of the one before does not drift away from it
    chain = _errs((0.25, 0.9), (0.25 + 0.8 * band, 0.85), (0.25 + 1.6 * band, 0.8))
    assert ilc.kept_trial(chain, m) == 1


def _trial(r: np.ndarray, rms_n: float, seed: int) -> np.ndarray:
    """A measured load-cell force: the reference less a smooth error of RMS ``rms_n``
    (a lag-like bump over the press), plus the simulated load cell's noise."""
    shape = np.gradient(r)
    shape = shape / np.sqrt(np.mean(shape ** 2))
    return r - rms_n * shape + NOISE * np.random.default_rng(seed).standard_normal(r.size)


def test_the_learner_keeps_the_trial_of_the_criterion_and_its_table():
    _, r, u0 = grid("forte")
    lrn = ilc.Learner.start(r, u0, ilc.LearningFilter.default(HZ, 0.008), CFG.limits, HZ,
                            noise_n=NOISE, models=())           # the P-type update: fast
    tables = []
    for k, level in enumerate([1.0, 0.30, 0.305, 0.29, 0.31]):
        tables.append(lrn.u.copy())
        lrn.update(_trial(r, level, seed=k))
        rms = np.array([h["rms_n"] for h in lrn.history])
        mx = np.array([h["max_n"] for h in lrn.history])
        lowest = rms.min()
        pool = rms ** 2 <= lowest ** 2 + lrn._margin(lowest)
        want = max(np.flatnonzero(pool & (mx == mx[pool].min())))
        best_u, best = lrn.result()
        assert best["trial"] == want + 1
        np.testing.assert_array_equal(best_u, tables[want])
    assert lrn.stopped is None


def test_a_trial_worse_beyond_the_spread_is_not_the_next_starting_point():
    # the P-type update (its steps exactly computable): trial 2 worse than trial 1 beyond
    # the noise spread; the update restarts from trial 1's table and error, half the step
    _, r, u0 = grid("forte")
    filt = ilc.LearningFilter.default(HZ, 0.008)
    lrn = ilc.Learner.start(r, u0, filt, CFG.limits, HZ, noise_n=NOISE, models=())
    y1 = _trial(r, 0.30, seed=1)
    lrn.update(y1)
    t1, t2 = lrn.best_u.copy(), lrn.u.copy()
    assert not np.array_equal(t1, t2)
    lrn.update(_trial(r, 0.45, seed=2))       # worse beyond the spread, not 1.5x worse
    assert lrn.stopped is None and lrn.result()[1]["trial"] == 1
    assert lrn.history[1]["restarted"] == 1.0 and "restarting from its table" in lrn.notes[-1]
    m = filt.lead
    e1 = r - y1
    gain = filt.gain * max(1 / 2, lrn.min_gain_fraction) * 0.5     # trial 2's gain, halved
    want = ilc.limit_table(ilc.q_filter(t1 + gain * np.r_[e1[m:], np.full(m, e1[-1])],
                                        filt.q_cutoff_hz, HZ), CFG.limits, 1 / HZ)
    np.testing.assert_allclose(lrn.u, want)
    # a trial within the spread, or one that replayed the kept table, is a starting point
    lrn2 = ilc.Learner.start(r, u0, filt, CFG.limits, HZ, noise_n=NOISE, models=())
    lrn2.update(_trial(r, 0.30, seed=1))
    lrn2.update(_trial(r, 0.30, seed=2))
    assert "restarted" not in lrn2.history[1]


@pytest.mark.slow
def test_the_model_based_update_restarts_from_the_kept_table_with_half_the_step():
    _, r, u0 = grid("forte")
    lrn = ilc.Learner.start(r, u0, ilc.LearningFilter.default(HZ, 0.008), CFG.limits, HZ,
                            noise_n=NOISE, minimax=False, identify=False)
    lrn.update(_trial(r, 0.30, seed=1))
    t1, t2 = lrn.best_u.copy(), lrn.u.copy()
    lrn.update(_trial(r, 0.45, seed=2))
    assert "restarting from its table, step x 0.5" in lrn.notes[-1]
    # the Newton step from trial 1's table and error, half as far (its model's gain is
    # the worse trial's estimate, the drive as it is now: within a few % of trial 1's)
    step, first = lrn.u - t1, t2 - t1
    assert np.linalg.norm(step) / np.linalg.norm(first) == pytest.approx(0.5, abs=0.05)
    assert step @ first / (np.linalg.norm(step) * np.linalg.norm(first)) > 0.99
    lrn.update(_trial(r, 0.20, seed=3))       # a new kept trial doubles the step again
    assert lrn.result()[1]["trial"] == 3 and lrn._trust == 1.0


def test_the_learner_reads_the_recorded_force_not_the_loops_late_reads(tmp_path,
                                                                       monkeypatch):
    # issue 41: in real time the loop is sometimes handed a sample a period old (the
    # plant process behind real time around the strike): on forte's release one period
    # late reads 1.5 N that is not in the force on the key. The learner learns from the
    # recorded force at each cycle's tick (load_cell_at_cycles), and its errors are of
    # that force. Here the loop's reads of a lock-step trial are made late at the release,
    # as measured on a loaded machine, after the trial wrote them.
    import h5py

    from rig.services import learn as learn_svc
    from rig.services import run as run_svc

    cfg = config.from_mapping({"name": "t", "backend": "sim", "drive": {"port": "sim"},
                               "sim": {"realtime": False, "seed": 3},
                               "loop": {"rest_s": 0.05, "settle_s": 0.05},
                               "data_folder": str(tmp_path)})
    real_run = run_svc.run
    late_at = np.arange(155, 170)   # cycles of the release (310-338 ms)

    def run_with_late_reads(*a, **kw):
        rep = real_run(*a, **kw)
        with h5py.File(rep.path, "r+") as f:
            cmd = f["trial_000/commands"]
            t = cmd["time"][:]
            first = int(np.argmax(t >= -1e-9))
            seen = cmd["measured_force"][:]
            seen[first + late_at] = seen[first + late_at - 1]   # one period late
            cmd["measured_force"][:] = seen
        return rep

    monkeypatch.setattr(run_svc, "run", run_with_late_reads)
    p = profiles.load("profiles/forte.yaml", force_limit=cfg.limits.max_force_n)
    rep = learn_svc.learn(Path("profiles/forte.yaml"), cfg, 1, out=tmp_path / "f.h5",
                          lockstep=True)
    path = rep.runs[0]
    t = learn_svc.grid(p, cfg.rates.control_hz)
    ref = np.array([p.at(x) for x in t])
    recorded = learn_svc.load_cell_at_cycles(path, t.size)
    seen = learn_svc.measured_force(path, t.size)
    # the loop's reads differ where they were made late, and only there
    assert np.array_equal(np.nonzero(recorded != seen)[0], late_at)
    assert np.abs(seen - recorded).max() > 1.0   # N: a period late on the release
    # the recorded force at each tick is the period's last 2 kHz sample (the sample the
    # loop is handed when it comes in time)
    from rig.recordings import runfile
    tr = runfile.read(path).trials[0]
    k = np.searchsorted(tr.time, t[100]) - 1
    assert recorded[100] == tr.channels["force"][k] and tr.time[k] < t[100]
    # what the learner learned from and printed: the recorded force's error
    by_recorded, by_seen = ilc.errors(ref, recorded, p.peak), ilc.errors(ref, seen, p.peak)
    assert by_recorded["rms_n"] != pytest.approx(by_seen["rms_n"], abs=1e-6)
    assert rep.history[0]["rms_n"] == pytest.approx(by_recorded["rms_n"], abs=1e-12)
    assert rep.history[0]["max_n"] == pytest.approx(by_recorded["max_n"], abs=1e-12)
    # a record that does not cover the profile is refused, naming the file and dataset
    with pytest.raises(InputError, match=r"f-learn1\.h5: commands/time"):
        learn_svc.load_cell_at_cycles(path, t.size + 10_000)


def test_the_plans_target_pools_the_models_miss_over_trials_that_agree():
    # issue 41: what the drive model misses (the action's reaction on the load cell over
    # forte's release, ~0.4 N) repeats from trial to trial while the noise does not; the
    # plan's target is corrected by the misses that agree with the newest one, averaged
    p, r, u0 = grid("forte")
    n, sigma = r.size, NOISE
    lrn = ilc.Learner.start(r, u0, ilc.LearningFilter.default(HZ, 0.008, 1.0), CFG.limits,
                            HZ, noise_n=sigma)
    tau = ilc.discrepancy_tau(n)
    rng = np.random.default_rng(7)
    plant_miss = np.zeros(n)
    plant_miss[151:168] = 0.4
    other = np.zeros(n)
    other[40:60] = 1.0          # a trial whose table made the plant do something else
    lrn._misses = [other + rng.normal(0, sigma, n)] + [
        plant_miss + rng.normal(0, sigma, n) for _ in range(4)]
    newest = lrn._misses[-1]
    miss, nv, pooled = lrn._pooled_miss(newest, sigma ** 2, tau)
    assert pooled == 4 and nv == pytest.approx(sigma ** 2 / 4)   # the other one left out
    assert np.allclose(miss, np.mean(lrn._misses[1:], axis=0))
    # the pooled miss is nearer the plant's than one trial's, by about sqrt(4)
    one = np.sqrt(np.mean((newest - plant_miss) ** 2))
    four = np.sqrt(np.mean((miss - plant_miss) ** 2))
    assert four < 0.6 * one
    # the trials already averaged with one table (nv = sigma^2 / 4): pooling four is no gain
    assert lrn._pooled_miss(newest, sigma ** 2 / 4, tau)[2] == 4
    assert lrn._pooled_miss(newest, sigma ** 2 / 4, tau)[0] is newest
    # a noise-free load cell: the newest miss as it is
    quiet = ilc.Learner.start(r, u0, ilc.LearningFilter.default(HZ, 0.008, 1.0), CFG.limits,
                              HZ, noise_n=0.0)
    quiet._misses = [plant_miss, plant_miss + 0.1]
    assert quiet._pooled_miss(plant_miss, 0.0, tau)[2] == 1


@pytest.mark.slow
def test_the_learner_pools_a_repeating_miss_into_its_plans():
    # the wiring of the test above: a plant that reads 0.4 N more over forte's release
    # than the drive model (as the simulated action does), trial after trial
    p, r, u0 = grid("forte")
    lrn = ilc.Learner.start(r, u0, ilc.LearningFilter.default(HZ, 0.008, 1.0), CFG.limits,
                            HZ, noise_n=NOISE)
    extra = np.zeros(r.size)
    extra[151:168] = 0.4
    rng = np.random.default_rng(11)
    for _ in range(3):
        res = offline.play(lrn.u, noise_n=NOISE, rng=rng)
        lrn.update(res.measured + extra, res.demand, res.lateness)
    assert len(lrn._misses) == 3
    assert any("the model's miss pooled over" in note for note in lrn.notes[1:]), lrn.notes
