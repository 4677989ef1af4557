"""Calibration of rig.analysis.stats on correlated noise like 2 kHz residuals (issue 13):
the held-out improvement test holds its false-alarm rate on noise alone and the HAC
(Newey-West) intervals of a least-squares fit cover the truth at their nominal rate, where
independent-noise intervals do not."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest
from scipy.signal import lfilter

from rig.analysis import diagnose as dg
from rig.analysis import fit as ft
from rig.analysis import stats

N, SEG = 600, [300, 300]  # two trials' channels of 0.15 s at 2 kHz


def coloured(rng: np.random.Generator, n: int = N) -> np.ndarray:
    """Noise through a resonant 2nd-order filter (ringing at ~100 Hz at 2 kHz) plus a slow
    AR(1) part: strongly autocorrelated, like a sensor chain's residual."""
    w = rng.standard_normal(n)
    r, th = 0.97, 2 * math.pi * 100 / 2000
    ring = lfilter([1.0], [1, -2 * r * math.cos(th), r * r], w)
    slow = lfilter([1.0], [1, -0.95], rng.standard_normal(n))
    return ring / ring.std() + 0.5 * slow / slow.std()


def test_improvement_test_holds_its_level_on_noise_alone() -> None:
    rng = np.random.default_rng(1)
    t = np.arange(N) / 2000
    alarms, reps = 0, 400
    for _ in range(reps):
        e = coloured(rng)
        # a change fitted on other (training) noise: smooth, independent of e, small
        delta = 0.05 * np.sin(2 * math.pi * 30 * t + rng.uniform(0, 6))
        _, p = stats.improvement_test(e, e - delta, SEG)
        alarms += p <= 0.05
    assert alarms / reps <= 0.08, alarms / reps
    # and it finds a real improvement of the same size against the same noise
    found = 0
    for _ in range(100):
        e = coloured(rng)
        miss = 1.0 * np.sin(2 * math.pi * 30 * t)
        _, p = stats.improvement_test(e + miss, e, SEG)
        found += p <= 0.05
    print(f"found {found}/100")
    assert found >= 80, found


def test_hac_intervals_cover_where_independent_noise_ones_do_not() -> None:
    rng = np.random.default_rng(2)
    t = np.arange(N) / 2000
    X = np.column_stack([np.sin(2 * math.pi * 20 * t), np.exp(-t / 0.05)])
    truth = np.array([1.0, -0.5])
    cover_hac, cover_iid = np.zeros(2), np.zeros(2)
    reps = 300
    for _ in range(reps):
        y = X @ truth + 0.3 * coloured(rng)
        beta, *_ = np.linalg.lstsq(X, y, rcond=None)
        r = y - X @ beta
        se_hac = np.sqrt(np.diag(stats.sandwich_cov(X, r, SEG)))
        se_iid = np.sqrt(np.diag(np.linalg.inv(X.T @ X)) * (r @ r) / (N - 2))
        cover_hac += np.abs(beta - truth) <= 1.96 * se_hac
        cover_iid += np.abs(beta - truth) <= 1.96 * se_iid
    assert np.all(cover_hac / reps >= 0.85), cover_hac / reps  # each parameter's interval
    assert np.all(cover_iid / reps < 0.7), cover_iid / reps  # what the old errors looked like


def test_values_print_and_round_to_their_uncertainty() -> None:
    assert stats.fmt(63.4123, 0.2211, "Hz") == "63.41 +- 0.22 Hz"
    assert stats.fmt(0.016912, 0.00201, "1") == "0.0169 +- 0.0020"
    assert stats.fmt(19387.2, 3456.0, "N/m") == "19400 +- 3500 N/m"
    assert "nan" not in stats.fmt(3e-13, math.nan, "s")
    assert stats.fmt(math.nan, 1.0) == "not determined"
    assert stats.round_to(0.12064, 0.0049) == 0.1206
    assert stats.round_to(19387.2, 3456.0) == 19400.0
    # an uncertainty beyond the value keeps three of its digits (the wide benchmark's
    # reserved seed 1014 wrote a drive bandwidth of 0.0 Hz, outside [5, 1000] Hz)
    assert stats.round_to(41.3, 500.0) == 41.3
    assert stats.round_to(0.0051472, 0.02) == 0.00515
    assert stats.round_to(-3.456e-7, 1e-3) == -3.46e-7


