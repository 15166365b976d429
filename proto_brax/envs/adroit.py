"""D4RL Adroit pen, door and hammer (gymnasium-robotics' ``AdroitHand{Pen,Door,Hammer}-v1``) as Brax MJX envs.

What is reproduced, and from where (``gymnasium_robotics/envs/adroit_hand/adroit_{pen,door,hammer}.py`` 1.4.2):

* **Model**: the package's ``adroit_{pen,door,hammer}.xml`` with its includes, plus the ``__init__``'s actuator
  "sensitivity" change (wrist actuators: gain 10, bias −10 · qpos; finger actuators: gain 1, bias −1 · qpos), as
  D4RL's ``hand_dapg`` envs do. ``frame_skip = 5`` (timestep 0.002 s, control dt 0.01 s).
* **Action**: ``a ∈ [−1, 1]`` (clipped), ``ctrl = act_mean + a · act_rng`` from the actuators' ctrlrange.
* **Observations** (same order and size: 45 pen, 39 door, 46 hammer) and the **dense reward** with its bonus terms,
  computed on the state after the step; ``metrics["success"]`` is gymnasium-robotics' ``info["success"]`` (D4RL's
  ``goal_achieved``): pen ``‖pen − target‖ < 0.075 and orientation dot > 0.95``, door ``hinge ≥ 1.35``, hammer
  ``‖nail − goal‖ < 0.01``. gymnasium-robotics never terminates an Adroit episode: ``done`` is 0 unless the physics
  state stops being finite (then 1, with a zeroed observation and reward, as ``antmaze.py`` does).
* **Reset** (``MujocoEnv.reset`` = ``mj_resetData`` then ``reset_model``): qpos0, zero velocities, and the task's
  random layout — pen: target orientation ``euler2quat((U(−1, 1), U(−1, 1), 0))``; door: frame position
  ``(U(−0.3, −0.2), U(0.25, 0.35), U(0.252, 0.35))``; hammer: board height ``U(0.1, 0.25)``. gymnasium-robotics writes
  these into the *model* (``body_quat`` / ``body_pos``); here the per-episode values live in ``state.info["layout"]``
  and each step runs MJX on ``sys`` with that one row replaced, so the physics is the same model, per env.

**Deviations** (each needed by MJX 3.17 or measured by ``benchmarks/adroit_check.py``):

1. *Cylinders → capsules.* MJX has no cylinder–box (nor cylinder–mesh) collider, and ``mjx.put_model`` refuses the
   models. Every ``cylinder`` geom becomes a ``capsule`` of the same radius and half-length (so each colliding
   cylinder grows a hemispherical cap of its radius at both ends): the pen, the door frame's and door's posts and
   the latch, the nail and its head, the hammer head, and visual-only ones (table legs, pen caps). To keep the
   *inertia* unchanged — the pen's body mass comes from its geoms (density 1500) — every body that has a converted
   geom and no ``<inertial>`` gets an explicit one with the original compiled mass, centre of mass and inertia.
   ``adroit_xml(cylinders="prism")`` is the alternative under test: every cylinder a convex mesh prism on a regular
   16-gon inscribed in its circle (its flat ends kept; MJX collides meshes with boxes) and every contact margin 0
   (MJX has no margins for meshes; the files' margin is 0.5 mm). Natively the DAPG experts succeed as on the original
   model there, and half as often on the capsules (docs/MEASUREMENTS.md#adroit).
2. *Cylinder sites → boxes.* MJX's touch sensor has no cylinder ray, so hammer's ``S_target`` site (the nail-head
   disc, read by the ``S_nail`` touch sensor, the last observation) becomes the box of half-sizes ``(r, r, h)``; the
   ``nail_goal`` site (position only) likewise. Positions are unchanged; the sensor also counts contacts in the corners.
3. *No noslip solver in MJX.* The XML asks for ``noslip_iterations = 20``; MJX ignores it (native MuJoCo runs it).
   The check measures the combined MJX error against native MuJoCo on the capsule model.
4. MJX solves in float32 (native float64).

D4RL's own ``hand_dapg`` envs differ from gymnasium-robotics in two places, which ``d4rl_reward=True`` restores:
door and hammer *subtract* ``0.1 ‖palm − handle/hammer‖`` (gymnasium-robotics adds it), and D4RL's pen ends the
episode when the pen drops (``z < 0.075``). D4RL also registers pen with 100-step episodes (door, hammer 200);
gymnasium-robotics registers all three at 200 (see ``proto_brax/envs/__init__.py`` for what the registry uses).

**Measured** (``benchmarks/adroit_check.py``, 50 random-action control steps from one reset, 2026-12-01, on the
2-core CPU under a load average of ~8 from other jobs, so speeds are low and only their ratios mean much):

max |Δqpos| over the 50 steps (return difference in brackets); "floor" nudges the actions by ±1e-6:

| task | floor (native) | capsule vs original (native) | MJX vs native (capsule) | steps/s MJX b=1 / native |
|------|----------------|------------------------------|-------------------------|--------------------------|
| pen  | 3.5e-5         | 1.69 (34.8 -> -67.5)         | 0.17 (-0.9)             | 19 / 171                 |
| door | 2.7e-4         | 0.032 (-0.18)                | 0.053 (+0.09)           | 8.9 / 186                |

gymnasium-robotics' own env and our numpy copy of its formulas on the original XML agree exactly (0.0). The pen is
the task the capsule change moves: its body collides with the hand through the converted geom, and even along its
side the contacts differ (probably because native MuJoCo collides cylinders with its general convex collider and
capsules with analytic ones; not verified), so a random-action trajectory differs from step 1 (Δqpos 0.058 within 10
steps); PROTO-style results on pen are therefore on a modified pen task, and D4RL's pen references and datasets come
from the cylinder pen. The door moves 3 cm at most (100x the floor) and ends with nearly the same return. Flat discs
(the nail head r 0.035, half-height 0.005) become capsules 0.08 tall — a crude shape for the hammer's target that
random actions never touch, so this check cannot see it. MJX compile of one 50-step rollout took 8-13 min under that
load. Since 2026-12-06 MJX keeps the 24 deepest contacts per condim group (``MAX_CONTACT_POINTS``) and computes only
the sensors the observations read (``USED_SENSORS``): the cross-check's errors are unchanged to the printed digits, and
a batch-1 rollout (interleaved with the unbounded, all-sensor env, beside one single-core sweep) went from 114 to 147
control steps/s (pen), 58 to 108 (door) and 45 to 130 (hammer); native gymnasium-robotics steps 2100-3000.
Since 2026-12-07 pen's table, target and thumb base/hub collide with the pen only (``PRUNED_COLLIDERS``; the hand
never touched them natively) and pen keeps 12 contacts per group: on one quiet core a batch-1 rollout steps 585 (pen),
243 (door) and 234 (hammer) control steps/s, with the cross-check's errors unchanged (docs/MEASUREMENTS.md#adroit).
"""

