"""proto_brax.analysis.throughput (benchmarks/throughput.py): the FLOP accounting, the goals' verdicts and the
summary table, on hand-made numbers."""

from __future__ import annotations

import math

import pytest

from proto_brax.analysis import throughput as tp


def test_gflops_prefers_the_single_update_program_and_falls_back_to_the_scan_over_n():
    # The scan counted 5 MFLOP for 100 updates of 4 MFLOP each: its loop body was counted once.
    g = tp.gflops(f_single=4e6, f_scan=5e6, sac_f_single=2e6, n_updates=100, scan_seconds=0.5)
    assert g["flops_per_update_used"] == 4e6 and g["flops_source"] == "single-update program"
    assert g["flops_scan_program_div_n"] == 5e4 and g["scan_vs_single_flops_ratio"] == pytest.approx(0.0125)
    assert g["proto_vs_sac_flops_ratio"] == 2.0 and g["scan_counted_once"] is True
    assert g["achieved_gflops"] == pytest.approx(0.8)  # 4e6 FLOP per 5 ms
    g = tp.gflops(f_single=None, f_scan=3e8, sac_f_single=1e6, n_updates=100, scan_seconds=2.0)
    assert g["flops_per_update_used"] == 3e6 and g["flops_source"] == "scan program / N"
    assert g["scan_vs_single_flops_ratio"] is None and g["proto_vs_sac_flops_ratio"] is None
    assert g["scan_counted_once"] is False and g["achieved_gflops"] == pytest.approx(0.15)  # 3e6 FLOP per 20 ms
    g = tp.gflops(f_single=None, f_scan=None, sac_f_single=None, n_updates=100, scan_seconds=2.0)
    assert g["flops_per_update_used"] is None and g["achieved_gflops"] is None and g["flops_scan_program_div_n"] is None


def results(ratio1=1.05, ratio2=0.5, flops=4e6, achieved=12.34):
    """The fields of the four measurements that the goals and the summary read."""
    cpu = {"process_cpu_per_wall": [1.0, 1.5, 1.2]}
    return {
        "1_proto_vs_sac": {"proto": {**cpu, "updates_per_s": 120.04}, "sac": {**cpu, "updates_per_s": 131.16},
                           "proto_vs_sac_time_ratio": ratio1},
        "2_gflops": {"flops_per_update_used": flops, "achieved_gflops": achieved,
                     "achieved_vs_matmul_gflops_ratio": ratio2,
                     "matmul": {"process_cpu_per_wall": [2.0, 1.9], "gflops": 24.68}},
        "3_grid_scaling": {"single": {**cpu, "updates_per_s": 100.0},
                           "grid_1_device": {**cpu, "updates_per_s_total": 130.0},
                           "grid_sharded": {**cpu, "updates_per_s_total": 150.0, "devices": ["cpu:0", "cpu:1"]},
                           "grid_vmap_1dev_vs_single_ratio": 1.3, "grid_vmap_sharded_vs_single_ratio": float("nan")},
        "4_online_step_vs_update": {"update_alone": {**cpu, "updates_per_s": 110.0},
                                    "online_step_vs_update_time_ratio": 1.15},
    }


def test_goals_compare_each_ratio_with_its_threshold():
    goals = tp.goals_of(results())
    assert list(goals) == list(tp.GOALS)
    assert goals["proto_vs_sac_time_ratio"] == {"value": 1.05, "op": "<=", "goal": 1.10, "verdict": "PASS"}
    assert goals["achieved_vs_matmul_gflops_ratio"]["verdict"] == "FAIL"  # 0.5 < 0.6
    assert goals["grid_vmap_1dev_vs_single_ratio"]["verdict"] == "PASS"  # 1.3 >= 1.2
    assert goals["grid_vmap_sharded_vs_single_ratio"]["verdict"] == "n/a"  # NaN: not measured
    assert goals["online_step_vs_update_time_ratio"]["verdict"] == "PASS"  # on the bound
    assert tp.verdict("proto_vs_sac_time_ratio", 1.2) == "FAIL" and tp.verdict("proto_vs_sac_time_ratio", None) == "n/a"
    assert tp.verdict("grid_vmap_sharded_vs_single_ratio", math.inf) == "n/a"


def test_summary_rows_format_the_measurements_and_say_na_where_xla_counted_nothing():
    r = results()
    rows = tp.summary_rows(r, tp.goals_of(r), tp.QUICK)
    assert len(rows) == 14
    assert rows[0] == ("1  PROTO-SAC updates/s (halfcheetah)", "120.0", "", "")
    assert rows[2] == ("1  time PROTO / time SAC", "1.050", "<= 1.10", "PASS")
    assert rows[3] == ("2  MFLOP per PROTO update (XLA)", "4.0", "", "")
    assert rows[5] == ("2  matmul GFLOP/s (512^3 x 4)", "24.7", "", "")
    assert rows[6] == ("2  achieved / matmul", "0.500", ">= 0.6", "FAIL")
    assert rows[9] == ("3c grid 4 sharded 2 dev, total updates/s", "150.0", "", "")
    assert rows[11] == ("3c grid(sharded) / single", "nan", ">= 1.5", "n/a")
    assert rows[13] == ("4  s/env step / s/update", "1.150", "<= 1.15", "PASS")
    r = results(ratio2=None, flops=None, achieved=None)
    rows = tp.summary_rows(r, tp.goals_of(r), tp.QUICK)
    assert [row[1] for row in rows[3:5]] + [rows[6][1]] == ["n/a", "n/a", "n/a"]
    assert tp.cpu_per_wall(r) == "PROTO 1.20, SAC 1.20, matmul 1.95, 3a 1.20, 3b 1.20, 3c 1.20, 4 1.20"
