"""The simulated world: a Franka Panda on a table in MuJoCo, its front camera, and motion execution.

Modules: ``panda`` (the MJCF), ``camera`` (intrinsics, pose, rendering), ``kinematics``
(JAX forward and inverse kinematics), ``motion`` (the motion representation), ``execution``
(motion -> controls -> rollouts on native MuJoCo or MJX), ``platform`` (process set-up).

Importing the package changes nothing in the process. A program that renders or executes calls
:func:`envs.platform.setup` first, before mujoco or jax are imported.
"""
