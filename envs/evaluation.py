"""Success evaluation in simulation: rebuild each test scene from its seed, execute motions.

Methods that need no learned model live here: ``expert`` replays the test split's recorded
motions; ``blind`` executes, on every test scene, the one training motion closest to the
mean training motion (a motion that ignores the image); ``nearest`` is an oracle that reads
the answer: the training motion closest to the scene's recorded motion (closest in position,
which is not always the one that succeeds). Learned methods hand their ranked candidates to
:func:`execute_candidates`, which falls back to the next candidate when one is abandoned (more
than 10 unreachable waypoints), as the paper's evaluator does; :func:`run_each_candidate`
executes each of them alone, to measure what choosing among them costs.
"""
from __future__ import annotations

import numpy as np

from envs import execution
from envs import motion as motion_lib
from envs.dataset import Split
from envs.progress import Progress

#: The paper's column order and abbreviations.
TASK_ORDER = (
    "close_box", "pick_up_cup", "push_button", "put_knife_on_chopping_board", "put_rubbish_in_bin",
    "put_umbrella_in_umbrella_stand", "reach_target", "stack_wine", "take_plate_off_colored_dish_rack",
)
ABBREVIATIONS = dict(zip(TASK_ORDER, ("CB", "PC", "PB", "PK", "PR", "PU", "RT", "SW", "TP")))
WORLD_METHODS = ("expert", "blind", "nearest")


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


def rebuild_scenes(name: str, test: Split, episodes: int):
    """Task ``name`` and its first ``episodes`` test scenes, rebuilt from their seeds."""
    from envs.tasks import get_task

    task = get_task(name, test.meta["image_size"])
    return task, [task.reset(int(s)) for s in test.seeds[:episodes]]


def run_each_candidate(name: str, test: Split, candidates: np.ndarray, backend: str = "auto",
                       progress: str | None = None) -> np.ndarray:
    """Success ``[E, K]`` (bool) of each of the ``candidates [E, K, 101, 11]`` executed alone, with
    no fallback, on the first ``E`` scenes of task ``name``'s split ``test``: which of a method's
    candidates would have solved each scene, had it been chosen. ``progress``: a label to report
    progress under, per candidate rank."""
    candidates = np.asarray(candidates, np.float32)
    if candidates.ndim != 4:
        raise ValueError(f"candidates must be [E, K, T, 11], got shape {candidates.shape}")
    task, scenes = rebuild_scenes(name, test, len(candidates))
    batch, k = task.batch(scenes), candidates.shape[1]
    bar, success = Progress(progress, k) if progress else None, []
    for i in range(k):
        success.append(execution.execute(task.world, candidates[:, i], batch, task.success, backend).success)
        if bar:
            bar.update(i + 1)
    if bar:
        bar.close()
    return np.stack(success, axis=1).astype(bool)


def blind_motion(train: Split) -> np.ndarray:
    """The training motion closest (squared error) to the mean training motion, ``[101, 11]``."""
    motions = np.asarray(train.motions, np.float64)
    mean = motions.mean(axis=0)
    return np.asarray(train.motions[int(np.argmin(((motions - mean) ** 2).sum(axis=(1, 2))))])


def nearest_bank_motions(train: Split, motions: np.ndarray) -> np.ndarray:
    """For each of ``motions [E, 101, 11]``, the training motion whose positions lie closest
    (mean 3-D distance over the 101 poses, camera frame) -> ``[E, 101, 11]``."""
    intrinsics, size = np.asarray(train.meta["intrinsics"], np.float64), train.meta["image_size"]

    def positions(m):
        return np.asarray(motion_lib.camera_positions(np.asarray(m, np.float64), intrinsics, size))

    bank = positions(train.motions)
    chosen = [int(np.argmin(np.linalg.norm(bank - p, axis=-1).mean(axis=-1))) for p in positions(motions)]
    return np.asarray(train.motions)[chosen]


def world_method_candidates(method: str, test: Split, train: Split | None, episodes: int) -> np.ndarray:
    """``[episodes, 1, 101, 11]`` motions of a method that needs no learned model."""
    if method == "expert":
        return np.asarray(test.motions[:episodes])[:, None]
    if method in ("blind", "nearest") and train is None:
        raise ValueError(f"the {method} method needs the training split")
    if method == "blind":
        return np.repeat(blind_motion(train)[None, None], episodes, axis=0)
    if method == "nearest":
        return nearest_bank_motions(train, test.motions[:episodes])[:, None]
    raise ValueError(f"unknown method {method!r}; expected one of {WORLD_METHODS}")


