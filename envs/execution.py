"""Executing motions: camera-frame poses -> IK joint targets -> controls -> physics rollouts.

The pipeline (docs/method.md, "Execution and success"):

1. :func:`plan` turns each motion's 101 camera-frame poses into world TCP targets and
   solves IK for them in order (damped least squares, warm-started, jit + vmap, the
   motions split over the local devices). A waypoint the IK cannot reach is skipped;
   once more than ``max_failed_waypoints`` have failed the motion is abandoned.
2. :func:`controls` holds every waypoint for ``substeps`` physics steps: the arm's
   position targets ramp linearly to the waypoint over ``ramp_steps``, then the gripper
   command (open if grasp > 0.5) is applied.
3. A back-end runs the same controls from the same initial states and records ``qpos``
   after every waypoint: ``"mujoco"`` (native, ``mujoco.rollout`` with one thread per
   core; the default on CPU) or ``"mjx"`` (``vmap`` over episodes, ``lax.scan`` over
   steps; the default on accelerators).
4. A task's success predicate, a function of those ``qpos`` records, is evaluated after
   every waypoint; an episode succeeds if it held after any valid waypoint.
"""
from __future__ import annotations

import contextlib
import copy
import dataclasses
import functools
import io
import os
from typing import Callable

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from envs import motion as motion_lib
from envs.camera import Camera, front_camera
from envs.kinematics import ArmChain, IKConfig, solve_ik_path
from envs.panda import ARM_JOINTS, GRIPPER_OPEN, HOME_QPOS

BACKENDS = ("mujoco", "mjx")


@dataclasses.dataclass(frozen=True)
class ExecutionConfig:
    substeps: int = 25  # physics steps per waypoint (0.1 s at the 4 ms time step)
    ramp_steps: int = 15  # arm targets ramp over these; the gripper command follows them
    max_failed_waypoints: int = 10
    ik: IKConfig = IKConfig()


@dataclasses.dataclass(frozen=True)
class SceneBatch:
    """Initial states of E episodes of one scene family.

    ``qpos [E, nq]``; optionally per-episode ``body_pos [E, nbody, 3]`` and
    ``body_quat [E, nbody, 4]`` for scenes whose fixed bodies are randomised.
    """

    qpos: np.ndarray
    body_pos: np.ndarray | None = None
    body_quat: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.qpos)

    def take(self, index) -> "SceneBatch":
        pick = lambda a: None if a is None else a[index]
        return SceneBatch(self.qpos[index], pick(self.body_pos), pick(self.body_quat))

    def model_for(self, model: mujoco.MjModel, e: int) -> mujoco.MjModel:
        """``model`` with episode ``e``'s body placements (``model`` itself if not randomised)."""
        if self.body_pos is None and self.body_quat is None:
            return model
        m = copy.copy(model)
        if self.body_pos is not None:
            m.body_pos[:] = self.body_pos[e]
        if self.body_quat is not None:
            m.body_quat[:] = self.body_quat[e]
        return m


#: ``success_fn(qpos [E, W, nq], scenes) -> bool [E, W]``: a task's predicate after each waypoint.
SuccessFn = Callable[[np.ndarray, SceneBatch], np.ndarray]


class World:
    """A compiled scene with its camera, arm chain and actuator layout."""

    def __init__(self, model: mujoco.MjModel, image_size: int = 256):
        self.model = model
        self.camera: Camera = front_camera(model, image_size)
        self.chain = ArmChain.from_model(model)
        act_names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_ACTUATOR, i) for i in range(model.nu)]
        expected = [f"act_{j}" for j in ARM_JOINTS] + ["act_gripper"]
        if act_names != expected:
            raise ValueError(f"World expects actuators {expected}, the model has {act_names}")

    @functools.cached_property
    def mjx_model(self):
        """The model on the JAX device, made on first use."""
        return _import_mjx().put_model(self.model)

    @classmethod
    def from_xml(cls, xml: str, image_size: int = 256) -> "World":
        return cls(mujoco.MjModel.from_xml_string(xml), image_size)

    def home_qpos(self) -> np.ndarray:
        """The model's ``qpos0`` with the arm at home and the gripper open."""
        qpos = self.model.qpos0.copy()
        qpos[self.chain.qpos_index] = HOME_QPOS
        for name in ("finger_left", "finger_right"):
            qpos[self.model.joint(name).qposadr[0]] = GRIPPER_OPEN
        return qpos

    def default_scenes(self, n: int = 1) -> SceneBatch:
        return SceneBatch(np.tile(self.home_qpos(), (n, 1)))


@dataclasses.dataclass(frozen=True)
class Plan:
    """Per episode and waypoint: ``arm_targets [E, W, 7]``, ``gripper [E, W]`` (finger
    opening in metres), ``reached [E, W]`` (IK within tolerance), ``valid [E, W]``
    (executed before the motion was abandoned), ``abandoned [E]``."""

    arm_targets: np.ndarray
    gripper: np.ndarray
    reached: np.ndarray
    valid: np.ndarray
    abandoned: np.ndarray


