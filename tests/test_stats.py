"""The aggregate statistics against hand-computed values."""

from __future__ import annotations

import numpy as np

from proto_brax.analysis.stats import iqm, iqm_ci, mean_ci, summarize


def test_iqm_is_the_mean_of_the_middle_half():
    x = np.array([100.0, 1, 7, 3, 2, 5, 4, 6, 8, -50, 9, 0])  # sorted: -50 0 1 | 2 3 4 5 6 7 | 8 9 100
    assert iqm(x) == np.mean([2, 3, 4, 5, 6, 7])


def test_bootstrap_intervals_hold_the_point_and_drop_nans():
    rng = np.random.default_rng(0)
    x = np.concatenate([rng.normal(10.0, 2.0, 200), [np.nan]])
    m, lo, hi = mean_ci(x)
    assert m == np.nanmean(x) and lo < m < hi
    assert 0.2 < hi - lo < 0.8  # ≈ 2 · 1.96 · 2/√200 = 0.55
    q, qlo, qhi = iqm_ci(x)
    assert q == iqm(x[:-1]) and qlo < q < qhi
    assert mean_ci([3.0, 3.0]) == (3.0, 3.0, 3.0) and np.isnan(mean_ci([np.nan])[0])
    s = summarize([1.0, np.nan, 3.0])
    assert s["mean"] == 2.0 and s["n"] == 3 and s["n_nonfinite"] == 1
