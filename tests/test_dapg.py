"""D4RL's DAPG experts (data.dapg): an mjrl policy pickle is read without torch or mjrl and without running its code,
its policy matches a NumPy computation of mjrl's forward, and it becomes a behaviour snapshot that the Adroit datasets
are generated from on the native capsule model.

The pickle here is built to the layout of hand_dapg's files (an ``mjrl.policies.gaussian_mlp.MLP`` holding an
``mjrl.utils.fc_network.FCNetwork`` of ``torch.nn.Linear`` layers whose tensors are legacy ``torch.save`` storages),
by pickling stand-in classes registered under those module names for the duration of the dump."""

from __future__ import annotations

import io
import os
import pickle
import struct
import sys
import types
from collections import OrderedDict

import jax
import numpy as np
import pytest

from proto_brax.data import dapg


def _module(monkeypatch, name: str, **members):
    parts = name.split(".")
    for i in range(1, len(parts)):  # the parent packages, so that pickle's import of ``name`` succeeds
        parent = ".".join(parts[:i])
        if parent not in sys.modules or not getattr(sys.modules[parent], "_stand_in", False):
            stand_in = types.ModuleType(parent)
            stand_in._stand_in, stand_in.__path__ = True, []
            monkeypatch.setitem(sys.modules, parent, stand_in)
    mod = sys.modules[name] if getattr(sys.modules.get(name), "_stand_in", False) else types.ModuleType(name)
    mod._stand_in, mod.__path__ = True, []
    for k, v in members.items():
        if isinstance(v, type) or callable(v):
            v.__module__, v.__qualname__ = name, k
        setattr(mod, k, v)
    monkeypatch.setitem(sys.modules, name, mod)
    return mod


def _legacy_bytes(array: np.ndarray, storage_type) -> bytes:
    """What legacy torch.save wrote for one float32 storage."""
    class P(pickle.Pickler):
        def persistent_id(self, obj):
            return ("storage", storage_type, "k0", "cpu", array.size, None) if obj is array else None

    f = io.BytesIO()
    for header in (dapg._LEGACY_MAGIC, 1001, {"little_endian": True}):
        pickle.dump(header, f, protocol=2)
    P(f, protocol=2).dump(array)
    pickle.dump(["k0"], f, protocol=2)
    f.write(struct.pack("<q", array.size) + array.astype("<f4").tobytes())
    return f.getvalue()


