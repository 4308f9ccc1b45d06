"""PK, PR, PU, TP: the success predicates on hand-made states (resets and experts: test_tasks.py)."""
import numpy as np

from envs import panda
from envs.tasks import put_knife_on_chopping_board as pk
from envs.tasks import put_rubbish_in_bin as pr
from envs.tasks import put_umbrella_in_umbrella_stand as pu
from envs.tasks import take_plate_off_colored_dish_rack as tp
from envs.tasks.base import planar_offset
from task_helpers import judge, task

TOP = panda.TABLE_HEIGHT


def _grip(t, qpos, opening):
    for joint in panda.FINGER_JOINTS:
        qpos[..., t.qpos_addr(joint)] = opening


def test_knife_success_needs_placing_then_release():
    t = task("put_knife_on_chopping_board")
    s = t.reset(0)
    board, yaw = s.params["board"], s.params["board_yaw"]
    on = s.qpos.copy()
    t.set_free(on, "knife", (*board, pk.BOARD_TOP + pk.HANDLE[2]), yaw)
    held, open_ = on.copy(), on.copy()
    _grip(t, held, 0.011)
    _grip(t, open_, panda.GRIPPER_OPEN)
    assert judge(t, s, [held, open_]) == [False, True]
    assert judge(t, s, [open_, open_]) == [False, False]  # never lay there in the gripper
    lifted = held.copy()
    t.set_free(lifted, "knife", (*board, pk.BOARD_TOP + 0.1), yaw)
    assert judge(t, s, [held, lifted]) == [False, False]  # carried away, not released on the board
    crossways = held.copy(), open_.copy()
    for q in crossways:
        t.set_free(q, "knife", (*board, pk.BOARD_TOP + pk.HANDLE[2]), yaw + np.pi / 2)  # ends overhang
    assert judge(t, s, list(crossways)) == [False, False]
    assert judge(t, s, [s.qpos]) == [False]


def test_rubbish_success_inside_bin_only():
    t = task("put_rubbish_in_bin")
    s = t.reset(1)
    bin_xy = planar_offset(s.params["base"], s.params["yaw"], pr.BIN)
    inside, above, start = s.qpos.copy(), s.qpos.copy(), s.qpos.copy()
    t.set_free(inside, "rubbish", (*bin_xy, TOP + 0.04))
    _grip(t, inside, 0.02)  # release is not required
    t.set_free(above, "rubbish", (*bin_xy, TOP + pr.BIN_H + 0.05))
    assert judge(t, s, [inside, above, start]) == [True, False, False]
    beside = s.qpos.copy()
    t.set_free(beside, "rubbish", (*(bin_xy + [0.0, pr.BIN_IN + 0.03]), TOP + 0.04))
    assert judge(t, s, [beside]) == [False]


def test_umbrella_success_in_stand_and_released():
    t = task("put_umbrella_in_umbrella_stand")
    s = t.reset(2)
    stand_xy = planar_offset(s.params["base"], s.params["yaw"], pu.STAND)
    inside = s.qpos.copy()
    t.set_free(inside, "umbrella", (*stand_xy, TOP + 0.012 + pu.TIP), s.params["yaw"])
    grasped = inside.copy()
    _grip(t, grasped, 0.012)
    hovering = inside.copy()
    t.set_free(hovering, "umbrella", (*stand_xy, TOP + pu.STAND_H + pu.TIP), s.params["yaw"])
    assert judge(t, s, [inside, grasped, hovering, s.qpos]) == [True, False, False, False]


def test_plate_success_off_rack_on_table_released():
    t = task("take_plate_off_colored_dish_rack")
    s = t.reset(3)
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
    assert judge(t, s, [standing, lying, held, raised, s.qpos]) == [True, True, False, False, False]