@functools.partial(jax.jit, static_argnames=("chain", "image_size", "ik", "devices"))
def _plan_jit(motions, q_start, camera_pos, camera_rot, intrinsics, *, chain, image_size, ik, devices):
    def paths(motions, q_start):
        pos, rot, _ = motion_lib.vector_to_pose(motions, camera_pos, camera_rot, intrinsics, image_size)
        return jax.vmap(lambda p, r, q: solve_ik_path(chain, p, r, q, ik))(pos, rot, q_start)

    if devices == 1:
        return paths(motions, q_start)
    mesh = jax.sharding.Mesh(np.asarray(jax.local_devices()[:devices]), ("motions",))
    spec = jax.sharding.PartitionSpec("motions")
    return jax.shard_map(paths, mesh=mesh, in_specs=(spec, spec), out_specs=spec)(motions, q_start)


def _check_motions(motions: np.ndarray) -> np.ndarray:
    motions = np.asarray(motions, np.float32)
    if motions.ndim == 2:
        motions = motions[None]
    if motions.ndim != 3 or motions.shape[-1] != motion_lib.POSE_DIM:
        raise ValueError(
            f"motions must be [E, T, {motion_lib.POSE_DIM}] (or [T, {motion_lib.POSE_DIM}]), got shape {motions.shape}"
        )
    if not np.all(np.isfinite(motions)):
        raise ValueError("motions contain NaN or inf")
    return motions


def plan(world: World, motions: np.ndarray, scenes: SceneBatch, config: ExecutionConfig = ExecutionConfig()) -> Plan:
    """IK for every waypoint of ``motions [E, W, 11]`` from each scene's arm posture."""
    motions = _check_motions(motions)
    if len(motions) != len(scenes):
        raise ValueError(f"{len(motions)} motions for {len(scenes)} scenes")
    cam = world.camera
    q_start = scenes.qpos[:, world.chain.qpos_index]
    # Each motion's IK runs on one thread; with the CPU cores exposed as devices
    # (envs.platform.expose_cpu_cores_as_devices) each device solves its share of the motions
    # (padded to a multiple of the device count with copies of the last), the same numbers.
    e, devices = len(motions), min(len(jax.local_devices()), len(motions))
    pad = -e % devices
    qs, reached = _plan_jit(
        jnp.asarray(np.concatenate([motions, np.repeat(motions[-1:], pad, 0)])),
        jnp.asarray(np.concatenate([q_start, np.repeat(q_start[-1:], pad, 0)]), jnp.float32),
        jnp.asarray(cam.position, jnp.float32), jnp.asarray(cam.rotation, jnp.float32),
        jnp.asarray(cam.intrinsics, jnp.float32),
        chain=world.chain, image_size=cam.image_size, ik=config.ik, devices=devices,
    )
    qs, reached = qs[:e], np.asarray(reached)[:e]
    failed = np.cumsum(~reached, axis=1)
    valid = failed <= config.max_failed_waypoints
    # A skipped waypoint applies neither its arm target nor its gripper command.
    grasp = motions[..., motion_lib.GRASP][..., 0]
    opening = np.where(grasp > 0.5, GRIPPER_OPEN, 0.0)
    gripper = np.empty_like(opening)
    prev = scenes.qpos[:, world.model.joint("finger_left").qposadr[0]]
    for w in range(opening.shape[1]):
        prev = np.where(reached[:, w] & valid[:, w], opening[:, w], prev)
        gripper[:, w] = prev
    arm = np.asarray(qs, np.float64)
    # After abandonment everything holds where the last valid waypoint left it.
    last_valid = np.maximum(valid.sum(axis=1) - 1, 0)
    for e in np.nonzero(~valid.all(axis=1))[0]:
        arm[e, last_valid[e] + 1:] = arm[e, last_valid[e]]
        gripper[e, last_valid[e] + 1:] = gripper[e, last_valid[e]]
    return Plan(arm, gripper, reached, valid, ~valid.all(axis=1))


def controls(p: Plan, q_start: np.ndarray, grip_start: np.ndarray, config: ExecutionConfig = ExecutionConfig()) -> np.ndarray:
    """Plan -> per-step controls ``[E, W, substeps, 8]`` (7 joint targets, finger opening)."""
    e, w, _ = p.arm_targets.shape
    prev_arm = np.concatenate([q_start[:, None], p.arm_targets[:, :-1]], axis=1)
    prev_grip = np.concatenate([grip_start[:, None], p.gripper[:, :-1]], axis=1)
    s = np.arange(config.substeps)
    alpha = np.minimum((s + 1) / config.ramp_steps, 1.0)[None, None, :, None]
    arm = prev_arm[:, :, None] + alpha * (p.arm_targets - prev_arm)[:, :, None]
    grip = np.where(s[None, None] < config.ramp_steps, prev_grip[..., None], p.gripper[..., None])
    return np.concatenate([arm, grip[..., None]], axis=-1)