def _mjrl_pickle(monkeypatch, tmp_path, params: dict, nonlinearity: str = "tanh"):
    """A file laid out as hand_dapg's dapg/policies/*-v0.pickle."""
    class FloatStorage:
        pass

    def _load_from_bytes(b):
        raise AssertionError("never called while dumping")

    def _rebuild_tensor_v2(*a):
        raise AssertionError

    class _VariableFunctions:
        pass

    _module(monkeypatch, "torch", FloatStorage=FloatStorage)
    _module(monkeypatch, "torch.storage", _load_from_bytes=_load_from_bytes)
    _module(monkeypatch, "torch._utils", _rebuild_tensor_v2=_rebuild_tensor_v2)
    _module(monkeypatch, "torch._C", _VariableFunctions=_VariableFunctions)

    class Tensor:  # reduces as old torch tensors did
        def __init__(self, a):
            self.a = np.ascontiguousarray(a, np.float32)

        def __reduce__(self):
            storage = _Storage(_legacy_bytes(self.a.ravel(), FloatStorage))
            return (_rebuild_tensor_v2, (storage, 0, self.a.shape, tuple(s // 4 for s in self.a.strides), False,
                                         OrderedDict()))

    class _Storage:
        def __init__(self, b):
            self.b = b

        def __reduce__(self):
            return (_load_from_bytes, (self.b,))

    class _Nonlinearity:
        def __reduce__(self):
            return (getattr, (_VariableFunctions, nonlinearity))

    Linear = _module(monkeypatch, "torch.nn.modules.linear", Linear=type("Linear", (), {})).Linear
    ModuleList = _module(monkeypatch, "torch.nn.modules.container", ModuleList=type("ModuleList", (), {})).ModuleList
    FCNetwork = _module(monkeypatch, "mjrl.utils.fc_network", FCNetwork=type("FCNetwork", (), {})).FCNetwork
    MLP = _module(monkeypatch, "mjrl.policies.gaussian_mlp", MLP=type("MLP", (), {})).MLP
    layers = ModuleList()
    layers.__dict__ = {"_modules": OrderedDict()}
    for i in range(len(params["layers"])):
        lin = Linear()
        lin.__dict__ = {"_parameters": OrderedDict(weight=Tensor(params["layers"][f"layer_{i}"]["w"]),
                                                   bias=Tensor(params["layers"][f"layer_{i}"]["b"]))}
        layers.__dict__["_modules"][str(i)] = lin
    net = FCNetwork()
    net.__dict__ = {"_modules": OrderedDict(fc_layers=layers), "nonlinearity": _Nonlinearity(),
                    **{k: np.asarray(params[k]) for k in ("in_shift", "in_scale", "out_shift", "out_scale")}}
    policy = MLP()
    policy.__dict__ = {"model": net, "log_std_val": np.float64(params["log_std"]), "n": 3}
    path = tmp_path / "policy-v0.pickle"
    path.write_bytes(pickle.dumps(policy, protocol=3))  # (as the files: protocol 3, bytes as BINBYTES)
    return path


def _params(rng, sizes):
    layers = {f"layer_{i}": {"w": rng.normal(size=(o, n)).astype(np.float32),
                             "b": rng.normal(size=o).astype(np.float32)}
              for i, (n, o) in enumerate(zip(sizes, sizes[1:]))}
    return {"layers": layers, "in_shift": rng.normal(size=sizes[0]).astype(np.float32),
            "in_scale": rng.uniform(0.5, 2.0, sizes[0]).astype(np.float32),
            "out_shift": rng.normal(size=sizes[-1]).astype(np.float32),
            "out_scale": rng.uniform(0.1, 0.5, sizes[-1]).astype(np.float32),
            "log_std": rng.uniform(-2.0, -1.0, sizes[-1]).astype(np.float32)}


def _numpy_mean(p, obs, nonlinearity="tanh"):
    """mjrl FCNetwork.forward in float64."""
    f = np.tanh if nonlinearity == "tanh" else (lambda x: np.maximum(x, 0.0))
    x = (obs - p["in_shift"]) / (p["in_scale"] + 1e-8)
    n = len(p["layers"])
    for i in range(n - 1):
        x = f(x @ p["layers"][f"layer_{i}"]["w"].astype(np.float64).T + p["layers"][f"layer_{i}"]["b"])
    last = p["layers"][f"layer_{n - 1}"]
    return (x @ last["w"].astype(np.float64).T + last["b"]) * p["out_scale"] + p["out_shift"]


def test_reads_an_mjrl_pickle_without_torch(monkeypatch, tmp_path):
    params = _params(np.random.default_rng(0), (5, 7, 6, 3))
    path = _mjrl_pickle(monkeypatch, tmp_path, params, "relu")
    monkeypatch.undo()  # torch and mjrl are gone again: the reader needs neither
    assert "torch" not in sys.modules or not hasattr(sys.modules["torch"], "FloatStorage")
    got = dapg.read_policy(path)
    assert got["nonlinearity"] == "relu"
    for i in range(3):
        for k in ("w", "b"):
            np.testing.assert_array_equal(got["params"]["layers"][f"layer_{i}"][k], params["layers"][f"layer_{i}"][k])
    for k in ("in_shift", "in_scale", "out_shift", "out_scale", "log_std"):
        np.testing.assert_array_equal(got["params"][k], params[k])


def test_refuses_other_globals_without_running_them(tmp_path):
    marker = tmp_path / "ran"

    class Evil:
        def __reduce__(self):
            return (os.system, (f"touch {marker}",))

    path = tmp_path / "evil.pickle"
    path.write_bytes(pickle.dumps(Evil()))
    with pytest.raises(pickle.UnpicklingError, match="refused"):
        dapg.read_policy(path)
    assert not marker.exists()


@pytest.mark.parametrize("nonlinearity", ["tanh", "relu"])
def test_policy_is_mjrls_gaussian_mlp(nonlinearity):
    rng = np.random.default_rng(1)
    p = _params(rng, (4, 8, 8, 3))
    obs = rng.normal(size=(6, 4)).astype(np.float32)
    np.testing.assert_allclose(dapg.mean_action(p, obs, nonlinearity), _numpy_mean(p, obs, nonlinearity),
                               rtol=1e-5, atol=1e-5)
    key = jax.random.PRNGKey(2)
    noise = np.asarray(jax.random.normal(key, (6, 3)))
    expected = np.clip(_numpy_mean(p, obs, nonlinearity) + np.exp(p["log_std"]) * noise, -1.0, 1.0)
    np.testing.assert_allclose(dapg.sample_action(p, obs, key, nonlinearity), expected, rtol=1e-5, atol=1e-5)
    mean = dapg.param_policy(nonlinearity, sampled=False)(p, obs, key)
    np.testing.assert_allclose(mean, np.clip(_numpy_mean(p, obs, nonlinearity), -1, 1), rtol=1e-5, atol=1e-5)


def test_a_converted_expert_generates_pen_data_on_the_native_capsule_model(monkeypatch, tmp_path):
    """convert -> snapshot step 0 with its evaluation; ``make_dataset('pen-expert')`` samples it on NativeAdroit."""
    from proto_brax.data import generate as g
    from proto_brax.data.cache import make_dataset
    from proto_brax.envs.adroit import get_task
    from proto_brax.envs.adroit_native import NativeAdroit

    task = get_task("pen")
    params = _params(np.random.default_rng(3), (task.obs_size, 16, 16, task.act_size))
    path = _mjrl_pickle(monkeypatch, tmp_path, params)
    monkeypatch.undo()
    with pytest.raises(ValueError, match="pass the door-v0 pickle"):
        dapg.convert(dapg.Args(task="door", pickle=path, out=tmp_path / "behavior", episodes=1))
    dapg.convert(dapg.Args(task="pen", pickle=path, out=tmp_path / "behavior", episodes=2))
    (snap,) = g.list_snapshots("pen", tmp_path / "behavior")
    assert snap.step == 0 and snap.metadata["policy_class"] == "dapg_mlp"
    assert 0.0 <= snap.metadata["eval_success_rate"] <= 1.0 and len(snap.metadata["eval_returns"]) == 2
    data, meta = make_dataset("pen-expert", size=200, seed=0, num_envs=2, behavior_root=tmp_path / "behavior",
                              progress=False)
    assert meta["backend"] == "native" and meta["behavior"][0]["policy_class"] == "dapg_mlp"
    # env 0's first episode replays on a fresh native env; its actions are the expert's clipped samples
    key = jax.random.fold_in(g.dataset_key(0, "expert"), 0)
    sim = NativeAdroit("pen")
    obs = sim.reset(jax.random.fold_in(jax.random.fold_in(jax.random.fold_in(key, 0), 0), 0))
    np.testing.assert_array_equal(data.observations[0], obs)
    for t in range(5):
        np.testing.assert_array_equal(data.observations[t], obs)
        both = np.stack([data.observations[t], data.observations[100 + t]])  # (env-major rows: env 1 from 100)
        sample = dapg.sample_action(params, both, jax.random.fold_in(key, t + 1))[0]
        np.testing.assert_allclose(data.actions[t], sample, rtol=1e-5, atol=1e-5)
        obs, reward, _, _ = sim.step(data.actions[t])
        assert data.rewards[t] == np.float32(reward)