from __future__ import annotations

import dataclasses
import os
import xml.etree.ElementTree as ET

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from brax.envs.base import PipelineEnv, State
from brax.io import mjcf

FRAME_SKIP = 5  # gymnasium-robotics Adroit frame_skip
# MJX keeps a contact slot for every candidate geom pair (124 pen, 279 door, 230 hammer: 220-449 slots) and solves
# them all every physics step, touching or not; native MuJoCo saw at most 9 (pen, hammer) and 17 (door) contacts at
# once over 20 random-action episodes of 200 steps. Keeping the 24 deepest per condim group (MJX's
# ``max_contact_points``) left the 50-step cross-check's MJX-vs-native error unchanged to 1e-6 (door 0.0526, pen 0.168,
# hammer 0.0029) and sped a batch-1 rollout up 1.2x (pen) to 3x (door) (docs/MEASUREMENTS.md). Bounding the
# broad phase too (``max_geom_pairs`` 16 or 32) raised the door's error tenfold: neighbouring finger capsules always
# overlap in bounding spheres, so the nearest-pairs cull drops real contacts. Left unbounded.
MAX_CONTACT_POINTS = 24
# Bodies that collide with the task's object only: their geoms' conaffinity is cleared, and the hand's geoms (contype 1,
# conaffinity 0) then never collide with them; the 19 explicit finger-finger pairs stay. On pen, native MuJoCo found
# no contact of the hand with the table, the target pen or the thumb's base and hub in 10 random-action, 10 DAPG-expert
# and 10 noisy-expert episodes (every physics step counted), and at most 8 contacts at once, so pen also keeps 12
# contacts per condim group. Together: 124 -> 44 candidate pairs, 68 -> 24 contact slots, a physics step 0.74 ->
# 0.38 ms at batch 1 (docs/MEASUREMENTS.md#adroit). On door and hammer the hand does touch the table and the frame,
# so nothing is pruned there.
PRUNED_COLLIDERS = {"pen": ("table", "target", "thbase", "thhub"), "door": (), "hammer": ()}
TASK_MAX_CONTACT_POINTS = {"pen": 12, "door": MAX_CONTACT_POINTS, "hammer": MAX_CONTACT_POINTS}
PRISM_SIDES = 16  # adroit_xml(cylinders="prism"): the polygon a cylinder's convex-mesh stand-in is built on
# Sensors the observations read: MJX computes every sensor on every physics step (65 on the door: ~10% of a step),
# and no sensor acts on the physics.
USED_SENSORS = {"pen": (), "door": (), "hammer": ("S_nail",)}


