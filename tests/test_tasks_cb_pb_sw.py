"""CB, PB, SW: the success predicates on hand-made states (resets and experts: test_tasks.py)."""
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from envs import panda
from envs.kinematics import solve_ik
from envs.tasks import close_box as cb
from envs.tasks import push_button as pb
from envs.tasks import stack_wine as sw
from task_helpers import judge, task

TOP = panda.TABLE_HEIGHT


def test_close_box_success_needs_the_lid_turned_by_2_6_rad():
    t = task("close_box")
    s = t.reset(0)
    lid = t.qpos_addr("lid")
    assert s.qpos[lid] == pytest.approx(cb.OPEN)
    states = np.tile(s.qpos, (4, 1))
    states[:, lid] = [cb.OPEN, 1.5, cb.OPEN - cb.TURN + 0.02, 0.0]  # open, upright, nearly shut, shut
    assert judge(t, s, states) == [False, False, False, True]


def test_push_button_success_needs_3_mm():
    t = task("push_button")
    s = t.reset(0)
    button = t.qpos_addr("button")
    states = np.tile(s.qpos, (4, 1))
    states[:, button] = [0.0, 0.002, 0.004, pb.TRAVEL]
    assert judge(t, s, states) == [False, False, True, True]


def _lying_quat(yaw):
    """Bottle axis (its local z) along the slot, i.e. along the rack's turned x axis."""
    x, y, z, w = Rotation.from_euler("ZY", [yaw, np.pi / 2]).as_quat()
    return np.array([w, x, y, z])


def _put_bottle(t, qpos, pos, quat):
    a = t.qpos_addr("bottle")
    qpos[a:a + 3], qpos[a + 3:a + 7] = pos, quat


def test_stack_wine_success_inside_the_slot_only():
    t = task("stack_wine")
    s = t.reset(2)
    yaw = s.params["yaw"]
    _, rack = t._layout(s.params)
    slot = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    across = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
    centre = np.array([*rack, TOP + sw.SLOT_Z])
    lying = _lying_quat(yaw)
    cases = [
        (centre, lying, True),
        (centre + 0.02 * slot, _lying_quat(yaw + np.pi), True),  # either end first
        (centre + 0.06 * slot, lying, False),  # off the cradles
        (centre + 0.03 * across, lying, False),  # on a rail
        (centre + [0, 0, 0.05], lying, False),  # above the slot
        (centre, _lying_quat(yaw + np.pi / 2), False),  # across the slot
        (centre, s.qpos[t.qpos_addr("bottle") + 3:t.qpos_addr("bottle") + 7], False),  # upright
    ]
    states = []
    for pos, quat, _ in cases:
        q = s.qpos.copy()
        _put_bottle(t, q, pos, quat)
        states.append(q)
    assert judge(t, s, states) == [want for *_, want in cases]
    assert judge(t, s, [s.qpos]) == [False]


def test_stack_wine_counts_a_bottle_still_held_in_the_slot():
    """RLBench does not require the release: the bottle in the slot between closed fingers,
    the arm posed by IK over it, is a success."""
    t = task("stack_wine")
    s = t.reset(5)
    yaw = s.params["yaw"]
    _, rack = t._layout(s.params)
    centre = np.array([*rack, TOP + sw.SLOT_Z])
    rot = Rotation.from_euler("z", yaw).as_matrix() @ np.diag([1.0, -1.0, -1.0])
    q_arm, reached, _, _ = solve_ik(t.world.chain, jnp.asarray(centre - [0, 0, 0.01], jnp.float32),
                                    jnp.asarray(rot, jnp.float32), jnp.asarray(panda.HOME_QPOS, jnp.float32))
    assert bool(reached)
    q = s.qpos.copy()
    q[t.world.chain.qpos_index] = np.asarray(q_arm)
    for joint in panda.FINGER_JOINTS:
        q[t.qpos_addr(joint)] = sw.HALF
    _put_bottle(t, q, centre, _lying_quat(yaw))
    assert t.held(q[None], centre[None], sw.HALF)[0]
    assert judge(t, s, [q]) == [True]