def test_values_in_sentences_read_plainly() -> None:
    assert stats.short(1000.0) == "1000"              # not 1e+03
    assert stats.short(968.4) == "968"
    assert stats.short(45.23) == "45.2"
    assert stats.short(0.002791) == "0.00279"
    assert stats.short(2.75e-4) == "0.000275"
    assert stats.short(3e-13) == "0"                  # a bound reached, not 3e-13
    assert stats.short(-0.5) == "-0.500"
    assert stats.short(5.376e9) == "5.38e+09"
    assert stats.short(math.nan) == "not determined"


def _cand(name: str, resid: np.ndarray, significant: bool = True) -> dg.Candidate:
    base = 1.0
    rem = 1 - float(np.mean(resid ** 2)) / base
    return dg.Candidate(name, "", {}, {}, {}, rem, {}, 10.0, significant, test_resid=resid)


def test_a_ranking_that_changes_across_trials_or_windows_is_warned_about() -> None:
    n = 40
    data = ft.Data([], "force", None, [["hammer_angle"], ["hammer_angle"]],
                   [np.arange(n) / 2000] * 2, [], [], [], [np.ones(n, bool)] * 2)
    base = np.ones(2 * n)
    # the string explains trial 0 entirely, the back check half of both: trials disagree
    string = np.r_[np.zeros(n), np.ones(n)]
    check = np.full(2 * n, math.sqrt(0.45))
    notes = dg.stability_notes([_cand("compliant_string", string),
                                _cand("backcheck_law", check)], base, data)
    assert len(notes) == 1 and "trial 0: compliant_string" in notes[0] \
        and "trial 1: backcheck_law" in notes[0], notes
    # one effect best everywhere: no warning
    assert dg.stability_notes([_cand("compliant_string", 0.1 * base),
                               _cand("backcheck_law", check)], base, data) == []


def test_an_effect_whose_own_parameters_are_off_is_not_named() -> None:
    c = dg.Candidate("key_encoder_misread", "", {"key_encoder_misread.sensitivity": 0.55},
                     {"key_encoder_misread.sensitivity": 4.6}, {}, 0.5, {}, 10.0, False,
                     p_value=1e-6, train_gain=0.4)
    from rig.model.effects import BUILTIN

    c.off_z = dg._off_z([BUILTIN["key_encoder_misread"]], c.values, c.sigma)
    dg.judge(c, 0.01, 0.2, 3.0, 1.96)
    assert not c.significant and "off values" in c.why_not
    c.sigma["key_encoder_misread.sensitivity"] = 0.1
    c.off_z = dg._off_z([BUILTIN["key_encoder_misread"]], c.values, c.sigma)
    dg.judge(c, 0.01, 0.2, 3.0, 1.96)
    assert c.significant
    # worse than nothing reads "worse", never a negative percentage
    c.removal = -13.047
    assert "makes the held-out error worse" in c.describe() and "-1304" not in c.describe()


def _backcheck_case(seed: int, load_cell_noise: float = 1.0):
    """Two 0.15 s blows of a truth whose back check differs (the hidden-effect suite's
    values) through the simulated rig's sensor chain, with the load cell's noise scaled."""
    import sys
    import tempfile
    from pathlib import Path

    from rig.analysis import measurement as ms
    from rig.analysis import synth
    from rig.model.action import ActionModel
    from rig.model.effects import BUILTIN

    sys.path.insert(0, str(Path(__file__).parent))
    from test_analysis_hidden import blows, truth_values

    cls = BUILTIN["backcheck_law"]
    truth_v = truth_values(cls)
    cfg = synth.default_rig()
    cfg = cfg.model_copy(update={"sim": cfg.sim.model_copy(update={
        "load_cell_noise_n": cfg.sim.load_cell_noise_n * load_cell_noise})})
    with tempfile.TemporaryDirectory() as tmp:
        run = Path(tmp) / "run.h5"
        synth.synth(ActionModel(effects=[{cls.name: truth_v}]), blows(), run, seed=seed,
                    duration=0.15, cfg=cfg)
        meas = ms.load(run)
    return cls, truth_v, ft.Data.build(meas, "force", 0.15, None, align_s=5e-4)


