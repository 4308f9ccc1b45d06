"""Shared by the task tests: one task instance per name, and success judged on hand-made states."""
import functools

import numpy as np

from envs.tasks import TASKS


@functools.cache
def task(name):
    """The task ``name`` (a name of ``envs.tasks.TASKS``), built once per test run."""
    return TASKS[name]()


def judge(task, scene, states):
    """``states``: qpos ``[W, nq]`` of one episode -> success after each waypoint."""
    return task.success(np.asarray(states)[None], task.batch([scene]))[0].tolist()
