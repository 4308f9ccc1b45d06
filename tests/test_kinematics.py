"""Forward kinematics against MuJoCo, and the damped-least-squares IK."""
import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from envs import demo, panda
from envs.kinematics import IKConfig, forward_kinematics, rotation_error, solve_ik, solve_ik_path

WORLD = demo.default_world(64)
CHAIN = WORLD.chain


def test_forward_kinematics_matches_mujoco():
    model, data = WORLD.model, mujoco.MjData(WORLD.model)
    rng = np.random.default_rng(0)
    fk = jax.jit(lambda q: forward_kinematics(CHAIN, q))
    for _ in range(20):
        q = rng.uniform(CHAIN.lower, CHAIN.upper)
        data.qpos[CHAIN.qpos_index] = q
        mujoco.mj_kinematics(model, data)
        pos, rot, _, _ = fk(jnp.asarray(q, jnp.float32))
        np.testing.assert_allclose(pos, data.site("tcp").xpos, atol=2e-6)
        np.testing.assert_allclose(rot, data.site("tcp").xmat.reshape(3, 3), atol=2e-6)


def test_chain_limits_come_from_the_model():
    assert CHAIN.lower[3] == np.float64(-3.0718) and CHAIN.upper[5] == np.float64(3.7525)
    assert len(CHAIN.link_pos) == 7


def _reachable_targets(n, seed=1):
    """Poses of random postures near home: reachable by construction."""
    rng = np.random.default_rng(seed)
    home = np.asarray(panda.HOME_QPOS)
    q = np.clip(home + rng.normal(0, 0.35, (n, 7)), CHAIN.lower, CHAIN.upper)
    pos, rot, _, _ = jax.vmap(lambda q: forward_kinematics(CHAIN, q))(jnp.asarray(q, jnp.float32))
    return pos, rot


def test_ik_reaches_reachable_targets_within_limits():
    pos, rot = _reachable_targets(200)
    home = jnp.tile(jnp.asarray(panda.HOME_QPOS, jnp.float32), (200, 1))
    q, reached, pos_err, rot_err = jax.jit(jax.vmap(lambda p, r, q0: solve_ik(CHAIN, p, r, q0)))(pos, rot, home)
    assert float(jnp.mean(reached)) > 0.95
    assert np.all(np.asarray(q) >= CHAIN.lower - 1e-6) and np.all(np.asarray(q) <= CHAIN.upper + 1e-6)
    # Reported errors are the real ones.
    p2, r2, _, _ = jax.vmap(lambda q: forward_kinematics(CHAIN, q))(q)
    np.testing.assert_allclose(jnp.linalg.norm(p2 - pos, axis=-1), pos_err, atol=1e-5)
    np.testing.assert_allclose(jax.vmap(rotation_error)(r2, rot), rot_err, atol=1e-3)
    assert float(jnp.median(pos_err)) < 2e-3


def test_ik_path_skips_unreachable_waypoints():
    pos, rot = _reachable_targets(5, seed=3)
    pos = pos.at[2].set(jnp.array([3.0, 0.0, 0.8]))  # 3 m away: out of reach
    qs, reached = jax.jit(lambda p, r: solve_ik_path(CHAIN, p, r, jnp.asarray(panda.HOME_QPOS, jnp.float32)))(pos, rot)
    assert not bool(reached[2])
    np.testing.assert_array_equal(qs[2], qs[1])  # the joint target is held
    assert bool(reached[3])


def test_ik_tolerances_are_configurable():
    pos, rot = _reachable_targets(20)
    strict = IKConfig(iterations=2, position_tolerance=1e-9, rotation_tolerance=1e-9)
    home = jnp.tile(jnp.asarray(panda.HOME_QPOS, jnp.float32), (20, 1))
    _, reached, _, _ = jax.vmap(lambda p, r, q0: solve_ik(CHAIN, p, r, q0, strict))(pos, rot, home)
    assert not bool(jnp.any(reached))
