"""D4RL's Adroit experts: the DAPG policies of ``aravindr93/hand_dapg`` (``dapg/policies/{pen,door,hammer}-v0.pickle``,
Apache-2.0; Rajeswaran et al. 2018), the policies D4RL's ``expert`` and ``cloned`` Adroit data came from, as
behaviour snapshots of the suite (issue 36: SAC from scratch on native MuJoCo reached no pen success in 1.4·10⁵ steps).

The pickles hold an ``mjrl`` ``MLP`` policy whose network is a PyTorch module, saved by an old PyTorch. They are read
here without ``torch`` or ``mjrl``: a restricted unpickler that admits only the globals such a file needs (PyTorch's and
mjrl's classes become plain records, a legacy tensor storage is decoded from its bytes, every other global is refused),
so loading a file cannot run code.

The policy (``mjrl.policies.gaussian_mlp``): a Gaussian with a state-independent ``log_std`` and the mean of an MLP with
tanh hidden layers, input ``(obs − in_shift)/(in_scale + 1e-8)`` and output ``out · out_scale + out_shift``; the env
clips the action to [−1, 1]. :func:`mean_action` and :func:`sample_action` are that policy in JAX (samples clipped to
the action box, as the env sees them and as the datasets store them).

    python -m proto_brax.data.dapg --task pen --pickle hand_dapg/dapg/policies/pen-v0.pickle

writes ``checkpoints/behavior/pen/step_0000000``, the snapshot ``python -m proto_brax.datasets make pen-expert`` uses,
with its success rate on the suite's native capsule model.
"""

from __future__ import annotations

import dataclasses
import functools
import io
import pickle
import struct
from pathlib import Path

if __name__ == "__main__":  # as a command line: the quiet start before the imports that print
    from proto_brax.startup import quiet_start

    quiet_start()

import jax
import jax.numpy as jnp
import numpy as np

POLICY_CLASS = "dapg_mlp"  # a snapshot's metadata["policy_class"]
SOURCE = "aravindr93/hand_dapg dapg/policies/{task}-v0.pickle (Apache-2.0; Rajeswaran et al. 2018, DAPG)"
_STORAGE_DTYPES = {"FloatStorage": np.float32, "DoubleStorage": np.float64, "LongStorage": np.int64,
                   "IntStorage": np.int32}
_LEGACY_MAGIC = 0x1950A86A20F9469CFC6C  # torch.save's legacy (pre-zip) format


class _Record:
    """A PyTorch or mjrl object of the pickle: its state only."""

    def __init__(self, *args, **kwargs):
        pass

    def __setstate__(self, state):
        self.__dict__.update(state if isinstance(state, dict) else {"state": state})


class _StorageType:
    def __init__(self, name: str):
        self.name = name


class _TorchFunctions:
    """``getattr(torch._C._VariableFunctions, "tanh")`` in the pickle names the nonlinearity: keep the name."""

    def __getattr__(self, name: str) -> str:
        return name


def _torch_function_name(obj, name: str) -> str:
    if not isinstance(obj, _TorchFunctions):
        raise pickle.UnpicklingError(f"getattr on {type(obj).__name__} in an mjrl policy pickle: refused")
    return name


