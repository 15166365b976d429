"""proto_brax.analysis.crosscheck (benchmarks/adroit_check.py, gym_v5_check.py): the comparisons of two
trajectories and of two samples of returns, on hand-made numbers."""

from __future__ import annotations

import numpy as np
import pytest

from proto_brax.analysis import crosscheck


def test_xml_kwargs_keep_the_envs_defaults_unless_given_and_zero_means_unbounded():
    assert crosscheck.xml_kwargs(None, None) == {}
    assert crosscheck.xml_kwargs(8, 16) == {"max_geom_pairs": 8, "max_contact_points": 16}
    assert crosscheck.xml_kwargs(None, 0) == {"max_contact_points": None}


def test_compare_reports_the_largest_differences_overall_and_early_and_the_motions_scale():
    obs_a, obs_b = np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0]]), np.array([[0.0, 0.0], [1.0, 1.5], [2.0, 4.0]])
    qpos_a, qpos_b = np.array([[0.0], [1.0], [3.0]]), np.array([[0.0], [1.25], [2.0]])
    c = crosscheck.compare((obs_a, np.array([1.0, 2.0]), qpos_a), (obs_b, np.array([1.0, 1.0]), qpos_b), early=1)
    assert c == {"max_abs_obs": 2.0, "max_abs_qpos": 1.0, "max_abs_reward": 1.0, "max_abs_obs_first1": 0.5,
                 "max_abs_qpos_first1": 0.25, "return_a": 3.0, "return_b": 2.0, "qpos_excursion": 2.0}


def test_first_above_counts_steps_from_one():
    err = np.array([0.0, 0.002, 0.5, 0.0])
    assert crosscheck.first_above(err, 1e-3) == 2 and crosscheck.first_above(err, 1e-1) == 3
    assert crosscheck.first_above(err, 1.0) is None


def test_returns_summary_and_welch_comparison():
    s = crosscheck.summary([1.0, 2.0, 3.0, 4.0])
    se = (5.0 / 3.0) ** 0.5 / 2.0  # sample std sqrt(5/3) over sqrt(4)
    assert s["n"] == 4 and s["mean"] == 2.5 and s["std"] == pytest.approx(2 * se) and s["se"] == pytest.approx(se)
    assert s["ci95"] == pytest.approx([2.5 - 1.96 * se, 2.5 + 1.96 * se])
    c = crosscheck.returns_comparison({"mean": 10.0, "se": 3.0}, {"mean": 6.0, "se": 4.0})
    assert c == {"diff": 4.0, "diff_se": 5.0, "z": 0.8, "within_ci95": True}
    c = crosscheck.returns_comparison({"mean": 20.0, "se": 3.0}, {"mean": 6.0, "se": 4.0})
    assert c["z"] == pytest.approx(2.8) and c["within_ci95"] is False
    assert crosscheck.returns_comparison({"mean": 1.0, "se": 0.0}, {"mean": 1.0, "se": 0.0})["z"] == 0.0