# ----------------------------------------------------------------------------- back-ends
def rollout_mujoco(world: World, scenes: SceneBatch, ctrl: np.ndarray, threads: int | None = None) -> np.ndarray:
    """Native MuJoCo: ``ctrl [E, W, S, nu]`` -> ``qpos [E, W, nq]`` after each waypoint."""
    from mujoco import rollout

    model = world.model
    e, w, s, nu = ctrl.shape
    threads = threads or os.cpu_count() or 1
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    models = [scenes.model_for(model, i) for i in range(e)]
    data = mujoco.MjData(model)
    init = np.empty((e, mujoco.mj_stateSize(model, spec)))
    for i, m in enumerate(models):
        mujoco.mj_resetData(m, data)
        data.qpos[:] = scenes.qpos[i]
        mujoco.mj_forward(m, data)
        mujoco.mj_getState(m, data, init[i], spec)
    datas = [mujoco.MjData(model) for _ in range(min(threads, e))]
    state, _ = rollout.rollout(models, datas, init, ctrl.reshape(e, w * s, nu))
    # FULLPHYSICS state = [time, qpos, qvel, act, ...]
    return state[:, s - 1 :: s, 1 : 1 + model.nq]


def _import_mjx():
    """``mujoco.mjx``, imported quietly: it prints a notice when the optional Warp back-end is absent."""
    with contextlib.redirect_stdout(io.StringIO()):
        from mujoco import mjx
    return mjx


@jax.jit
def _mjx_rollout(mjx_model, qpos, body_pos, body_quat, ctrl):
    mjx = _import_mjx()

    def episode(q0, bp, bq, ctrl_e):
        m = mjx_model.replace(body_pos=bp, body_quat=bq)
        # No forward pass first: each step computes its own from qpos and qvel (the same numbers
        # bit for bit), and tracing MJX's pipeline once less saves seconds of compilation.
        d = mjx.make_data(m).replace(qpos=q0)

        def waypoint(d, ctrl_w):
            d, _ = jax.lax.scan(lambda d, c: (mjx.step(m, d.replace(ctrl=c)), None), d, ctrl_w)
            return d, d.qpos

        _, qs = jax.lax.scan(waypoint, d, ctrl_e)
        return qs

    return jax.vmap(episode)(qpos, body_pos, body_quat, ctrl)


def rollout_mjx(world: World, scenes: SceneBatch, ctrl: np.ndarray) -> np.ndarray:
    """MJX: the same contract as :func:`rollout_mujoco`, batched with ``vmap`` (float32)."""
    model = world.model
    e = ctrl.shape[0]
    body_pos = scenes.body_pos if scenes.body_pos is not None else np.broadcast_to(model.body_pos, (e, *model.body_pos.shape))
    body_quat = scenes.body_quat if scenes.body_quat is not None else np.broadcast_to(model.body_quat, (e, *model.body_quat.shape))
    qs = _mjx_rollout(
        world.mjx_model, jnp.asarray(scenes.qpos, jnp.float32), jnp.asarray(body_pos, jnp.float32),
        jnp.asarray(body_quat, jnp.float32), jnp.asarray(ctrl, jnp.float32),
    )
    return np.asarray(qs, np.float64)


def default_backend() -> str:
    """Native MuJoCo on CPU (far faster there), MJX on accelerators."""
    return "mujoco" if jax.default_backend() == "cpu" else "mjx"


# ----------------------------------------------------------------------------- execute
@dataclasses.dataclass(frozen=True)
class ExecutionResult:
    """``success [E]``; per waypoint ``success_after [E, W]``, ``reached [E, W]``,
    ``valid [E, W]``; ``abandoned [E]``; ``qpos [E, W, nq]`` after each waypoint."""

    success: np.ndarray
    success_after: np.ndarray
    reached: np.ndarray
    valid: np.ndarray
    abandoned: np.ndarray
    qpos: np.ndarray


def execute(
    world: World,
    motions: np.ndarray,
    scenes: SceneBatch,
    success_fn: SuccessFn,
    backend: str = "auto",
    config: ExecutionConfig = ExecutionConfig(),
    threads: int | None = None,
) -> ExecutionResult:
    """Run ``motions [E, W, 11]`` in their ``scenes`` and judge them with ``success_fn``.
    ``threads``: native back-end threads (default: one per core)."""
    if backend == "auto":
        backend = default_backend()
    if backend not in BACKENDS:
        raise ValueError(f"unknown back-end {backend!r}; expected one of {BACKENDS} or 'auto'")
    p = plan(world, motions, scenes, config)
    grip_start = scenes.qpos[:, world.model.joint("finger_left").qposadr[0]]
    ctrl = controls(p, scenes.qpos[:, world.chain.qpos_index], grip_start, config)
    if backend == "mujoco":
        qpos = rollout_mujoco(world, scenes, ctrl, threads)
    else:
        qpos = rollout_mjx(world, scenes, ctrl)
    after = np.asarray(success_fn(qpos, scenes), bool) & p.valid
    return ExecutionResult(after.any(axis=1), after, p.reached, p.valid, p.abandoned, qpos)