def _legacy_storage(data: bytes) -> np.ndarray:
    """A tensor storage saved with the legacy ``torch.save`` (``torch.storage._load_from_bytes``): three header
    pickles (magic number, protocol, system info), the storage's pickle (a persistent id), the storage keys, then per
    key its element count (int64) and raw little-endian elements."""
    f = io.BytesIO(data)
    storages: dict[str, tuple[str, int]] = {}

    class _Storage(pickle.Unpickler):
        def find_class(self, module, name):
            if module == "torch" and name in _STORAGE_DTYPES:
                return _StorageType(name)
            raise pickle.UnpicklingError(f"unexpected global {module}.{name} in a tensor storage")

        def persistent_load(self, pid):
            _, storage_type, key, _location, numel, _view = pid
            storages[key] = (storage_type.name, numel)
            return key

    if pickle.load(f) != _LEGACY_MAGIC:
        raise pickle.UnpicklingError("not a legacy torch.save storage")
    pickle.load(f), pickle.load(f)  # protocol version, system info
    root = _Storage(f).load()
    arrays = {}
    for key in pickle.load(f):
        dtype = np.dtype(_STORAGE_DTYPES[storages[key][0]]).newbyteorder("<")
        (count,) = struct.unpack("<q", f.read(8))
        arrays[key] = np.frombuffer(f.read(count * dtype.itemsize), dtype).astype(dtype.newbyteorder("="))
    return arrays[root]


def _rebuild_tensor(storage, offset, size, stride, *_):
    if not size:
        return storage[offset].copy()
    return np.lib.stride_tricks.as_strided(storage[offset:], shape=tuple(size),
                                           strides=[s * storage.itemsize for s in stride]).copy()


class _Unpickler(pickle.Unpickler):
    _ALLOWED = {("collections", "OrderedDict"), ("numpy", "ndarray"), ("numpy", "dtype"),
                *((m, n) for m in ("numpy.core.multiarray", "numpy._core.multiarray")
                  for n in ("_reconstruct", "scalar"))}

    def find_class(self, module, name):
        if (module, name) == ("torch.storage", "_load_from_bytes"):
            return _legacy_storage
        if (module, name) == ("torch._utils", "_rebuild_tensor_v2"):
            return _rebuild_tensor
        if (module, name) == ("torch._utils", "_rebuild_parameter"):
            return lambda data, *_: data
        if (module, name) == ("torch._C", "_VariableFunctions"):
            return _TorchFunctions()
        if (module, name) == ("builtins", "getattr"):  # only to name a torch function (the nonlinearity)
            return _torch_function_name
        if (module, name) == ("torch.nn.backends.thnn", "_get_thnn_function_backend"):
            return lambda: None
        if module.split(".")[0] in ("torch", "mjrl") and name[:1].isupper():  # a module or policy class: a record
            return type(name, (_Record,), {})
        if (module, name) in self._ALLOWED:
            if module == "numpy.core.multiarray":
                module = "numpy._core.multiarray" if hasattr(np, "_core") else module
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"{module}.{name} is not a global an mjrl policy pickle needs: refused")


def read_policy(path: str | Path) -> dict:
    """The DAPG policy of an ``mjrl`` pickle: ``params`` (NumPy: ``layer_i`` {``w`` [out, in], ``b`` [out]} for i =
    0, 1, …, ``in_shift``, ``in_scale``, ``out_shift``, ``out_scale``, ``log_std``) and the ``nonlinearity`` name."""
    with open(path, "rb") as f:
        policy = _Unpickler(f).load()
    net = policy.model.__dict__
    if net.get("nonlinearity") not in ("tanh", "relu"):
        raise ValueError(f"{path}: an mjrl MLP with nonlinearity {net.get('nonlinearity')!r} (tanh or relu expected)")
    layers = net["_modules"]["fc_layers"].__dict__["_modules"].values()
    params = {"layers": {f"layer_{i}": {"w": np.asarray(m.__dict__["_parameters"]["weight"], np.float32),
                             "b": np.asarray(m.__dict__["_parameters"]["bias"], np.float32)}
                         for i, m in enumerate(layers)},
              **{k: np.asarray(net[k], np.float32) for k in ("in_shift", "in_scale", "out_shift", "out_scale")},
              "log_std": np.asarray(policy.log_std_val, np.float32)}
    return {"params": params, "nonlinearity": net["nonlinearity"]}


