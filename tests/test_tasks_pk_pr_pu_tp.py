"""PK, PR, PU, TP: seeded resets, the success predicates on hand-made states, the experts (native)."""
import functools

import numpy as np
import pytest

from envs import execution, panda
from envs.tasks import put_knife_on_chopping_board as pk
from envs.tasks import put_rubbish_in_bin as pr
from envs.tasks import put_umbrella_in_umbrella_stand as pu
from envs.tasks import take_plate_off_colored_dish_rack as tp
from envs.tasks.base import planar_offset

CLASSES = {
    "PK": pk.PutKnifeOnChoppingBoard, "PR": pr.PutRubbishInBin,
    "PU": pu.PutUmbrellaInUmbrellaStand, "TP": tp.TakePlateOffColoredDishRack,
}
TOP = panda.TABLE_HEIGHT


@functools.cache
def _task(abbr):
    return CLASSES[abbr]()


def _grip(task, qpos, opening):
    for joint in panda.FINGER_JOINTS:
        qpos[..., task.qpos_addr(joint)] = opening


def _judge(task, scene, states):
    """``states``: qpos ``[W, nq]`` of one episode -> success after each waypoint."""
    return task.success(np.asarray(states)[None], task.batch([scene]))[0].tolist()


@pytest.mark.parametrize("abbr", list(CLASSES))
def test_reset_is_seeded(abbr):
    t = _task(abbr)
    a, b, c = t.reset(3), t.reset(3), t.reset(4)
    for field in ("qpos", "body_pos", "body_quat"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert not (np.allclose(a.qpos, c.qpos) and np.allclose(a.body_pos, c.body_pos)
                and np.allclose(a.body_quat, c.body_quat))
    # Placements really vary: the randomised fixed bodies move between seeds.
    moved = np.abs(a.body_pos - c.body_pos).max(axis=1) > 1e-3
    assert moved.any()


def test_knife_success_needs_placing_then_release():
    t, s = _task("PK"), _task("PK").reset(0)
    board, yaw = s.params["board"], s.params["board_yaw"]
    on = s.qpos.copy()
    t.set_free(on, "knife", (*board, pk.BOARD_TOP + pk.HANDLE[2]), yaw)
    held, open_ = on.copy(), on.copy()
    _grip(t, held, 0.011)
    _grip(t, open_, panda.GRIPPER_OPEN)
    assert _judge(t, s, [held, open_]) == [False, True]
    assert _judge(t, s, [open_, open_]) == [False, False]  # never lay there in the gripper
    lifted = held.copy()
    t.set_free(lifted, "knife", (*board, pk.BOARD_TOP + 0.1), yaw)
    assert _judge(t, s, [held, lifted]) == [False, False]  # carried away, not released on the board
    crossways = held.copy(), open_.copy()
    for q in crossways:
        t.set_free(q, "knife", (*board, pk.BOARD_TOP + pk.HANDLE[2]), yaw + np.pi / 2)  # ends overhang
    assert _judge(t, s, list(crossways)) == [False, False]
    assert _judge(t, s, [s.qpos]) == [False]


def test_rubbish_success_inside_bin_only():
    t, s = _task("PR"), _task("PR").reset(1)
    bin_xy = planar_offset(s.params["base"], s.params["yaw"], pr.BIN)
    inside, above, start = s.qpos.copy(), s.qpos.copy(), s.qpos.copy()
    t.set_free(inside, "rubbish", (*bin_xy, TOP + 0.04))
    _grip(t, inside, 0.02)  # release is not required
    t.set_free(above, "rubbish", (*bin_xy, TOP + pr.BIN_H + 0.05))
    assert _judge(t, s, [inside, above, start]) == [True, False, False]
    beside = s.qpos.copy()
    t.set_free(beside, "rubbish", (*(bin_xy + [0.0, pr.BIN_IN + 0.03]), TOP + 0.04))
    assert _judge(t, s, [beside]) == [False]


def test_umbrella_success_in_stand_and_released():
    t, s = _task("PU"), _task("PU").reset(2)
    stand_xy = planar_offset(s.params["base"], s.params["yaw"], pu.STAND)
    inside = s.qpos.copy()
    t.set_free(inside, "umbrella", (*stand_xy, TOP + 0.012 + pu.TIP), s.params["yaw"])
    grasped = inside.copy()
    _grip(t, grasped, 0.012)
    hovering = inside.copy()
    t.set_free(hovering, "umbrella", (*stand_xy, TOP + pu.STAND_H + pu.TIP), s.params["yaw"])
    assert _judge(t, s, [inside, grasped, hovering, s.qpos]) == [True, False, False, False]


def test_plate_success_off_rack_on_table_released():
    t, s = _task("TP"), _task("TP").reset(3)
    yaw = s.params["yaw"]
    beside_xy = planar_offset(s.params["rack"], s.params["yaw"], (-tp.MOVE, tp.SLOTS[tp.SLOT]))
    standing = s.qpos.copy()
    t.set_free(standing, "plate", (*beside_xy, TOP + tp.PLATE[2]), yaw)
    lying = s.qpos.copy()
    a = t.qpos_addr("plate")
    lying[a:a + 3] = (*beside_xy, TOP + tp.PLATE[1])
    lying[a + 3:a + 7] = (np.sqrt(0.5), np.sqrt(0.5), 0.0, 0.0)  # flat on its face
    held = standing.copy()
    _grip(t, held, 0.006)
    raised = s.qpos.copy()
    t.set_free(raised, "plate", (*beside_xy, TOP + tp.PLATE[2] + 0.1), yaw)
    assert _judge(t, s, [standing, lying, held, raised, s.qpos]) == [True, True, False, False, False]


@pytest.mark.parametrize("abbr", list(CLASSES))
def test_expert_succeeds_natively(abbr):
    t = _task(abbr)
    scenes = [t.reset(seed) for seed in (0, 1, 2)]
    motions = np.stack([t.expert_motion(s) for s in scenes])
    result = execution.execute(t.world, motions, t.batch(scenes), t.success, "mujoco")
    assert result.success.all(), result.success
    assert result.reached.all()
    # Not at the start: the object had to be moved there.
    assert not result.success_after[:, 0].any()