@dataclasses.dataclass(frozen=True)
class AdroitTask:
    """One Adroit task: its gymnasium-robotics id, XML and sizes."""

    gym_id: str
    xml_file: str
    obs_size: int
    act_size: int


TASKS: dict[str, AdroitTask] = {
    "pen": AdroitTask("AdroitHandPen-v1", "adroit_pen.xml", 45, 24),
    "door": AdroitTask("AdroitHandDoor-v1", "adroit_door.xml", 39, 28),
    "hammer": AdroitTask("AdroitHandHammer-v1", "adroit_hammer.xml", 46, 26),
}


def get_task(task: str) -> AdroitTask:
    if task not in TASKS:
        raise ValueError(f"Unknown Adroit task {task!r}: choose one of {sorted(TASKS)}.")
    return TASKS[task]


def asset_dir() -> str:
    """gymnasium-robotics' ``assets/adroit_hand`` directory."""
    import gymnasium_robotics

    return os.path.join(os.path.dirname(gymnasium_robotics.__file__), "envs", "assets", "adroit_hand")


def _inline_includes(parent: ET.Element, directory: str) -> None:
    """Replace every ``<include file=...>`` below ``parent`` by the children of the included ``<mujocoinclude>``."""
    for i, child in enumerate(list(parent)):
        if child.tag == "include":
            included = ET.parse(os.path.join(directory, child.get("file"))).getroot()
            _inline_includes(included, directory)
            parent.remove(child)
            for j, grandchild in enumerate(list(included)):
                parent.insert(i + j, grandchild)
            _inline_includes(parent, directory)  # indices moved: start over (includes are few)
            return
        _inline_includes(child, directory)


def original_xml(task: str) -> str:
    """gymnasium-robotics' XML for ``task`` with includes inlined and absolute mesh / texture directories."""
    directory = asset_dir()
    root = ET.parse(os.path.join(directory, get_task(task).xml_file)).getroot()
    _inline_includes(root, directory)
    for compiler in root.iter("compiler"):
        for attr in ("meshdir", "texturedir"):
            if compiler.get(attr) is not None:
                compiler.set(attr, os.path.join(directory, compiler.get(attr)))
    return ET.tostring(root, encoding="unicode")


def apply_actuator_sensitivity(model: mujoco.MjModel) -> mujoco.MjModel:
    """gymnasium-robotics' (and D4RL's) ``__init__`` change of the hand's position-servo gains, in place."""
    aid = {mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, i): i for i in range(model.nu)}
    for first, last, gain in (("A_WRJ1", "A_WRJ0", 10.0), ("A_FFJ3", "A_THJ0", 1.0)):
        sl = slice(aid[first], aid[last] + 1)
        model.actuator_gainprm[sl, :3] = np.array([gain, 0.0, 0.0])
        model.actuator_biasprm[sl, :3] = np.array([0.0, -gain, 0.0])
    return model