@pytest.mark.slow
def test_input_noise_covariance_scales_with_the_input_noise() -> None:
    # the model is driven by the measured force: its noise moves the fitted values. The
    # term is zero for a noise-free force and grows as the noise's variance (linear regime)
    from rig.model.action import ActionModel

    sd = {}
    for scale in (0.0, 1.0, 2.0):
        cls, truth_v, data = _backcheck_case(5, scale)
        add = [cls(**truth_v)]
        labels = [f"{cls.name}.{k}" for k in truth_v]
        targets = [ft.target(ActionModel(), k, add) for k in labels]
        cov = ft.input_noise_cov(ActionModel(), add, targets,
                                 {f"{cls.name}.{k}": v for k, v in truth_v.items()}, data)
        assert cov is not None and cov.shape == (len(labels), len(labels))
        sd[scale] = np.sqrt(np.diag(cov))
    ratio = sd[2.0] / sd[1.0]
    assert np.all(sd[0.0] < 0.05 * sd[1.0]), sd
    # 32 draws: each sd to ~12 %; the friction's response is not quite linear (stick-slip)
    assert np.all((ratio > 1.2) & (ratio < 2.7)) and 1.6 < np.median(ratio) < 2.5, ratio


@pytest.mark.slow
def test_fitted_values_scatter_within_their_stated_uncertainty() -> None:
    # replicates with fresh noise: the back check's stiffness scatters ~3x more than the
    # residual-only (HAC) standard error says, because the noisy force drives the model;
    # with the input-noise term the stated sigma covers the scatter
    from rig.model.action import ActionModel

    est, hac, full = [], [], []
    for seed in range(200, 208):
        cls, truth_v, data = _backcheck_case(seed)
        specs = [f"{cls.name}.{k}" for k in truth_v]
        res0 = ft.fit(ActionModel(), data, specs, [cls], jobs=1, max_nfev=20)
        key = f"{cls.name}.stiffness_scale"
        est.append(res0.values[key])
        hac.append(res0.sigma[key])
        cls2, _, _ = cls, None, None
        extra = ft.input_noise_cov(ActionModel(), [cls2(**{k.split(".", 1)[1]: v for k, v
                                                           in res0.values.items()})],
                                   res0.targets, res0.values, data)
        assert extra is not None
        s, _ = ft.combine_uncertainty(specs, res0.sigma, res0.corr, extra)
        full.append(s[key])
    scatter = float(np.std(est, ddof=1))
    print(f"stiffness_scale: scatter {scatter:.3f}, HAC sigma {np.median(hac):.3f}, "
          f"with the input noise {np.median(full):.3f}")
    assert np.median(hac) < 0.6 * scatter            # the residual-only sigma is too small
    assert 0.6 * scatter < np.median(full) < 2.5 * scatter


@pytest.mark.slow
def test_noise_model_test_holds_its_level_and_keeps_its_power_beside_another_misfit() -> None:
    # held-out noise = white output noise + the model's response to the input's noise
    # (coloured); the test is given that noise model: its level, and its power when the
    # residual also holds a second, unexplained misfit (which the HAC test counts as noise)
    rng = np.random.default_rng(2)
    t = np.arange(N) / 2000
    out_sigma = np.full(N, 0.3)

    def draws(k: int) -> np.ndarray:
        return np.array([0.5 * coloured(rng) for _ in range(k)])

    alarms, reps = 0, 400
    other = 2.0 * np.sin(2 * math.pi * 7 * t)  # another missing effect, fixed
    for _ in range(reps):
        noise = out_sigma * rng.standard_normal(N) + draws(1)[0]
        delta = 0.05 * np.sin(2 * math.pi * 30 * t + rng.uniform(0, 6))  # fitted to noise
        _, p = stats.noise_model_test(other + noise, other + noise - delta, out_sigma,
                                      draws(32))
        alarms += p <= 0.05
    assert alarms / reps <= 0.08, alarms / reps
    found_noise = found_hac = 0
    for _ in range(100):
        noise = out_sigma * rng.standard_normal(N) + draws(1)[0]
        miss = 0.6 * np.sin(2 * math.pi * 30 * t)  # what the candidate explains
        r0, r1 = other + miss + noise, other + noise
        found_noise += stats.noise_model_test(r0, r1, out_sigma, draws(32))[1] <= 0.005
        found_hac += stats.improvement_test(r0, r1, SEG)[1] <= 0.005
    assert found_noise >= 80, found_noise
    print(f"found at p <= 0.005: noise model {found_noise}, HAC {found_hac} of 100")
    assert found_hac < found_noise, (found_hac, found_noise)