def mean_action(params, obs: jax.Array, nonlinearity: str = "tanh") -> jax.Array:
    """The policy's mean (mjrl ``FCNetwork.forward``), unclipped. ``obs`` [..., obs]."""
    act = jnp.tanh if nonlinearity == "tanh" else jax.nn.relu
    layers = [params["layers"][f"layer_{i}"] for i in range(len(params["layers"]))]
    x = (obs - params["in_shift"]) / (params["in_scale"] + 1e-8)
    for layer in layers[:-1]:
        x = act(x @ layer["w"].T + layer["b"])
    return (x @ layers[-1]["w"].T + layers[-1]["b"]) * params["out_scale"] + params["out_shift"]


def sample_action(params, obs: jax.Array, key: jax.Array, nonlinearity: str = "tanh") -> jax.Array:
    """mjrl's ``get_action``: mean + exp(log_std)·N(0, 1), here clipped to [−1, 1] as the env clips it."""
    mean = mean_action(params, obs, nonlinearity)
    return jnp.clip(mean + jnp.exp(params["log_std"]) * jax.random.normal(key, mean.shape), -1.0, 1.0)


@functools.lru_cache(maxsize=None)
def param_policy(nonlinearity: str, sampled: bool = True):
    """The policy as a ``generate.ParamPolicy`` (params, obs [n, obs], key) -> actions: clipped samples or the
    clipped mean; cached, so one compiled rollout program serves every call."""
    if sampled:
        return lambda params, obs, key: sample_action(params, obs, key, nonlinearity)
    return lambda params, obs, key: jnp.clip(mean_action(params, obs, nonlinearity), -1.0, 1.0)


def template(meta: dict):
    """A zero pytree of a snapshot's shapes (``metadata["dapg"]["shapes"]``), to restore it into."""
    shapes = meta["dapg"]["shapes"]
    zeros = lambda s: np.zeros(s, np.float32)  # noqa: E731
    return {"layers": {f"layer_{i}": {"w": zeros(w), "b": zeros(b)} for i, (w, b) in enumerate(shapes["layers"])},
            **{k: zeros(shapes[k]) for k in ("in_shift", "in_scale", "out_shift", "out_scale", "log_std")}}


@dataclasses.dataclass
class Args:
    task: str = "pen"  # pen, door or hammer
    pickle: Path = Path("hand_dapg/dapg/policies/pen-v0.pickle")
    out: Path = Path("checkpoints/behavior")  # the snapshot: OUT/<task>/step_0000000
    episodes: int = 100
    """Evaluation episodes on the suite's native capsule model (sampled and mean actions)."""
    seed: int = 0


class _Original:
    """gymnasium-robotics' own env (the cylinder model the DAPG experts were trained on), behind NativeAdroit's
    ``reset(key)`` / ``step(action) -> (obs, reward, terminal, success)``; no termination (its pen never ends)."""

    def __init__(self, task: str):
        import gymnasium as gym
        import gymnasium_robotics

        from proto_brax.envs import adroit

        gym.register_envs(gymnasium_robotics)
        self.task = task
        self.env = gym.make(adroit.get_task(task).gym_id, max_episode_steps=10**9).unwrapped

    def reset(self, key: jax.Array) -> np.ndarray:
        return self.env.reset(seed=int(jax.random.randint(key, (), 0, 2**31 - 1)))[0].astype(np.float32)

    def step(self, action: np.ndarray):
        obs, reward, _, _, info = self.env.step(np.asarray(action, np.float64))
        return obs.astype(np.float32), float(reward), False, bool(info["success"])