def load_original_model(task: str) -> mujoco.MjModel:
    """Native MuJoCo model of gymnasium-robotics' env (cylinders kept), with the actuator change."""
    return apply_actuator_sensitivity(mujoco.MjModel.from_xml_string(original_xml(task)))


def adroit_xml(
    task: str,
    *,
    max_geom_pairs: int | None = None,
    max_contact_points: int | None | str = "task",
    solver_iterations: int | None = None,
    ls_iterations: int | None = None,
    capsule_ends: str = "extend",
    all_sensors: bool = False,
    cylinders: str = "capsule",
    prune_colliders: bool = True,
) -> str:
    """MJX-loadable XML: ``original_xml`` with every cylinder geom turned into a capsule (same radius and
    half-length) and explicit inertials where a body's inertia came from a converted geom (module docstring).

    The optional MJX contact bounds are inserted as the first ``<custom>`` numerics (mjx 3.17 reads them by index);
    native MuJoCo ignores them (``max_contact_points=None``: unbounded; "task": ``TASK_MAX_CONTACT_POINTS``).
    ``prune_colliders``: the bodies of ``PRUNED_COLLIDERS`` collide with the object only. ``solver_iterations`` /
    ``ls_iterations``
    override the XML's solver caps. Only the sensors in ``USED_SENSORS`` are kept unless ``all_sensors``.
    ``capsule_ends``: "extend" keeps the cylinder's half-length (the caps stick out by the radius at both ends);
    "match" shortens the half-length by the radius where the cylinder is longer than wide (half-length > radius),
    so the capsule's tips end where the cylinder's faces were; flat discs keep their half-length.
    """
    if capsule_ends not in ("extend", "match"):
        raise ValueError(f"capsule_ends must be 'extend' or 'match', not {capsule_ends!r}")
    if cylinders not in ("capsule", "prism"):
        raise ValueError(f"cylinders must be 'capsule' or 'prism', not {cylinders!r}")
    prisms: dict[tuple[str, str], str] = {}  # (radius, half-length) -> mesh name
    xml = original_xml(task)
    compiled = mujoco.MjModel.from_xml_string(xml)
    root = ET.fromstring(xml)
    bodies = list(root.find("worldbody").iter("body"))  # depth-first XML order = MuJoCo body ids 1, 2, ...
    for body_id, body in enumerate(bodies, start=1):
        name = body.get("name")
        if name is not None and mujoco.mj_name2id(compiled, mujoco.mjtObj.mjOBJ_BODY, name) != body_id:
            raise RuntimeError(f"body order mismatch at {name!r}")
        converted = False
        if prune_colliders and name in PRUNED_COLLIDERS[task]:
            for geom in body.findall("geom"):
                geom.set("conaffinity", "0")
        for geom in body.findall("geom"):
            if geom.get("type") == "cylinder" and cylinders == "prism":
                radius, half = geom.get("size").split()[:2]
                name = prisms.setdefault((radius, half), f"cylinder_prism_{len(prisms)}")
                geom.set("type", "mesh")
                geom.set("mesh", name)
                del geom.attrib["size"]
                converted = True
            elif geom.get("type") == "cylinder":
                geom.set("type", "capsule")
                if capsule_ends == "match":
                    radius, half = (float(v) for v in geom.get("size").split()[:2])
                    if half > radius:
                        geom.set("size", f"{radius!r} {half - radius!r}")
                converted = True
        if converted and body.find("inertial") is None:
            q = compiled.body_iquat[body_id]
            inertial = ET.Element(
                "inertial",
                pos=" ".join(repr(float(v)) for v in compiled.body_ipos[body_id]),
                quat=" ".join(repr(float(v)) for v in q),
                mass=repr(float(compiled.body_mass[body_id])),
                diaginertia=" ".join(repr(float(v)) for v in compiled.body_inertia[body_id]),
            )
            body.insert(0, inertial)
    # MJX's touch sensor ray-casts contacts into its site, and mjx 3.17 has no cylinder ray: hammer's S_nail site
    # (a thin disc) becomes the box around it. Sites have no physics; only which contacts the sensor counts changes.
    for site in root.iter("site"):
        if site.get("type") == "cylinder":
            radius, half = site.get("size").split()[:2]
            site.set("type", "box")
            site.set("size", f"{radius} {radius} {half}")
    # Geoms inherit no cylinder type from defaults in these files; fail loudly if that ever changes.
    for default_geom in root.iter("geom"):
        if default_geom.get("type") == "cylinder":
            raise RuntimeError("a cylinder geom is left (from a default class?)")
    if not all_sensors:
        for block in root.iter("sensor"):
            for sensor in list(block):
                if sensor.get("name") not in USED_SENSORS[task]:
                    block.remove(sensor)
    if prisms:  # each cylinder as the convex prism on a regular PRISM_SIDES-gon inscribed in its circle
        # MJX collides meshes without margins: every geom's 0.5 mm contact margin goes (a pair takes the larger one)
        for geom in root.iter("geom"):
            if geom.get("margin") is not None:
                geom.set("margin", "0")
        for default in root.iter("default"):
            for geom in default.findall("geom"):
                geom.set("margin", "0")
        asset = root.find("asset")
        if asset is None:
            asset = ET.SubElement(root, "asset")
        angles = 2 * np.pi * np.arange(PRISM_SIDES) / PRISM_SIDES
        for (radius, half), name in prisms.items():
            r, h = float(radius), float(half)
            ring = [(r * np.cos(a), r * np.sin(a)) for a in angles]
            vertex = " ".join(f"{float(x)!r} {float(y)!r} {float(z)!r}" for z in (-h, h) for x, y in ring)
            asset.append(ET.Element("mesh", name=name, vertex=vertex, scale="1 1 1"))  # (the files default to mm)
    custom = root.find("custom")
    if max_contact_points == "task":
        max_contact_points = TASK_MAX_CONTACT_POINTS[task]
    bounds = [("max_contact_points", max_contact_points), ("max_geom_pairs", max_geom_pairs)]
    if any(v is not None for _, v in bounds):
        if custom is None:
            custom = ET.Element("custom")
            root.append(custom)
        for name, value in bounds:
            if value is not None:
                custom.insert(0, ET.Element("numeric", name=name, data=str(int(value))))
    option = root.find("option")
    if option is None:
        option = ET.SubElement(root, "option")
    if solver_iterations is not None:
        option.set("iterations", str(int(solver_iterations)))
    if ls_iterations is not None:
        option.set("ls_iterations", str(int(ls_iterations)))
    return ET.tostring(root, encoding="unicode")


