"""Forward and inverse kinematics of the Panda's tool-centre point, in JAX.

The kinematic chain (body offsets, joint axes and limits) is read from the compiled
MuJoCo model, so the MJCF is the only place it is written down. Everything here is
pure, ``jit``- and ``vmap``-able.
"""
from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from envs.panda import ARM_JOINTS, HOME_QPOS, TCP_SITE


def _quat_to_mat(q: np.ndarray) -> np.ndarray:
    out = np.zeros(9)
    mujoco.mju_quat2Mat(out, np.asarray(q, np.float64))
    return out.reshape(3, 3)


def _axis_angle(axis: jnp.ndarray, angle: jnp.ndarray) -> jnp.ndarray:
    """Rodrigues' rotation about a unit ``axis [3]`` by ``angle``."""
    x, y, z = axis
    k = jnp.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return jnp.eye(3) + jnp.sin(angle) * k + (1.0 - jnp.cos(angle)) * (k @ k)


@dataclasses.dataclass(frozen=True, eq=False)  # hashed by identity: a static jit argument
class ArmChain:
    """Static description of the 7-joint chain from the world to the TCP site.

    Attributes (all numpy, float64 in, used as float32 constants in JAX):
      base_pos ``[3]``, base_rot ``[3, 3]``: world pose of the parent of the first link.
      link_pos ``[7, 3]``, link_rot ``[7, 3, 3]``: each link's offset in its parent.
      joint_axis ``[7, 3]``: hinge axes in the link frames.
      tip_pos ``[3]``, tip_rot ``[3, 3]``: the TCP site in the last link's frame (through
        any fixed bodies in between, e.g. the hand).
      lower, upper ``[7]``: joint limits.
      qpos_index ``[7]``: the joints' addresses in ``qpos``.
    """

    base_pos: np.ndarray
    base_rot: np.ndarray
    link_pos: np.ndarray
    link_rot: np.ndarray
    joint_axis: np.ndarray
    tip_pos: np.ndarray
    tip_rot: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    qpos_index: np.ndarray

    @classmethod
    def from_model(cls, model: mujoco.MjModel) -> "ArmChain":
        joint_ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in ARM_JOINTS]
        bodies = [int(model.jnt_bodyid[j]) for j in joint_ids]
        for j, body in zip(joint_ids, bodies):
            if model.jnt_type[j] != mujoco.mjtJoint.mjJNT_HINGE or np.any(model.jnt_pos[j] != 0):
                raise ValueError("ArmChain expects hinge joints at their bodies' origins")
        data = mujoco.MjData(model)
        mujoco.mj_kinematics(model, data)  # at qpos0 every parent is placed by its fixed offsets
        parent = int(model.body_parentid[bodies[0]])
        site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, TCP_SITE)
        # The TCP site relative to the last link, read at qpos0 where the last joint is at 0.
        last_rot = data.xmat[bodies[-1]].reshape(3, 3)
        last_pos = data.xpos[bodies[-1]]
        joint_q0 = model.qpos0[model.jnt_qposadr[joint_ids[-1]]]
        undo = _quat_to_mat(_axis_quat(model.jnt_axis[joint_ids[-1]], -joint_q0))
        site_rot_in_last = last_rot.T @ data.site_xmat[site].reshape(3, 3)
        site_pos_in_last = last_rot.T @ (data.site_xpos[site] - last_pos)
        return cls(
            base_pos=data.xpos[parent].copy(),
            base_rot=data.xmat[parent].reshape(3, 3).copy(),
            link_pos=np.stack([model.body_pos[b] for b in bodies]),
            link_rot=np.stack([_quat_to_mat(model.body_quat[b]) for b in bodies]),
            joint_axis=np.stack([model.jnt_axis[j] for j in joint_ids]),
            tip_pos=undo @ site_pos_in_last,
            tip_rot=undo @ site_rot_in_last,
            lower=np.array([model.jnt_range[j, 0] for j in joint_ids]),
            upper=np.array([model.jnt_range[j, 1] for j in joint_ids]),
            qpos_index=np.array([model.jnt_qposadr[j] for j in joint_ids]),
        )


def _axis_quat(axis: np.ndarray, angle: float) -> np.ndarray:
    quat = np.zeros(4)
    mujoco.mju_axisAngle2Quat(quat, np.asarray(axis, np.float64), float(angle))
    return quat