def evaluate(task: str, params, nonlinearity: str, episodes: int, seed: int, sampled: bool,
             model: str = "capsule") -> dict:
    """Returns and D4RL's success rate (success on more than ``success_steps`` of the D4RL horizon's steps) of the
    policy, sampled or mean actions, on the suite's native capsule model (``envs.adroit_native.NativeAdroit``, the
    physics the MJX env runs), on the model with cylinders as convex prisms (``model="prism"``,
    ``adroit.adroit_xml(cylinders="prism")``) or on gymnasium-robotics' original cylinder model (``"original"``)."""
    from proto_brax import envs
    from proto_brax.envs.adroit_native import NativeAdroit
    from proto_brax.envs.native import native_episodes

    env = _Original(task) if model == "original" else NativeAdroit(task, cylinders=model)
    policy = param_policy(nonlinearity, sampled)
    act = jax.jit(lambda obs, k: policy(params, obs, k))
    r = native_episodes(env, lambda obs, key, t: act(obs, jax.random.fold_in(key, t)),
                        jax.random.split(jax.random.PRNGKey(seed), episodes))
    return {**r, "return_std": float(np.std(r["returns"])),
            "normalized": float(envs.normalized_score(task, r["return_mean"])), "episodes": episodes,
            "actions": "sampled (clipped)" if sampled else "mean (clipped)", "model": model}


def convert(args: Args) -> Path:
    """Read the pickle, evaluate it on the native capsule model, save it as the task's behaviour snapshot."""
    import hashlib

    from proto_brax import __version__, checkpoints
    from proto_brax.data.behavior import snapshot_dir
    from proto_brax.envs import adroit

    policy = read_policy(args.pickle)
    params, nonlinearity = policy["params"], policy["nonlinearity"]
    task = adroit.get_task(args.task)
    first, last = params["layers"]["layer_0"]["w"], params["layers"][f"layer_{len(params['layers']) - 1}"]["w"]
    if first.shape[1] != task.obs_size or last.shape[0] != task.act_size:
        raise ValueError(f"{args.pickle} maps {first.shape[1]} observations to {last.shape[0]} actions; {args.task} "
                         f"has {task.obs_size} and {task.act_size}: pass the {args.task}-v0 pickle.")
    sampled = evaluate(args.task, params, nonlinearity, args.episodes, args.seed, sampled=True)
    mean = evaluate(args.task, params, nonlinearity, args.episodes, args.seed, sampled=False)
    layers = [params["layers"][f"layer_{i}"] for i in range(len(params["layers"]))]
    shapes = {"layers": [(list(v["w"].shape), list(v["b"].shape)) for v in layers],
              **{k: list(params[k].shape) for k in ("in_shift", "in_scale", "out_shift", "out_scale", "log_std")}}
    record = {"env": args.task, "backend": "native", "step": 0, "seed": args.seed, "policy_class": POLICY_CLASS,
              "dapg": {"source": SOURCE.format(task=args.task), "nonlinearity": nonlinearity, "shapes": shapes,
                       "pickle_sha256": hashlib.sha256(Path(args.pickle).read_bytes()).hexdigest()},
              # the snapshot's evaluation, as the SAC snapshots record theirs (deterministic = mean actions)
              "eval_return_mean": mean["return_mean"], "eval_returns": mean["returns"],
              "eval_success_rate": mean["success_rate"], "behavior_return": {
                  "mean": sampled["return_mean"], "std": sampled["return_std"], "episodes": args.episodes,
                  "seed": args.seed, "success_rate": sampled["success_rate"],
                  "policy": "stochastic (Gaussian samples clipped to the action box), as in the datasets"},
              "config": {"trainer": "dapg (hand_dapg)", "model": "the suite's capsule model (envs.adroit)"},
              "version": __version__}
    path = snapshot_dir(args.out, args.task, 0)
    checkpoints.save(path, params, record)
    for r in (mean, sampled):
        print(f"[{args.task}] DAPG expert, {r['actions']} actions: return {r['return_mean']:.1f} ± "
              f"{r['return_std']:.1f} (normalized {r['normalized']:.1f}), success {r['success_rate']:.2f} over "
              f"{r['episodes']} episodes on the native capsule model", flush=True)
    print(f"[{args.task}] -> {path}")
    return path


if __name__ == "__main__":
    import tyro

    convert(tyro.cli(Args))