def load_capsule_model(task: str, **xml_kwargs) -> mujoco.MjModel:
    """Native MuJoCo model of the MJX env's physics (capsules), with the actuator change."""
    return apply_actuator_sensitivity(mujoco.MjModel.from_xml_string(adroit_xml(task, **xml_kwargs)))


# ------------------------------------------------------------------------------------------------------------------
# gymnasium-robotics' rotation helpers (utils/rotations.py), in jnp
# ------------------------------------------------------------------------------------------------------------------


def euler2quat(euler: jax.Array) -> jax.Array:
    """gymnasium-robotics ``rotations.euler2quat`` (its axis convention) for one ``(3,)`` Euler triple."""
    ai, aj, ak = euler[2] / 2, -euler[1] / 2, euler[0] / 2
    si, sj, sk = jnp.sin(ai), jnp.sin(aj), jnp.sin(ak)
    ci, cj, ck = jnp.cos(ai), jnp.cos(aj), jnp.cos(ak)
    cc, cs, sc, ss = ci * ck, ci * sk, si * ck, si * sk
    return jnp.stack([cj * cc + sj * ss, cj * cs - sj * sc, -(cj * ss + sj * cc), cj * sc - sj * cs])


def quat2euler(quat: jax.Array, xp=jnp) -> jax.Array:
    """gymnasium-robotics ``rotations.quat2euler`` (= ``mat2euler(quat2mat(q))``) for one ``(4,)`` quaternion."""
    w, x, y, z = quat[0], quat[1], quat[2], quat[3]
    s = 2.0 / xp.sum(quat * quat)
    m00, m01, m02 = 1.0 - s * (y * y + z * z), s * (x * y - w * z), s * (x * z + w * y)
    m10, m11, m12 = s * (x * y + w * z), 1.0 - s * (x * x + z * z), s * (y * z - w * x)
    m22 = 1.0 - s * (x * x + y * y)
    cy = xp.sqrt(m22 * m22 + m12 * m12)
    ok = cy > 4.0 * np.finfo(np.float64).eps
    e2 = xp.where(ok, -xp.arctan2(m01, m00), -xp.arctan2(-m10, m11))
    e1 = -xp.arctan2(-m02, cy)
    e0 = xp.where(ok, -xp.arctan2(m12, m22), 0.0)
    return xp.stack([e0, e1, e2])


