"""Success evaluation in simulation: rebuild each test scene from its seed, execute motions.

Methods that need no learned model live here: ``expert`` replays the test split's recorded
motions; ``blind`` executes, on every test scene, the one training motion closest to the
mean training motion (a motion that ignores the image). Learned methods hand their ranked
candidates to :func:`execute_candidates`, which falls back to the next candidate when one
is abandoned (more than 10 unreachable waypoints), as the paper's evaluator does.
"""
from __future__ import annotations

import numpy as np

from envs import execution
from envs.dataset import Split

#: The paper's column order and abbreviations.
TASK_ORDER = (
    "close_box", "pick_up_cup", "push_button", "put_knife_on_chopping_board", "put_rubbish_in_bin",
    "put_umbrella_in_umbrella_stand", "reach_target", "stack_wine", "take_plate_off_colored_dish_rack",
)
ABBREVIATIONS = dict(zip(TASK_ORDER, ("CB", "PC", "PB", "PK", "PR", "PU", "RT", "SW", "TP")))
WORLD_METHODS = ("expert", "blind")


def execute_candidates(task, scenes, candidates: np.ndarray, backend: str = "auto") -> dict:
    """Execute ranked ``candidates [E, n, 101, 11]`` (best first) on ``scenes`` (list of E).

    Candidate k of an episode runs only if candidates 0..k-1 were all abandoned. Returns
    ``success [E]`` (bool), ``candidate [E]`` (index of the last candidate executed) and
    ``abandoned [E]`` (every candidate tried was abandoned).
    """
    candidates = np.asarray(candidates, np.float32)
    if candidates.ndim != 4 or candidates.shape[0] != len(scenes):
        raise ValueError(f"candidates must be [E={len(scenes)}, n, T, 11], got shape {candidates.shape}")
    e, n = candidates.shape[:2]
    success = np.zeros(e, bool)
    used = np.zeros(e, np.int64)
    pending = np.arange(e)
    for k in range(n):
        if len(pending) == 0:
            break
        batch = task.batch([scenes[i] for i in pending])
        result = execution.execute(task.world, candidates[pending, k], batch, task.success, backend)
        success[pending] = result.success
        used[pending] = k
        pending = pending[result.abandoned]
    abandoned = np.zeros(e, bool)
    abandoned[pending] = True
    return {"success": success, "candidate": used, "abandoned": abandoned}


def blind_motion(train: Split) -> np.ndarray:
    """The training motion closest (squared error) to the mean training motion, ``[101, 11]``."""
    motions = np.asarray(train.motions, np.float64)
    mean = motions.mean(axis=0)
    return np.asarray(train.motions[int(np.argmin(((motions - mean) ** 2).sum(axis=(1, 2))))])


def world_method_candidates(method: str, test: Split, train: Split | None, episodes: int) -> np.ndarray:
    """``[episodes, 1, 101, 11]`` motions of a method that needs no learned model."""
    if method == "expert":
        return np.asarray(test.motions[:episodes])[:, None]
    if method == "blind":
        if train is None:
            raise ValueError("the blind method needs the training split")
        return np.repeat(blind_motion(train)[None, None], episodes, axis=0)
    raise ValueError(f"unknown method {method!r}; expected one of {WORLD_METHODS}")


def success_table(rates: dict[str, float], label: str) -> str:
    """One row in the paper's layout (CB PC PB PK PR PU RT SW TP, then the average)."""
    head = "| method | " + " | ".join(ABBREVIATIONS[t] for t in TASK_ORDER) + " | avg |"
    sep = "|---" * (len(TASK_ORDER) + 2) + "|"
    cells = [f"{100 * rates[t]:.0f}" if t in rates else "–" for t in TASK_ORDER]
    avg = f"{100 * np.mean(list(rates.values())):.1f}" if rates else "–"
    return "\n".join([head, sep, f"| {label} | " + " | ".join(cells) + f" | {avg} |"])
