"""The simulated world: a Franka Panda on a table in MuJoCo, its front camera, and motion execution.

Modules: ``panda`` (the MJCF), ``camera`` (intrinsics, pose, rendering), ``kinematics``
(JAX forward and inverse kinematics), ``execution`` (motion -> controls -> rollouts on
native MuJoCo or MJX).
"""
from envs.gl import select_gl_backend
from envs.platform import configure_jax_for_cpu

# Both must run before mujoco's GL module and jax's backend initialise.
select_gl_backend()
configure_jax_for_cpu()
