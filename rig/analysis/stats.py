"""Statistics for autocorrelated residuals (2 kHz samples are far from independent).

Both the parameter uncertainties of a fit and the significance of a held-out
improvement (``improvement_test``) use heteroskedasticity-and-autocorrelation-consistent (HAC,
Newey-West) estimates: sums of lagged products within each contiguous segment
(one trial's channel), with Bartlett weights ``1 - l / (L + 1)`` up to a
bandwidth ``L`` read from the data's own autocorrelation (the last lag, up to a
quarter of the shortest segment, at which it still exceeds ``ACF_FLOOR``). With
so long a bandwidth the variance estimate is itself uncertain and biased low;
intervals and the test use fixed-b critical values (``fixed_b_factor``) so that a
stated 95 % interval covers and a 5 % test false-alarms at about those rates
(tests/test_stats.py checks both on coloured noise).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

ACF_FLOOR = 0.05
MIN_LAG = 5


def _split(x: np.ndarray, segments: Sequence[int]) -> list[np.ndarray]:
    if sum(segments) != len(x):
        segments = [len(x)]
    return [p for p in np.split(x, np.cumsum(segments)[:-1]) if len(p)]


def bandwidth(x: np.ndarray, segments: Sequence[int]) -> int:
    """Bartlett bandwidth (in samples) for the series ``x`` made of these segments."""
    parts = _split(np.asarray(x, float), segments)
    shortest = min(len(p) for p in parts)
    lmax = max(1, shortest // 4)
    parts = [p - p.mean() for p in parts]
    g0 = sum(float(p @ p) for p in parts)
    if g0 <= 0:
        return MIN_LAG if lmax >= MIN_LAG else lmax
    last = 0
    for lag in range(1, lmax + 1):
        acf = sum(float(p[:-lag] @ p[lag:]) for p in parts) / g0
        if abs(acf) > ACF_FLOOR:
            last = lag
    return min(lmax, max(MIN_LAG, last))


def fixed_b_factor(lag: int, segments: Sequence[int]) -> float:
    """How much wider than the normal 1.96 a 95 % interval from a Bartlett HAC estimate
    must be when the bandwidth is a sizeable share ``b = (lag + 1) / T`` of each segment
    (fixed-b asymptotics, Kiefer & Vogelsang 2005, their cubic fit of the Bartlett critical
    values): the variance estimate itself is then uncertain and biased low."""
    t = float(np.mean([s for s in segments if s > 0])) if segments else 1.0
    b = min(1.0, (lag + 1) / max(t, 1.0))
    return (1.96 + 2.9694 * b + 0.4160 * b ** 2 - 0.5324 * b ** 3) / 1.96


def long_run_cov(s: np.ndarray, segments: Sequence[int], lag: int) -> np.ndarray:
    """Newey-West sum over samples of the (n, p) scores ``s`` (not divided by n)."""
    parts = _split(s, segments)
    out = sum(p.T @ p for p in parts)
    for k in range(1, lag + 1):
        w = 1 - k / (lag + 1)
        g = sum((p[:-k].T @ p[k:]) for p in parts if len(p) > k)
        if isinstance(g, np.ndarray):
            out = out + w * (g + g.T)
    return np.asarray(out, float)


def improvement_test(r0: np.ndarray, r1: np.ndarray, segments: Sequence[int]
                     ) -> tuple[float, float]:
    """One-sided test that residuals ``r1`` are smaller in mean square than ``r0`` on the
    same held-out samples: (z, p).

    With ``delta = r0 - r1`` (the change of prediction, fixed by the training data),
    ``r0^2 - r1^2 = delta^2 + 2 r1 delta``: the only part that varies with the held-out
    data's noise is ``2 r1 delta``, and the variance of its mean is taken from its HAC
    long-run variance (Diebold-Mariano, conditional on the fitted change)."""
    r0, r1 = np.asarray(r0, float), np.asarray(r1, float)
    if r0.shape != r1.shape or r0.size < 4:
        return 0.0, 1.0
    delta = r0 - r1
    return mean_test(r0 ** 2 - r1 ** 2, segments, 2 * r1 * delta)


def noise_model_test(r0: np.ndarray, r1: np.ndarray, out_sigma: np.ndarray,
                     input_responses: np.ndarray | None = None) -> tuple[float, float]:
    """One-sided test that residuals ``r1`` are smaller in mean square than ``r0`` on the
    same held-out samples, with the variance from a noise model rather than from the
    residuals: (z, p).

    ``r0^2 - r1^2 = delta^2 + 2 n delta + (fixed)`` with ``delta = r0 - r1`` fixed by the
    training data and ``n`` the held-out data's noise: white output noise of level
    ``out_sigma`` per sample, plus the model's response to the input force's noise, given
    as draws (rows of ``input_responses``, e.g. ``fit.input_noise_responses``). What the
    residuals hold besides noise -- another missing effect's misfit -- is fixed, not noise:
    the HAC test (``improvement_test``) counts it as noise and loses power to it."""
    r0, r1 = np.asarray(r0, float), np.asarray(r1, float)
    if r0.shape != r1.shape or r0.size < 4:
        return 0.0, 1.0
    delta = r0 - r1
    n = r0.size
    stat = float(np.mean(r0 ** 2 - r1 ** 2))
    var = 4.0 * float(np.sum(delta ** 2 * np.asarray(out_sigma, float) ** 2)) / n ** 2
    if input_responses is not None and len(input_responses) >= 2:
        proj = 2.0 * (np.asarray(input_responses, float) @ delta) / n
        var += float(np.var(proj, ddof=1))
    if not var > 0:
        return 0.0, 1.0
    z = stat / math.sqrt(var)
    return z, 0.5 * math.erfc(z / math.sqrt(2))


def segment_noise_test(r0: np.ndarray, r1: np.ndarray, out_sigma: np.ndarray,
                       input_responses: np.ndarray | None, segments: Sequence[int]
                       ) -> tuple[float, float]:
    """``noise_model_test`` with each segment (a held-out trial's channel) weighed by the
    evidence it can hold: (z, p).

    Per segment ``i`` the statistic ``S_i = sum(r0^2 - r1^2)`` has the expected gain
    ``D_i = sum(delta^2)`` if ``r1``'s model is right, and the noise variance ``V_i``
    (white output noise plus the input force's noise through the model, as in
    ``noise_model_test``); ``sum w_i S_i`` with ``w_i = D_i / V_i`` is the linear
    combination with the most power for that gain (a matched filter over segments). One
    noisy segment no longer swamps the rest: a held-out piano blow whose hammer timing the
    force's noise moves by milliseconds held most of the plain statistic's variance, while
    the shank's strain on the same blow showed the candidate's oscillation at 49 times its
    own noise (wide benchmark, development seed 145: plain p = 0.013).

    ``delta = r0 - r1`` is fixed by the training data and the variances come from the
    noise model's draws, so the weights hold no held-out noise. The weights and the
    variance of the weighted sum come from the same draws: weights chosen where the draws
    happen to look quiet shrink the variance they are judged by, but only by
    ``E[V / V_hat]``, 1.07 for 32 draws (3 % on z); taking them from disjoint halves
    instead leaves 16 draws for the variance, a t-distribution of 15 degrees of freedom
    that doubles the false alarms at the diagnose's levels (about 0.006). Falls back to
    ``noise_model_test`` when there are fewer than two segments or fewer than four
    draws."""
    r0, r1 = np.asarray(r0, float), np.asarray(r1, float)
    seg = [int(s) for s in segments]
    resp = None if input_responses is None else np.asarray(input_responses, float)
    if r0.shape != r1.shape or r0.size < 4 or len(seg) < 2 or sum(seg) != r0.size \
            or resp is None or resp.ndim != 2 or resp.shape[0] < 4 \
            or resp.shape[1] != r0.size:
        return noise_model_test(r0, r1, out_sigma, input_responses)
    delta = r0 - r1
    sig2 = np.broadcast_to(np.asarray(out_sigma, float) ** 2, r0.shape)
    edges = np.cumsum([0, *seg])
    idx = np.repeat(np.arange(len(seg)), seg)
    gain = np.bincount(idx, r0 ** 2 - r1 ** 2, len(seg))
    expect = np.bincount(idx, delta ** 2, len(seg))
    v_out = 4.0 * np.bincount(idx, delta ** 2 * sig2, len(seg))
    proj = 2.0 * np.stack([resp[:, a:b] @ delta[a:b] for a, b in zip(edges[:-1], edges[1:],
                                                                      strict=True)], axis=1)
    v_seg = v_out + np.var(proj, axis=0, ddof=1)
    w = np.divide(expect, v_seg, out=np.zeros_like(expect), where=v_seg > 0)
    if not np.any(w > 0):
        return noise_model_test(r0, r1, out_sigma, input_responses)
    w = w / w.max()
    var = float(np.sum(w ** 2 * v_out)) + float(np.var(proj @ w, ddof=1))
    if not var > 0:
        return 0.0, 1.0
    z = float(w @ gain) / math.sqrt(var)
    return z, 0.5 * math.erfc(z / math.sqrt(2))


def weighted_noise_model_test(r0: np.ndarray, r1: np.ndarray, out_sigma: np.ndarray,
                              input_responses: np.ndarray | None, weights: np.ndarray
                              ) -> tuple[float, float]:
    """``noise_model_test`` on residuals weighed per sample (``r0``, ``r1``, ``out_sigma``
    and the rows of ``input_responses`` all times ``weights``), taken twice, as given and
    with the weights divided out, and the smaller p doubled (Bonferroni over the two
    statistics, so that on noise alone the level holds whatever the two's dependence):
    (the z of the smaller p, that p doubled, at most 1).

    A diagonal weighting, 1 / the noise model's SD per sample, takes the noise as
    independent from sample to sample; the force's noise moves a blow's prediction in a
    few correlated directions (mostly in time), so where it is large in variance (the
    strike, the catch) it hides a change of another shape less than the weight says: a
    short, localized effect there loses the power of the samples that show it. The
    unweighted statistic keeps it; the weighted one keeps the power that samples swamped by
    noise (a long window's return) would take from the unweighted one."""
    w = np.asarray(weights, float)
    z_w, p_w = noise_model_test(r0, r1, out_sigma, input_responses)
    if w.shape != np.shape(r0) or not np.all(w > 0):
        return z_w, p_w
    resp = None if input_responses is None else np.asarray(input_responses, float) / w
    z_1, p_1 = noise_model_test(np.asarray(r0, float) / w, np.asarray(r1, float) / w,
                                np.asarray(out_sigma, float) / w, resp)
    z, p = (z_w, p_w) if p_w <= p_1 else (z_1, p_1)
    return z, min(1.0, 2.0 * p)


def input_noise_mc_test(r0: np.ndarray, r1: np.ndarray, responses0: np.ndarray,
                        responses1: np.ndarray, out_sigma: np.ndarray | None = None
                        ) -> tuple[float, float]:
    """One-sided test that model 1's residuals ``r1`` are smaller in mean square than model
    0's ``r0`` on the same held-out samples once the input force's noise is accounted for,
    when the two models pass that noise differently (a low-pass or a delay in one of them):
    (z, p).

    ``responses0``/``responses1`` are each model's response to the same draws of fresh
    input noise (rows; ``fit.input_noise_responses`` with one seed). Each draw gives the
    statistic ``d_k = ms(r0 + R0_k) - ms(r1 + R1_k)`` with one more unit of the noise; the
    observed ``d = ms(r0) - ms(r1)`` holds one unit (the data's own), so ``mean(d_k) - d``
    estimates what the noise alone adds to ``d`` (a model that filters it more fits the
    noisy force better for that alone), subtracted as in SIMEX, and ``var(d_k)`` is the
    spread the noise gives ``d`` -- the quadratic part too, which ``noise_model_test``'s
    linear projection leaves out. White output noise of level ``out_sigma`` adds
    ``4 sum(delta^2 sigma^2) / n^2``. Needs at least 2 draws; (0, 1) otherwise."""
    r0, r1 = np.asarray(r0, float), np.asarray(r1, float)
    R0, R1 = np.asarray(responses0, float), np.asarray(responses1, float)
    if (r0.shape != r1.shape or r0.size < 4 or R0.ndim != 2 or R0.shape != R1.shape
            or R0.shape[0] < 2 or R0.shape[1] != r0.size):
        return 0.0, 1.0
    d = float(np.mean(r0 ** 2) - np.mean(r1 ** 2))
    dk = np.mean((r0[None, :] + R0) ** 2, axis=1) - np.mean((r1[None, :] + R1) ** 2, axis=1)
    var = float(np.var(dk, ddof=1))
    if out_sigma is not None:
        var += 4.0 * float(np.sum((r0 - r1) ** 2 * np.asarray(out_sigma, float) ** 2)) \
            / r0.size ** 2
    if not var > 0:
        return 0.0, 1.0
    z = (d - (float(np.mean(dk)) - d)) / math.sqrt(var)
    return z, 0.5 * math.erfc(z / math.sqrt(2))


FLOOR_DRAWS = 64  # draws of white output noise alone (noise_floor_draws)


def noise_floor_draws(out_sigma: np.ndarray, input_responses: np.ndarray | None = None,
                      *, seed: int = 0) -> np.ndarray:
    """Draws of what a residual holds when the model is right: white output noise of level
    ``out_sigma`` per sample, plus (when given) the model's response to the input force's
    noise, one row of ``input_responses`` per draw (``FLOOR_DRAWS`` draws without them).
    A (draws, n) array."""
    sig = np.asarray(out_sigma, float)
    resp = None if input_responses is None or not len(input_responses) else \
        np.asarray(input_responses, float)
    draws = len(resp) if resp is not None else FLOOR_DRAWS
    out = sig[None, :] * np.random.default_rng(seed).standard_normal((draws, sig.size))
    return out + resp if resp is not None else out


def floor_test(r: np.ndarray, floor: np.ndarray) -> tuple[float, float]:
    """One-sided test that residuals ``r`` hold more than noise: (ratio, p), ``ratio`` the
    mean square of ``r`` over the noise floor's (the mean over the rows of ``floor``, e.g.
    ``noise_floor_draws``), ``p`` the chance that noise alone reaches it.

    Under the null ``r`` is Gaussian noise, so its mean square is a quadratic form: a
    weighted sum of chi-squares, taken as a scaled chi-square with the draws' mean and
    variance (Satterthwaite 1946; the correlated input-noise response makes it far wider
    than white noise's, and skewed). (inf, 0) for a non-empty residual over a zero floor;
    (nan, 1) for an empty one."""
    from scipy.stats import chi2

    r = np.asarray(r, float)
    if r.size == 0:
        return math.nan, 1.0
    t = float(np.mean(r ** 2))
    m_k = np.mean(np.asarray(floor, float) ** 2, axis=1)
    m, v = float(np.mean(m_k)), float(np.var(m_k, ddof=1)) if len(m_k) > 1 else 0.0
    if not m > 0:
        return (math.inf, 0.0) if t > 0 else (math.nan, 1.0)
    if not v > 0:
        return t / m, (0.0 if t > m else 1.0)
    g, h = v / (2.0 * m), 2.0 * m * m / v
    return t / m, float(chi2.sf(t / g, h))


def mean_test(d: np.ndarray, segments: Sequence[int], noise: np.ndarray | None = None
              ) -> tuple[float, float]:
    """One-sided test that the mean of ``d`` is > 0 with a HAC variance of the mean of
    ``noise`` (default ``d`` itself: Diebold-Mariano): (z, p)."""
    d = np.asarray(d, float)
    if d.size < 4:
        return 0.0, 1.0
    x = d if noise is None else np.asarray(noise, float)
    parts = _split(x - x.mean(), segments)
    lag = bandwidth(x, segments)
    s = long_run_cov(np.concatenate(parts)[:, None], [len(p) for p in parts], lag)
    var = float(s[0, 0]) / d.size ** 2
    if not var > 0:
        return 0.0, 1.0
    z = float(d.mean()) / math.sqrt(var) / fixed_b_factor(lag, [len(p) for p in parts])
    return z, 0.5 * math.erfc(z / math.sqrt(2))


def sandwich_cov(J: np.ndarray, r: np.ndarray, segments: Sequence[int]) -> np.ndarray:
    """HAC covariance of least-squares parameters: (J'J)^-1 S (J'J)^-1 with S the
    Newey-West long-run covariance of the scores J_t r_t."""
    n, p = J.shape
    bread = np.linalg.pinv(J.T @ J)
    lag = bandwidth(r, segments)
    meat = long_run_cov(J * r[:, None], segments, lag)
    scale = n / max(n - p, 1) * fixed_b_factor(lag, segments) ** 2
    return np.asarray(bread @ meat @ bread * scale, float)


def round_to(v: float, s: float) -> float:
    """``v`` rounded to two significant digits of its uncertainty ``s``, keeping at least
    three of its own: an uncertainty larger than the value (a parameter the data hardly
    see) must not round it to 0 or across the bound it was fitted within (a drive's
    bandwidth of 41.3 +- 500 Hz is written 41.3, not 0)."""
    if not (math.isfinite(v) and math.isfinite(s) and s > 0):
        return float(f"{v:.4g}") if math.isfinite(v) else v
    dec = 1 - math.floor(math.log10(s))
    if v != 0:
        dec = max(dec, 2 - math.floor(math.log10(abs(v))))
    return float(round(v, dec))


def short(v: float, digits: int = 3) -> str:
    """``v`` to ``digits`` significant digits for a sentence: plain decimals from 1e-3 to
    1e5 (1000, not 1e+03), powers of ten outside, and 0 below 1e-12 (a bound at zero
    reached up to the optimizer's rounding, not 3e-13)."""
    if not math.isfinite(v):
        return "not determined"
    a = abs(v)
    if a < 1e-12:
        return "0"
    if 1e-3 <= a < 1e5:
        return f"{v:.{max(0, digits - 1 - math.floor(math.log10(a)))}f}"
    return f"{v:.{digits}g}"


def fmt(v: float, s: float, units: str = "") -> str:
    """``v +- s units`` with v rounded to two digits of s; dimensionless shows no unit."""
    u = "" if units in ("", "1") else f" {units}"
    if not math.isfinite(v):
        return "not determined"
    if not (math.isfinite(s) and s > 0):
        return f"{v:.4g}{u} (uncertainty not determined)"
    big = max(abs(v), s)
    e = math.floor(math.log10(big)) if big > 0 else 0
    if e >= 5 or e <= -4:  # scientific, common exponent
        scale = 10.0 ** e
        dec = max(0, 1 - math.floor(math.log10(s / scale)))
        return f"({v / scale:.{dec}f} +- {s / scale:.{dec}f})e{e}{u}"
    dec = 1 - math.floor(math.log10(s))
    d = max(0, dec)
    return f"{round(v, dec):.{d}f} +- {round(s, dec):.{d}f}{u}"