# ------------------------------------------------------------------------------------------------------------------
# Observation, reward and success: gymnasium-robotics' formulas on any MuJoCo-like data (mjx.Data or MjData arrays)
# ------------------------------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Ids:
    """Body / site / joint / sensor indices a task's formulas read (from ``task_ids``)."""

    body: dict
    site: dict
    door_hinge: int = -1  # door: dof address of door_hinge (gymnasium-robotics indexes qpos with it)
    nail_sensor_adr: int = -1  # hammer: sensordata address of S_nail
    pen_length: float = 1.0
    tar_length: float = 1.0


def task_ids(task: str, model: mujoco.MjModel) -> Ids:
    def bid(name):
        return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)

    def sid(name):
        return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, name)

    if task == "pen":
        sites = {n: sid(n) for n in ("eps_ball", "object_top", "object_bottom", "target_top", "target_bottom")}
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)  # lengths at qpos0, as reset_model measures them (rotation-invariant)
        pen = np.linalg.norm(data.site_xpos[sites["object_top"]] - data.site_xpos[sites["object_bottom"]])
        tar = np.linalg.norm(data.site_xpos[sites["target_top"]] - data.site_xpos[sites["target_bottom"]])
        return Ids({"Object": bid("Object"), "target": bid("target")}, sites, pen_length=float(pen),
                   tar_length=float(tar))
    if task == "door":
        hinge = int(model.jnt_dofadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "door_hinge")])
        return Ids({"frame": bid("frame")}, {"S_grasp": sid("S_grasp"), "S_handle": sid("S_handle")},
                   door_hinge=hinge)
    if task == "hammer":
        sensor = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, "S_nail")
        return Ids({"Object": bid("Object"), "nail_board": bid("nail_board")},
                   {n: sid(n) for n in ("S_target", "S_grasp", "tool", "nail_goal")},
                   nail_sensor_adr=int(model.sensor_adr[sensor]))
    raise ValueError(task)


def observation(task: str, ids: Ids, qpos, qvel, xpos, xquat, site_xpos, sensordata, xp=jnp):
    """gymnasium-robotics' ``_get_obs`` for ``task``; ``xp`` is ``jnp`` (jitted env) or ``np`` (tests, checks)."""
    if task == "pen":
        obj_pos = xpos[ids.body["Object"]]
        desired_pos = site_xpos[ids.site["eps_ball"]]
        obj_orien = (site_xpos[ids.site["object_top"]] - site_xpos[ids.site["object_bottom"]]) / ids.pen_length
        desired_orien = (site_xpos[ids.site["target_top"]] - site_xpos[ids.site["target_bottom"]]) / ids.tar_length
        return xp.concatenate([qpos[:-6], obj_pos, qvel[-6:], obj_orien, desired_orien, obj_pos - desired_pos,
                               obj_orien - desired_orien])
    if task == "door":
        handle = site_xpos[ids.site["S_handle"]]
        palm = site_xpos[ids.site["S_grasp"]]
        door = qpos[ids.door_hinge]
        door_open = xp.where(door > 1.0, 1.0, -1.0)
        return xp.concatenate([qpos[1:-2], qpos[-1:], door[None], palm, handle, palm - handle, door_open[None]])
    if task == "hammer":
        euler = quat2euler(xquat[ids.body["Object"]], xp)
        impact = xp.clip(sensordata[ids.nail_sensor_adr], -1.0, 1.0)
        return xp.concatenate([qpos[:-6], xp.clip(qvel, -1.0, 1.0)[-6:], site_xpos[ids.site["S_grasp"]],
                               xpos[ids.body["Object"]], euler, site_xpos[ids.site["S_target"]], impact[None]])
    raise ValueError(task)


