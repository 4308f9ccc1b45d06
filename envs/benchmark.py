"""Throughput of the execution back-ends (physics steps per second, episodes per second)."""
from __future__ import annotations

import time

import numpy as np


def benchmark_execution(episodes: int = 64, repeats: int = 3, backends=("mujoco", "mjx")) -> list[dict]:
    """Execute the scripted cube pick-up ``episodes`` times per back-end, batched; return one
    row per back-end with the median wall time of ``repeats`` runs after a warm-up run (which
    includes MJX's compilation, reported separately)."""
    from envs import demo, execution

    world = demo.default_world()
    motions = np.repeat(demo.pick_cube_motion(world)[None], episodes, axis=0)
    scenes = world.default_scenes(episodes)
    success = demo.cube_lifted(world)
    config = execution.ExecutionConfig()
    steps = episodes * motions.shape[1] * config.substeps
    rows = []
    for backend in backends:
        t0 = time.perf_counter()
        result = execution.execute(world, motions, scenes, success, backend, config)
        first = time.perf_counter() - t0
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            execution.execute(world, motions, scenes, success, backend, config)
            times.append(time.perf_counter() - t0)
        wall = float(np.median(times))
        rows.append({
            "backend": backend, "episodes": episodes, "physics_steps": steps,
            "first_run_s": round(first, 2), "median_s": round(wall, 3),
            "steps_per_s": round(steps / wall), "episodes_per_s": round(episodes / wall, 2),
            "success_rate": float(result.success.mean()),
        })
    return rows