def forward_kinematics(chain: ArmChain, q: jnp.ndarray):
    """Joint angles ``q [7]`` -> (tcp position ``[3]``, tcp rotation ``[3, 3]``,
    joint positions ``[7, 3]``, joint axes ``[7, 3]``), all in world coordinates."""
    pos = jnp.asarray(chain.base_pos, jnp.float32)
    rot = jnp.asarray(chain.base_rot, jnp.float32)
    joint_pos, joint_axis = [], []
    for i in range(len(chain.link_pos)):
        pos = pos + rot @ jnp.asarray(chain.link_pos[i], jnp.float32)
        rot = rot @ jnp.asarray(chain.link_rot[i], jnp.float32)
        axis = jnp.asarray(chain.joint_axis[i], jnp.float32)
        joint_pos.append(pos)
        joint_axis.append(rot @ axis)
        rot = rot @ _axis_angle(axis, q[i])
    tcp_pos = pos + rot @ jnp.asarray(chain.tip_pos, jnp.float32)
    tcp_rot = rot @ jnp.asarray(chain.tip_rot, jnp.float32)
    return tcp_pos, tcp_rot, jnp.stack(joint_pos), jnp.stack(joint_axis)


def rotation_error(current: jnp.ndarray, target: jnp.ndarray) -> jnp.ndarray:
    """Angle (radians) of ``current^T target``."""
    cos = (jnp.trace(current.T @ target) - 1.0) / 2.0
    return jnp.arccos(jnp.clip(cos, -1.0, 1.0))


@dataclasses.dataclass(frozen=True)
class IKConfig:
    """Damped least squares settings. Tolerances decide whether a waypoint is reachable."""

    iterations: int = 60
    damping: float = 0.05
    rotation_weight: float = 0.5  # metres per radian in the stacked error
    max_step: float = 0.3  # radians per iteration, per joint
    nullspace_gain: float = 0.05  # pull towards the home posture in the Jacobian's null space
    position_tolerance: float = 0.01
    rotation_tolerance: float = 0.1


def solve_ik(chain: ArmChain, target_pos: jnp.ndarray, target_rot: jnp.ndarray, q_init: jnp.ndarray,
             config: IKConfig = IKConfig()):
    """One target pose ``([3], [3, 3])`` from ``q_init [7]`` -> (q ``[7]``, reached ``bool``,
    position error ``m``, rotation error ``rad``). Joint limits are enforced by clipping."""
    lower = jnp.asarray(chain.lower, jnp.float32)
    upper = jnp.asarray(chain.upper, jnp.float32)
    home = jnp.asarray(HOME_QPOS, jnp.float32)
    w = config.rotation_weight

    def at(i, q):
        # The loop carries q with its forward kinematics and errors: computed once per iteration,
        # read by both the stopping test and the next step.
        pos, rot, joint_pos, joint_axis = forward_kinematics(chain, q)
        return i, q, (pos, rot, joint_pos, joint_axis, target_pos - pos, rotation_error(rot, target_rot))

    def step(carry):
        i, q, (pos, rot, joint_pos, joint_axis, e_pos, _) = carry
        # Small-angle orientation error: 0.5 * sum_i current_i x target_i (columns).
        e_rot = 0.5 * jnp.sum(jnp.cross(rot.T, target_rot.T), axis=0)
        err = jnp.concatenate([e_pos, w * e_rot])
        jac = jnp.concatenate([jnp.cross(joint_axis, pos - joint_pos).T, w * joint_axis.T])  # [6, 7]
        jjt = jac @ jac.T + config.damping**2 * jnp.eye(6)
        pinv = jac.T @ jnp.linalg.inv(jjt)
        dq = pinv @ err + config.nullspace_gain * (jnp.eye(7) - pinv @ jac) @ (home - q)
        dq = jnp.clip(dq, -config.max_step, config.max_step)
        return at(i + 1, jnp.clip(q + dq, lower, upper))

    def not_done(carry):
        # Stop early once the pose is 10x tighter than the tolerances (warm starts converge in a few steps).
        i, _, (*_, e_pos, rot_err) = carry
        converged = (jnp.linalg.norm(e_pos) < 0.1 * config.position_tolerance) & (
            rot_err < 0.1 * config.rotation_tolerance)
        return (i < config.iterations) & ~converged

    _, q, (*_, e_pos, rot_err) = jax.lax.while_loop(not_done, step, at(0, jnp.asarray(q_init, jnp.float32)))
    pos_err = jnp.linalg.norm(e_pos)
    reached = (pos_err < config.position_tolerance) & (rot_err < config.rotation_tolerance)
    return q, reached, pos_err, rot_err


def solve_ik_path(chain: ArmChain, target_pos: jnp.ndarray, target_rot: jnp.ndarray, q_start: jnp.ndarray,
                  config: IKConfig = IKConfig()):
    """Waypoints ``[W, 3]``, ``[W, 3, 3]`` in order, each warm-started from the last reached
    solution -> (q ``[W, 7]``, reached ``[W]``). An unreached waypoint keeps the previous
    solution as its joint target (the executor skips it)."""

    def body(q_prev, target):
        q, reached, _, _ = solve_ik(chain, target[0], target[1], q_prev, config)
        q_keep = jnp.where(reached, q, q_prev)
        return q_keep, (q_keep, reached)

    _, (qs, reached) = jax.lax.scan(body, jnp.asarray(q_start, jnp.float32), (target_pos, target_rot))
    return qs, reached