def reward_and_success(task: str, ids: Ids, qpos, qvel, xpos, site_xpos, d4rl_reward: bool = False, xp=jnp):
    """gymnasium-robotics' dense reward and ``info["success"]`` (D4RL's sign of the palm term if ``d4rl_reward``).

    Returns ``(reward, success, dropped)``; ``dropped`` is pen's ``z < 0.075`` (D4RL's pen termination), else False.
    """
    palm_sign = -1.0 if d4rl_reward else 1.0
    if task == "pen":
        obj_pos = xpos[ids.body["Object"]]
        dist = xp.linalg.norm(obj_pos - site_xpos[ids.site["eps_ball"]])
        obj_orien = (site_xpos[ids.site["object_top"]] - site_xpos[ids.site["object_bottom"]]) / ids.pen_length
        desired_orien = (site_xpos[ids.site["target_top"]] - site_xpos[ids.site["target_bottom"]]) / ids.tar_length
        sim = xp.dot(obj_orien, desired_orien)
        dropped = obj_pos[2] < 0.075
        reward = (-dist + sim + 10.0 * ((dist < 0.075) & (sim > 0.9)) + 50.0 * ((dist < 0.075) & (sim > 0.95))
                  - 5.0 * dropped)
        return reward, (dist < 0.075) & (sim > 0.95), dropped
    if task == "door":
        door = qpos[ids.door_hinge]
        handle, palm = site_xpos[ids.site["S_handle"]], site_xpos[ids.site["S_grasp"]]
        reward = (palm_sign * 0.1 * xp.linalg.norm(palm - handle) - 0.1 * (door - 1.57) * (door - 1.57)
                  - 1e-5 * xp.sum(qvel**2) + 2.0 * (door > 0.2) + 8.0 * (door > 1.0) + 10.0 * (door > 1.35))
        return reward, door >= 1.35, xp.zeros((), bool)
    if task == "hammer":
        hamm = xpos[ids.body["Object"]]
        palm, head = site_xpos[ids.site["S_grasp"]], site_xpos[ids.site["tool"]]
        nail, goal = site_xpos[ids.site["S_target"]], site_xpos[ids.site["nail_goal"]]
        goal_distance = xp.linalg.norm(nail - goal)
        reward = (palm_sign * 0.1 * xp.linalg.norm(palm - hamm) - xp.linalg.norm(head - nail) - 10.0 * goal_distance
                  - 1e-2 * xp.linalg.norm(qvel) + 2.0 * ((hamm[2] > 0.04) & (head[2] > 0.04))
                  + 25.0 * (goal_distance < 0.020) + 75.0 * (goal_distance < 0.010))
        return reward, goal_distance < 0.01, xp.zeros((), bool)
    raise ValueError(task)


def sample_layout(task: str, key: jax.Array, sys_value: jax.Array) -> jax.Array:
    """The per-episode model row gymnasium-robotics' ``reset_model`` draws: pen ``body_quat[target]``, door
    ``body_pos[frame]``, hammer ``body_pos[nail_board]`` (only z random). ``sys_value`` is the model's own row."""
    if task == "pen":
        roll_pitch = jax.random.uniform(key, (2,), minval=-1.0, maxval=1.0)
        return euler2quat(jnp.concatenate([roll_pitch, jnp.zeros(1)]))
    if task == "door":
        lo, hi = jnp.array([-0.3, 0.25, 0.252]), jnp.array([-0.2, 0.35, 0.35])
        return jax.random.uniform(key, (3,), minval=lo, maxval=hi)
    if task == "hammer":
        return jnp.asarray(sys_value).at[2].set(jax.random.uniform(key, (), minval=0.1, maxval=0.25))  # (or numpy)
    raise ValueError(task)


LAYOUT = {"pen": ("body_quat", "target"), "door": ("body_pos", "frame"), "hammer": ("body_pos", "nail_board")}