def test_weighted_noise_model_test_holds_its_level_and_keeps_a_localized_change() -> None:
    """Weighted residuals (1 / the noise model's SD per sample, as diagnose weighs them):
    on noise alone the two-statistic test holds its level; a change confined to where the
    input noise is large in variance but moves the residual in one shape (a timing-like
    direction), which the weights push down, is found by it as by the unweighted test,
    and more often than by the weighted statistic alone."""
    rng = np.random.default_rng(4)
    t = np.arange(N) / 2000
    out_sigma = np.full(N, 0.3)
    burst = np.exp(-0.5 * ((t - 0.1) / 0.004) ** 2)  # a strike: sharp, 4 ms
    shape = np.gradient(burst, t) * 1e-3  # the input noise shifts it in time

    def draws(k: int) -> np.ndarray:
        return rng.standard_normal((k, 1)) * 10.0 * shape[None, :] + 0.2 * np.array(
            [coloured(rng) for _ in range(k)])

    var = out_sigma ** 2 + 100.0 * shape ** 2 + 0.04  # the weights: 0.23-1
    w = np.sqrt(np.median(var) / var)
    alarms, reps = 0, 400
    for _ in range(reps):
        noise = out_sigma * rng.standard_normal(N) + draws(1)[0]
        delta = 0.05 * np.sin(2 * math.pi * 30 * t + rng.uniform(0, 6))
        _, p = stats.weighted_noise_model_test(w * noise, w * (noise - delta),
                                               w * out_sigma, w * draws(32), w)
        alarms += p <= 0.05
    assert alarms / reps <= 0.08, alarms / reps
    found_both = found_w = 0
    for _ in range(100):
        noise = out_sigma * rng.standard_normal(N) + draws(1)[0]
        miss = 1.25 * burst  # the localized effect: a change of height, not of time
        r0, r1, resp = w * (miss + noise), w * noise, w * draws(32)
        found_both += stats.weighted_noise_model_test(r0, r1, w * out_sigma, resp,
                                                      w)[1] <= 0.005
        found_w += stats.noise_model_test(r0, r1, w * out_sigma, resp)[1] <= 0.005
    print(f"found at p <= 0.005: both statistics {found_both}, weighted alone {found_w}")
    assert found_both >= 60 and found_w <= 0.75 * found_both, (found_both, found_w)


