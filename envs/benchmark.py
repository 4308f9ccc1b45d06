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


def benchmark_data_generation(task_name: str = "pick_up_cup", episodes: int = 64, image_size: int = 64) -> dict:
    """Generate ``episodes`` demonstrations of a task (scripted expert, native MuJoCo,
    rendering) into a temporary directory, as ``bin/generate_data`` does; returns the wall
    time and episodes per second (kept episodes: the expert's failures are retried)."""
    import tempfile

    from envs import dataset
    from envs.tasks import get_task

    task = get_task(task_name, image_size)
    with tempfile.TemporaryDirectory() as root:
        t0 = time.perf_counter()
        dataset.generate_split(task, "train", episodes, root, batch=min(64, episodes), verbose=False)
        wall = time.perf_counter() - t0
    return {"task": task_name, "image_size": image_size, "episodes": episodes, "seconds": round(wall, 2),
            "episodes_per_s": round(episodes / wall, 2)}
