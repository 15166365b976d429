"""Aggregate statistics over seeds/runs: mean ± std and the interquartile mean with a bootstrap 95% CI.

IQM (the mean of the middle 50%) with percentile-bootstrap confidence intervals is the rliable recommendation
(Agarwal et al., 2021) for few-seed RL results; ``scipy.stats`` provides both pieces.
"""

from __future__ import annotations

import numpy as np
from scipy import stats


def iqm(x, axis=-1) -> np.ndarray:
    """Interquartile mean: the 25%-trimmed mean."""
    return stats.trim_mean(np.asarray(x, np.float64), 0.25, axis=axis)


def iqm_ci(x, confidence: float = 0.95, n_resamples: int = 2000, seed: int = 0) -> tuple[float, float, float]:
    """(IQM, low, high) with a percentile bootstrap over the values; NaNs (diverged runs) are dropped first."""
    return bootstrap_ci(x, iqm, confidence, n_resamples, seed)


def mean_ci(x, confidence: float = 0.95, n_resamples: int = 2000, seed: int = 0) -> tuple[float, float, float]:
    """(mean, low, high) with a percentile bootstrap over the values (evaluation episodes); NaNs dropped first."""
    return bootstrap_ci(x, np.mean, confidence, n_resamples, seed)


def bootstrap_ci(x, statistic, confidence: float, n_resamples: int, seed: int) -> tuple[float, float, float]:
    """(statistic, low, high): ``statistic(values, axis)`` of the finite values and its percentile-bootstrap CI."""
    x = np.asarray(x, np.float64)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return float("nan"), float("nan"), float("nan")
    point = float(statistic(x, axis=-1))
    if x.size == 1 or np.all(x == x[0]):
        return point, point, point
    res = stats.bootstrap((x,), statistic, confidence_level=confidence, n_resamples=n_resamples, method="percentile",
                          random_state=np.random.default_rng(seed), vectorized=True, axis=-1)
    return point, float(res.confidence_interval.low), float(res.confidence_interval.high)


def summarize(values) -> dict[str, float]:
    """mean, std, min, max, IQM and its 95% CI of finite values, plus how many were not finite."""
    x = np.asarray(values, np.float64)
    finite = x[np.isfinite(x)]
    m, lo, hi = iqm_ci(finite)
    nan = float("nan")
    return {
        "mean": float(finite.mean()) if finite.size else nan,
        "std": float(finite.std()) if finite.size else nan,
        "min": float(finite.min()) if finite.size else nan,
        "max": float(finite.max()) if finite.size else nan,
        "iqm": m, "iqm_low": lo, "iqm_high": hi,
        "n": int(x.size), "n_nonfinite": int(x.size - finite.size),
    }