def test_input_noise_mc_test_holds_its_level_when_one_model_filters_the_noise() -> None:
    # two models equally right but for how they pass the input's noise: model 1 low-passes
    # it (a drive of lower bandwidth), so on every realization it fits the noisy data
    # better; that is not evidence against model 0. The linear-projection and HAC tests
    # call it significant; the Monte Carlo test holds its level, and finds a real misfit.
    from scipy.signal import butter, sosfilt

    rng = np.random.default_rng(5)
    t = np.arange(N) / 2000
    sos = butter(2, 40.0, fs=2000.0, output="sos")
    out_sigma = np.full(N, 0.05)

    def response(e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ring = lfilter([1.0], [1, -2 * 0.97 * math.cos(2 * math.pi * 100 / 2000), 0.97 ** 2], e)
        slow = lfilter([1.0], [1, -0.99], e)
        g0 = 0.05 * ring + 0.02 * slow
        return g0, sosfilt(sos, g0)

    def draws(k: int) -> tuple[np.ndarray, np.ndarray]:
        pairs = [response(rng.standard_normal(N)) for _ in range(k)]
        return -np.array([a for a, _ in pairs]), -np.array([b for _, b in pairs])

    alarms = alarms_linear = 0
    reps = 300
    for _ in range(reps):
        g0, g1 = response(rng.standard_normal(N))
        out = out_sigma * rng.standard_normal(N)
        r0, r1 = out - g0, out - g1
        d0, d1 = draws(16)
        alarms += stats.input_noise_mc_test(r0, r1, d0, d1, out_sigma)[1] <= 0.05
        alarms_linear += stats.noise_model_test(r0, r1, out_sigma, d1)[1] <= 0.05
    assert alarms / reps <= 0.08, alarms / reps
    assert alarms_linear / reps > 0.5, alarms_linear / reps   # what the old test said
    found = 0
    for _ in range(100):
        g0, g1 = response(rng.standard_normal(N))
        out = out_sigma * rng.standard_normal(N)
        miss = 0.9 * np.sin(2 * math.pi * 12 * t)  # model 0's real misfit
        d0, d1 = draws(16)
        found += stats.input_noise_mc_test(miss + out - g0, out - g1, d0, d1,
                                           out_sigma)[1] <= 0.05
    print(f"false alarms {alarms / reps:.3f} (linear {alarms_linear / reps:.3f}); "
          f"misfit found {found}/100")
    print(f"found {found}/100")
    assert found >= 80, found


def test_a_round_picks_the_first_needed_newcomer_or_first_refits_the_set(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """``diagnose._pick``: a refused newcomer whose set fits better than the set so far
    makes the round start again from it (while re-fits are left); otherwise the round goes
    on to the next candidate, and the first needed one is chosen."""
    state = dg.State([], np.ones(4), {}, 1.0)
    better_set = dg.Candidate("s", "", {}, {}, {}, 0.0, {}, 0.0, True, train_cost=0.5,
                              test_resid=np.full(4, 0.5))

    def fake(c, *a, **k):  # the first refused (the set fits better), the second needed
        if c.name == "a":
            c.significant = False
            return better_set
        return None

    monkeypatch.setattr(dg, "_without_newcomer", fake)
    ranked = [dg.Candidate(n, "", {}, {}, {}, 0.5, {}, 10.0, True) for n in "ab"]
    best, better = dg._pick(ranked, None, None, {}, None, None, state, 0.01, True)
    assert best is None and better is better_set
    ranked = [dg.Candidate(n, "", {}, {}, {}, 0.5, {}, 10.0, True) for n in "ab"]
    best, better = dg._pick(ranked, None, None, {}, None, None, state, 0.01, False)
    assert best is ranked[1] and better is None
    ranked[1].significant = False
    assert dg._pick(ranked, None, None, {}, None, None, state, 0.01, False) == (None, None)


def test_default_window_ends_at_the_keys_release() -> None:
    from rig.analysis import measurement as ms

    rate = 2000.0
    t = np.arange(0, 2.0, 1 / rate)
    force = np.interp(t, [0, 0.02, 0.1, 0.3, 0.34, 2.0], [0, 0, 30, 30, 0, 0])
    force = force + 0.2 * np.random.default_rng(0).standard_normal(t.size)
    hammer = np.interp(t, [0, 0.05, 0.09, 0.35, 0.45, 2.0], [0, 0, 1.0, 0.8, 0.0, 0.0])
    m = ms.Measurement(t, {"time": t, "force": force, "hammer_angle": hammer},
                       {"force": "N", "hammer_angle": "rad"})
    end, why = ms.blow_window(m)
    # the force falls from 30 N at 0.30 s to 0 at 0.34 s: 5 % of the rise at 0.338 s (the
    # 250 Hz smoothing moves it by a fraction of a millisecond)
    assert end == pytest.approx(0.34 - 0.05 * 0.04, abs=2e-3)
    assert "release at 0.33" in why
    held = ms.Measurement(t, {"time": t, "force": np.interp(t, [0, 0.1, 2.0], [0, 30, 30]),
                              "hammer_angle": hammer}, {"force": "N", "hammer_angle": "rad"})
    assert ms.blow_window(held)[0] == pytest.approx(t[-1])  # never released: whole trial
    # no force channel (a recording driven by the key's motion): the key's release found in
    # its measured motion ends the blow; a release given by a simulation, or none, does not
    moved = ms.Measurement(t, {"time": t, "key_dip": hammer, "hammer_angle": hammer},
                           {"key_dip": "m", "hammer_angle": "rad"}, events={"key_release": 0.4},
                           event_source={"key_release": "found in the measured channels"})
    end, why = ms.blow_window(moved)
    assert end == 0.4 and "release at 0.400 s, found in its measured motion" in why
    moved.event_source = {}
    assert ms.blow_window(moved) == (pytest.approx(t[-1]), "the trial's end (no force channel)")


@pytest.mark.slow
def test_floor_test_holds_its_level_on_a_right_models_residual_and_finds_a_misfit() -> None:
    # a right model's residual: white output noise plus its (coloured, strongly correlated)
    # response to the input's noise, drawn 32 times as diagnose draws it; the test of its
    # mean square against that floor false-alarms at about its level, where a white-noise
    # floor alone (the noise the channels show) would call nearly every right model short
    rng = np.random.default_rng(5)
    t = np.arange(N) / 2000
    out_sigma = np.full(N, 0.3)

    def response() -> np.ndarray:
        return 0.5 * coloured(rng)

    alarms = white_alarms = 0
    reps = 400
    for _ in range(reps):
        r = out_sigma * rng.standard_normal(N) + response()
        floor = stats.noise_floor_draws(out_sigma, np.array([response() for _ in range(32)]),
                                        seed=int(rng.integers(1 << 30)))
        ratio, p = stats.floor_test(r, floor)
        alarms += p <= 0.05
        white_alarms += stats.floor_test(r, stats.noise_floor_draws(out_sigma))[1] <= 0.05
    print(f"floor test: {alarms}/{reps} alarms, white floor {white_alarms}/{reps}")
    assert 0.01 <= alarms / reps <= 0.09, alarms / reps
    assert white_alarms / reps >= 0.9, white_alarms / reps
    found = 0
    for _ in range(100):  # a 30 Hz misfit of twice the floor's mean square beside the noise
        r = out_sigma * rng.standard_normal(N) + response() + 0.85 * np.sin(
            2 * math.pi * 30 * t + rng.uniform(0, 6))
        floor = stats.noise_floor_draws(out_sigma, np.array([response() for _ in range(32)]))
        ratio, p = stats.floor_test(r, floor)
        found += p <= 0.05
    print(f"found {found}/100")
    assert found >= 80, found
    empty = stats.floor_test(np.zeros(0), floor)
    assert math.isnan(empty[0]) and empty[1] == 1.0
    assert stats.floor_test(np.ones(4), np.zeros((3, 4)))[1] == 0.0


def _four_blows(rng: np.random.Generator
                ) -> tuple[np.ndarray, np.ndarray, Callable[[int], np.ndarray]]:
    """Four held-out segments of 0.15 s: the first a blow whose timing the input force's
    noise moves (a strike's time derivative, large), the others quiet (white output noise
    and a little coloured input noise). Returns (time, timing shape, draws(k))."""
    t = np.arange(300) / 2000
    burst = np.exp(-0.5 * ((t - 0.075) / 0.004) ** 2)
    shape = np.gradient(burst, t) * 1e-3

    def draws(k: int) -> np.ndarray:
        d = 0.2 * np.array([coloured(rng, 1200) for _ in range(k)])
        d[:, :300] += rng.standard_normal((k, 1)) * 10.0 * shape[None, :]
        return d

    return t, shape, draws


def test_segment_noise_test_holds_its_level_and_finds_a_change_beside_a_noisy_blow() -> None:
    """Where one held-out segment's variance is mostly the input noise's timing jitter and
    another shows the candidate's change clearly, the segment-weighted test finds it and
    the pooled one mostly does not; at the edge of the null (both models equally far from
    the data in expected mean square) it holds its level as the pooled test does."""
    rng = np.random.default_rng(11)
    t, shape, draws = _four_blows(rng)
    seg, out = [300] * 4, np.full(1200, 0.3)
    alarms, reps = {"segment": 0, "pooled": 0}, 800
    for _ in range(reps):
        noise = out * rng.standard_normal(1200) + draws(1)[0]
        delta = np.zeros(1200)
        delta[:300] = 0.5 * rng.standard_normal() * shape
        delta[300:600] = 0.2 * np.sin(2 * math.pi * 50 * t + rng.uniform(0, 6))
        delta[900:] = 0.3 * np.sin(2 * math.pi * 30 * t + rng.uniform(0, 6))
        r0, r1, resp = noise + delta / 2, noise - delta / 2, draws(32)
        alarms["segment"] += stats.segment_noise_test(r0, r1, out, resp, seg)[1] <= 0.05
        alarms["pooled"] += stats.noise_model_test(r0, r1, out, resp)[1] <= 0.05
    assert alarms["segment"] / reps <= 0.075, alarms
    found = {"segment": 0, "pooled": 0}
    for _ in range(100):
        noise = out * rng.standard_normal(1200) + draws(1)[0]
        miss = np.zeros(1200)  # the shank's ringing on the quiet blow's strain
        miss[900:] = 0.5 * np.sin(2 * math.pi * 240 * t) * np.exp(-t / 0.05)
        delta = miss.copy()
        delta[:300] = 0.5 * rng.choice([-1.0, 1.0]) * shape  # it also moves the noisy blow
        r0, resp = noise + miss, draws(32)
        found["segment"] += stats.segment_noise_test(r0, r0 - delta, out, resp, seg)[1] <= 0.005
        found["pooled"] += stats.noise_model_test(r0, r0 - delta, out, resp)[1] <= 0.005
    print(f"false alarms at 0.05 of {reps}: {alarms}; found at p <= 0.005 of 100: {found}")
    assert found["segment"] >= 80 and found["pooled"] <= 40, found