#: Test scenes evaluated when a call does not say (or the whole split, if shorter).
DEFAULT_EPISODES = 100


def episodes_to_run(episodes: int | None, test: Split, name: str, data_root) -> int:
    """The number of test scenes to evaluate: ``episodes``, or with None the first
    :data:`DEFAULT_EPISODES` (fewer if the split is shorter); ``DatasetError`` when ``episodes``
    asks for more scenes than the test split holds."""
    from envs.dataset import DatasetError

    if episodes is None:
        return min(DEFAULT_EPISODES, len(test))
    if episodes > len(test):
        raise DatasetError(f"{episodes} episodes asked for, but the test split of {name} in {data_root} holds "
                           f"{len(test)}; ask for at most {len(test)} or generate more (bin/generate_data --test N)")
    return episodes


def evaluate_world_method(name: str, method: str, episodes: int | None, data_root, backend: str = "auto") -> dict:
    """Evaluate ``expert``, ``blind`` or ``nearest`` on the first ``episodes`` test scenes of task ``name``
    (None: :func:`episodes_to_run`'s default; see :func:`run_episodes` for the result); raises
    ``envs.dataset.DatasetError`` if the data is missing or too short."""
    from envs.dataset import load_split

    test = load_split(data_root, name, "test")
    train = load_split(data_root, name, "train") if method != "expert" else None
    episodes = episodes_to_run(episodes, test, name, data_root)
    return {"method": method, **run_episodes(name, test, world_method_candidates(method, test, train, episodes),
                                             backend)}


def run_episodes(name: str, test: Split, candidates: np.ndarray, backend: str = "auto") -> dict:
    """Rebuild the first ``E`` test scenes of task ``name`` from their seeds and execute the
    ranked ``candidates [E, n, 101, 11]`` with fallback. Returns ``{"task", "episodes",
    "successes", "success_rate", "seconds", "episode_success", "candidate_used"}``."""
    import time

    episodes = len(candidates)
    task, scenes = rebuild_scenes(name, test, episodes)
    start = time.perf_counter()
    out = execute_candidates(task, scenes, candidates, backend)
    successes = int(out["success"].sum())
    return {
        "task": name, "episodes": episodes, "successes": successes, "success_rate": successes / episodes,
        "seconds": round(time.perf_counter() - start, 2), "episode_success": out["success"].astype(int).tolist(),
        "candidate_used": out["candidate"].tolist(),
    }


def success_table(rows: list[tuple[str, dict[str, float]]]) -> str:
    """Markdown table in the paper's layout (CB PC PB PK PR PU RT SW TP, then the average over
    the tasks evaluated): one row per ``(label, {task: success rate})``."""
    lines = ["| method | " + " | ".join(ABBREVIATIONS[t] for t in TASK_ORDER) + " | avg |",
             "|---" * (len(TASK_ORDER) + 2) + "|"]
    for label, rates in rows:
        cells = [f"{100 * rates[t]:.0f}" if t in rates else "–" for t in TASK_ORDER]
        avg = f"{100 * np.mean(list(rates.values())):.1f}" if rates else "–"
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {avg} |")
    return "\n".join(lines)


def task_suite_report(data_root, tasks, episodes: int | None = None, mjx_episodes: int = 20, log=print) -> str:
    """Markdown table per task: expert success (native), blind success (native), and the MJX
    back-end's agreement with native on the expert's first ``mjx_episodes`` episodes."""
    rows = ["| task | expert (native) | blind (native) | MJX agrees with native | expert on MJX |",
            "|---|---|---|---|---|"]
    for name in tasks:
        expert = evaluate_world_method(name, "expert", episodes, data_root, "mujoco")
        blind = evaluate_world_method(name, "blind", episodes, data_root, "mujoco")
        mjx = evaluate_world_method(name, "expert", min(mjx_episodes, expert["episodes"]), data_root, "mjx")
        agree = sum(a == b for a, b in zip(mjx["episode_success"], expert["episode_success"]))
        rows.append(
            f"| {ABBREVIATIONS.get(name, name)} {name} | {expert['successes']}/{expert['episodes']} "
            f"({100 * expert['success_rate']:.0f} %) | {blind['successes']}/{blind['episodes']} "
            f"({100 * blind['success_rate']:.0f} %) | {agree}/{mjx['episodes']} | "
            f"{mjx['successes']}/{mjx['episodes']} |"
        )
        log(rows[-1])
    return "\n".join(rows)