class Adroit(PipelineEnv):
    """An Adroit task (``"pen"``, ``"door"``, ``"hammer"``) on Brax's MJX pipeline; see the module docstring.

    ``d4rl_reward`` switches to D4RL's ``hand_dapg`` reward sign and pen drop termination. Other keyword arguments
    (MJX contact bounds, solver caps) go to ``adroit_xml``.
    """

    def __init__(self, task: str = "pen", backend: str = "mjx", d4rl_reward: bool = False, **xml_kwargs):
        if backend != "mjx":
            raise ValueError(f"Adroit runs on the mjx backend only, not {backend!r}.")
        get_task(task)
        model = load_capsule_model(task, **xml_kwargs)
        super().__init__(sys=mjcf.load_model(model), backend=backend, n_frames=FRAME_SKIP)
        self.task = task
        self._ids = task_ids(task, model)
        self._act_mean = jnp.asarray(np.mean(model.actuator_ctrlrange, axis=1), jnp.float32)
        self._act_rng = jnp.asarray(0.5 * (model.actuator_ctrlrange[:, 1] - model.actuator_ctrlrange[:, 0]),
                                    jnp.float32)
        self._d4rl_reward = d4rl_reward
        field, body = LAYOUT[task]
        self._layout_field = field
        self._layout_body = self._ids.body[body]

    def sys_for(self, layout: jax.Array):
        """``sys`` with this episode's layout row (gymnasium-robotics writes it into the model at reset)."""
        value = jnp.asarray(getattr(self.sys, self._layout_field))
        return self.sys.replace(**{self._layout_field: value.at[self._layout_body].set(layout)})

    def reset(self, rng: jax.Array) -> State:
        own = jnp.asarray(getattr(self.sys, self._layout_field))[self._layout_body]
        layout = sample_layout(self.task, rng, own)
        return self.reset_to(layout, self.sys.qpos0, jnp.zeros(self.sys.nv))

    def reset_to(self, layout: jax.Array, qpos: jax.Array, qvel: jax.Array) -> State:
        """An episode from a given layout row and physics state (tests and checks use it)."""
        pipeline_state = self._pipeline.init(self.sys_for(layout), qpos, qvel, None, None, self._debug)
        obs = self._obs(pipeline_state)
        zero = jnp.zeros(())
        _, success, _ = self._reward(pipeline_state)
        metrics = {"success": success.astype(jnp.float32)}
        return State(pipeline_state, obs, zero, zero, metrics, {"layout": layout})

    def step(self, state: State, action: jax.Array) -> State:
        ctrl = self._act_mean + jnp.clip(action, -1.0, 1.0) * self._act_rng
        sys = self.sys_for(state.info["layout"])

        def frame(ps, _):
            return self._pipeline.step(sys, ps, ctrl, self._debug), None

        pipeline_state = jax.lax.scan(frame, state.pipeline_state, (), self._n_frames)[0]
        reward, success, dropped = self._reward(pipeline_state)
        finite = jnp.all(jnp.isfinite(pipeline_state.qpos)) & jnp.all(jnp.isfinite(pipeline_state.qvel))
        done = 1.0 - finite.astype(jnp.float32)
        if self._d4rl_reward:
            done = jnp.maximum(done, dropped.astype(jnp.float32))
        obs = jnp.where(finite, self._obs(pipeline_state), 0.0)
        metrics = {**state.metrics, "success": jnp.where(finite, success, False).astype(jnp.float32)}
        return state.replace(pipeline_state=pipeline_state, obs=obs, reward=jnp.where(finite, reward, 0.0),
                             done=done, metrics=metrics)

    def _obs(self, d) -> jax.Array:
        return observation(self.task, self._ids, d.qpos, d.qvel, d.xpos, d.xquat, d.site_xpos, d.sensordata)

    def _reward(self, d):
        return reward_and_success(self.task, self._ids, d.qpos, d.qvel, d.xpos, d.site_xpos, self._d4rl_reward)

    @property
    def observation_size(self) -> int:
        return get_task(self.task).obs_size

    @property
    def action_size(self) -> int:
        return get_task(self.task).act_size
