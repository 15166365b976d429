"""Resumable segmented builds (proto_brax.data.partial): an interrupted build resumes bit for bit."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from proto_brax.data.dataset import Transition
from proto_brax.data.partial import discard, run_segments

COUNT, ENVS, STEPS = 5, 3, 4
KEY = jax.random.PRNGKey(7)


@jax.jit
def _walk(key, state):
    """A cheap stand-in for an env rollout segment: a random walk with an episode counter in a nested state."""
    def body(s, k):
        pos = s["pos"] + jax.random.normal(k, s["pos"].shape)
        done = jnp.abs(pos[:, 0]) > 2.0
        tr = Transition(s["pos"], pos[:, :1], done.astype(jnp.float32), pos, done.astype(jnp.float32),
                        jnp.zeros_like(pos[:, 0]))
        return {"pos": jnp.where(done[:, None], 0.0, pos), "episodes": s["episodes"] + done}, tr

    state, tr = jax.lax.scan(body, state, jax.random.split(key, STEPS))
    return tr, state


def _init():
    return {"pos": jnp.zeros((ENVS, 2)), "episodes": jnp.zeros(ENVS, jnp.int32)}


class Stop(Exception):
    pass


def _segment(calls, stop_at=None):
    def segment(i, state):
        if i == stop_at:
            raise Stop  # the process is killed between segments
        if not isinstance(state["pos"], jax.core.Tracer):  # not the structure-only trace of a fully resumed build
            calls.append(i)
        return _walk(jax.random.fold_in(KEY, i + 1), state)
    return segment


def _build(checkpoint=None, fingerprint=None, stop_at=None):
    calls, ticks = [], []
    tr = run_segments(COUNT, _init, _segment(calls, stop_at), checkpoint, fingerprint, tick=lambda: ticks.append(1))
    return tr, calls, len(ticks)


def test_interrupted_build_resumes_bit_for_bit(tmp_path):
    want, calls, ticks = _build()
    assert calls == list(range(COUNT)) and ticks == COUNT and want.observations.shape == (COUNT * STEPS, ENVS, 2)
    ck, fp = tmp_path / ".x.npz.partial", {"name": "x", "size": (3, 4)}
    with pytest.raises(Stop):
        _build(ck, fp, stop_at=3)
    assert json.loads((ck / "fingerprint.json").read_text()) == {"name": "x", "size": [3, 4]}
    assert sorted(p.name for p in ck.glob("seg-*.npz")) == ["seg-000000.npz", "seg-000001.npz", "seg-000002.npz"]
    got, calls, ticks = _build(ck, fp)  # the same build again: only the missing segments run
    assert calls == [3, 4] and ticks == COUNT
    jax.tree.map(np.testing.assert_array_equal, got, want)
    # everything saved but the dataset not yet written (killed after the last segment): nothing runs again
    got, calls, _ = _build(ck, fp)
    assert calls == [] and isinstance(got, Transition)
    jax.tree.map(np.testing.assert_array_equal, got, want)
    discard(ck)
    assert not ck.exists()


def test_another_build_or_a_corrupt_checkpoint_starts_afresh(tmp_path, capsys):
    ck = tmp_path / "partial"
    with pytest.raises(Stop):
        _build(ck, {"seed": 0}, stop_at=2)
    _, calls, _ = _build(ck, {"seed": 1})
    assert calls == list(range(COUNT)) and "something else" in capsys.readouterr().out
    discard(ck)
    with pytest.raises(Stop):
        _build(ck, {"seed": 1}, stop_at=2)
    (ck / "state.npz").write_bytes(b"not a zip file")
    got, calls, _ = _build(ck, {"seed": 1})
    assert calls == list(range(COUNT)) and "unreadable partial build" in capsys.readouterr().out
    jax.tree.map(np.testing.assert_array_equal, got, _build()[0])


@pytest.mark.slow  # two MJX compiles of the AntMaze collection segment (~1-2 min each on 2 cores)
def test_antmaze_build_resumes_bit_for_bit(tmp_path, monkeypatch):
    """The real state (an MJX pipeline state inside a Brax State, planner and episode bookkeeping) round-trips."""
    from proto_brax.data import antmaze_data as ad
    from proto_brax.networks import NetworkConfig, make_networks

    nets = make_networks(NetworkConfig(hidden=(16, 16)), 8)
    controller = ({"step": 0, "eval_return": 0.0}, nets, nets.actor.init(jax.random.PRNGKey(0), jnp.zeros((1, 27))))
    kw = dict(maze="umaze", kind="diverse", size=120, seed=3, num_envs=4, controller=controller, progress=False,
              episode_length=12)  # 30 steps per env: 3 segments of 10
    want, _ = ad.make_antmaze_dataset(**kw)
    real, calls = ad._segment, []

    def killed_in_segment_2(*args):
        calls.append(1)
        if len(calls) == 3:
            raise Stop
        return real(*args)

    monkeypatch.setattr(ad, "_segment", killed_in_segment_2)
    with pytest.raises(Stop):
        ad.make_antmaze_dataset(**kw, checkpoint=tmp_path / "ck")
    assert len(list((tmp_path / "ck").glob("seg-*.npz"))) == 2
    monkeypatch.setattr(ad, "_segment", real)
    got, _ = ad.make_antmaze_dataset(**kw, checkpoint=tmp_path / "ck")
    jax.tree.map(np.testing.assert_array_equal, got, want)
