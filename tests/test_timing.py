"""proto_brax.analysis.timing: the cost benchmarks' interleaved timing."""

from __future__ import annotations

import jax.numpy as jnp
import pytest

from proto_brax.analysis import timing


def test_run_interleaved_alternates_the_programs_and_reports_medians_per_unit():
    calls = []

    def program(name, work):
        def step(state):
            calls.append(name)
            return state + 1, jnp.zeros(())
        return timing.Case(name, step, jnp.zeros(()), units=work, compile_s=0.0)

    a, b = program("a", 10.0), program("b", 1000.0)
    timing.run_interleaved([a, b], reps=3, warmup=1)
    assert calls == ["a", "b"] * 4  # one warm-up round, then a b a b a b: drift hits both alike
    assert len(a.times) == len(a.cpu_util) == 3 and int(a.state) == int(b.state) == 4
    a.times, b.times = [2.0, 1.0, 4.0], [1.0, 5.0, 2.0]
    assert (a.median, a.rate, b.rate) == (2.0, 5.0, 500.0)
    assert a.record()["units_per_s"] == 5.0 and a.record()["times_s"] == [2.0, 1.0, 4.0]


def test_aot_compiles_once_and_flops_counts_a_matmul():
    compiled, seconds = timing.aot(lambda x, y: x @ y, jnp.ones((8, 16)), jnp.ones((16, 4)))
    assert seconds > 0 and compiled(jnp.ones((8, 16)), jnp.ones((16, 4))).shape == (8, 4)
    assert timing.flops_of(compiled) == pytest.approx(2 * 8 * 16 * 4, rel=0.1)


def test_steady_rate_counts_from_the_first_mark_to_the_last():
    """peer_brax_sac's rate: (env steps, wall time) marks; the interval between the first and the last only."""
    from proto_brax.analysis.timing import steady_rate

    assert steady_rate([(1000, 10.0), (6000, 30.0), (11000, 40.0)]) == 10000 / 30.0
    assert steady_rate([(6000, 30.0), (11000, 40.0)]) == 500.0
