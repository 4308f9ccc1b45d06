"""Motion execution: planning, controls, the native and MJX back-ends, success bookkeeping."""
import mujoco
import numpy as np
import pytest

from envs import demo, execution
from envs import motion as M
from envs.execution import ExecutionConfig, controls, execute, plan
from helpers import run_on_two_devices

WORLD = demo.default_world(256)
PICK = demo.pick_cube_motion(WORLD)
LIFTED = demo.cube_lifted(WORLD)
CUBE = WORLD.model.joint("cube_free").qposadr[0]


def _unreachable(motion, waypoints):
    """Push the given waypoints 4 m deeper along the optical axis: out of the arm's reach."""
    bad = motion.copy()
    bad[waypoints, 2] += 4.0
    return bad


@pytest.fixture(scope="module")
def native():
    return execute(WORLD, PICK, WORLD.default_scenes(1), LIFTED, backend="mujoco")


def test_scripted_pick_succeeds_natively(native):
    assert native.success.tolist() == [True]
    assert native.reached.all() and native.valid.all() and not native.abandoned.any()
    # Success comes only once the cube has been lifted, near the end of the motion.
    first = int(np.argmax(native.success_after[0]))
    assert 70 < first < M.NUM_STEPS
    assert native.qpos[0, -1, CUBE + 2] > WORLD.model.qpos0[CUBE + 2] + 0.15


def test_mjx_agrees_with_native(native):
    """Same model, same controls: same verdict, and the cube ends within 1 cm.

    MJX runs in float32 with its own collision routines, so trajectories are not bit
    equal; 1 cm is a tenth of the cube's lift and ten times the gap measured here."""
    motions = np.stack([PICK, _unreachable(PICK, slice(20, 35))])
    scenes = WORLD.default_scenes(2)
    nat = execute(WORLD, motions, scenes, LIFTED, backend="mujoco")
    mjx = execute(WORLD, motions, scenes, LIFTED, backend="mjx")
    assert nat.success.tolist() == mjx.success.tolist() == [True, False]
    np.testing.assert_allclose(mjx.qpos[:, :, CUBE:CUBE + 3], nat.qpos[:, :, CUBE:CUBE + 3], atol=0.01)
    np.testing.assert_allclose(native.qpos[0], nat.qpos[0])  # batching does not change an episode


def test_native_rollout_records_qpos_after_each_waypoint():
    """The recorded qpos equals stepping the same controls by hand."""
    config = ExecutionConfig()
    scenes = WORLD.default_scenes(1)
    p = plan(WORLD, PICK[None, :6], scenes, config)
    ctrl = controls(p, scenes.qpos[:, WORLD.chain.qpos_index], np.full(1, 0.04), config)
    recorded = execution.rollout_mujoco(WORLD, scenes, ctrl)
    model, data = WORLD.model, mujoco.MjData(WORLD.model)
    data.qpos[:] = scenes.qpos[0]
    mujoco.mj_forward(model, data)
    for w in range(6):
        for c in ctrl[0, w]:
            data.ctrl[:] = c
            mujoco.mj_step(model, data)
        np.testing.assert_allclose(recorded[0, w], data.qpos, atol=1e-9)


def test_controls_ramp_then_switch_gripper():
    config = ExecutionConfig(substeps=10, ramp_steps=4)
    p = execution.Plan(
        arm_targets=np.ones((1, 2, 7)), gripper=np.array([[0.0, 0.0]]),
        reached=np.ones((1, 2), bool), valid=np.ones((1, 2), bool), abandoned=np.zeros(1, bool),
    )
    c = controls(p, np.zeros((1, 7)), np.array([0.04]), config)
    assert c.shape == (1, 2, 10, 8)
    np.testing.assert_allclose(c[0, 0, :4, 0], [0.25, 0.5, 0.75, 1.0])
    np.testing.assert_allclose(c[0, 0, 4:, 0], 1.0)
    np.testing.assert_allclose(c[0, 0, :4, 7], 0.04)  # the gripper waits for the arm
    np.testing.assert_allclose(c[0, 0, 4:, 7], 0.0)


def test_failed_waypoints_are_skipped_then_the_motion_is_abandoned():
    scenes = WORLD.default_scenes(2)
    few = _unreachable(PICK, [10, 11, 12])  # 3 failures: skipped, motion goes on
    many = _unreachable(PICK, slice(10, 22))  # 12 failures: abandoned at the 11th
    p = plan(WORLD, np.stack([few, many]), scenes)
    assert (~p.reached[0]).sum() == 3 and not p.abandoned[0] and p.valid[0].all()
    np.testing.assert_array_equal(p.arm_targets[0, 10], p.arm_targets[0, 9])
    assert p.abandoned[1]
    assert p.valid[1, :20].all() and not p.valid[1, 20:].any()
    np.testing.assert_array_equal(p.arm_targets[1, 20:], np.broadcast_to(p.arm_targets[1, 19], (81, 7)))


def test_skipped_waypoints_do_not_apply_their_gripper_command():
    closing = int(np.argmax(PICK[:, 9] < 0.5))
    bad = _unreachable(PICK, [closing])
    p = plan(WORLD, bad, WORLD.default_scenes(1))
    assert p.gripper[0, closing] == pytest.approx(0.04)
    assert p.gripper[0, closing + 1] == pytest.approx(0.0)


def test_success_after_abandonment_does_not_count():
    always = lambda qpos, scenes: np.ones(qpos.shape[:2], bool)
    far = _unreachable(PICK, slice(0, M.NUM_STEPS))
    result = execute(WORLD, far, WORLD.default_scenes(1), always, backend="mujoco")
    assert result.abandoned[0]
    assert result.success_after[0, :10].all() and not result.success_after[0, 10:].any()  # 11th failure


@pytest.mark.parametrize(
    "motions, match",
    [
        (np.zeros((101, 10), np.float32), "101, 11|T, 11"),
        (np.zeros((2, 3, 101, 11), np.float32), "E, T"),
        (np.full((101, 11), np.nan, np.float32), "NaN"),
    ],
)
def test_bad_motions_fail_clearly(motions, match):
    with pytest.raises(ValueError, match=match):
        execute(WORLD, motions, WORLD.default_scenes(1), LIFTED, backend="mujoco")


def test_unknown_backend_fails_clearly():
    with pytest.raises(ValueError, match="back-end"):
        execute(WORLD, PICK, WORLD.default_scenes(1), LIFTED, backend="bullet")


_PLAN_ON_TWO_DEVICES = r"""
import sys, json
sys.path.insert(0, sys.argv[1])
from envs.platform import setup
setup()
import jax, numpy as np
from envs import demo, execution
assert jax.device_count() == 2, jax.devices()
world = demo.default_world(64)
pick = demo.pick_cube_motion(world)
far = pick.copy()
far[20:35, 2] += 4.0  # out of reach: skipped waypoints, then abandoned
motions = np.stack([pick, far, pick + 0.01])  # 3: the split pads one copy
split = execution.plan(world, motions, world.default_scenes(3))
whole = [execution.plan(world, m[None], world.default_scenes(1)) for m in motions]
print(json.dumps({"equal": all(np.array_equal(getattr(split, f)[i], getattr(w, f)[0]) for i, w in enumerate(whole)
                                for f in ("arm_targets", "gripper", "reached", "valid", "abandoned")),
                  "abandoned": split.abandoned.tolist()}))
"""


def test_the_plan_split_over_two_devices_equals_each_motion_planned_alone():
    r = run_on_two_devices(_PLAN_ON_TWO_DEVICES)
    assert r["abandoned"] == [False, True, False] and r["equal"]  # bit for bit
