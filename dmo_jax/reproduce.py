"""The paper's success tables, rebuilt from nothing but this repository (``bin/reproduce``, whose
command line is ``dmo_jax.commands.reproduce``).

For each table and task it generates the data that is missing, trains the networks that are
not trained (``workflow.train_task`` skips and resumes), evaluates, and records every result in
``<results>/table<N>.json`` as soon as it exists, so a killed run resumes where it stopped and a
finished one does no work. The tables are then rendered into BENCHMARKS.md between the markers
``<!-- table<N> -->`` and ``<!-- /table<N> -->``: no table there is edited by hand.

A table file is a ``bin/evaluate --json`` file (``bin/compare results/table1.json`` compares its
rows scene by scene) plus ``provenance``: preset, scenes, date, machine, package versions and the
commands that made it. Each result carries the ``settings`` its row was made with.
"""
from __future__ import annotations

import dataclasses
import datetime
import json
import os
import platform
import time
from importlib import metadata
from pathlib import Path
from typing import Callable, Sequence

from .comparison import row_label
from .config import RECIPES, VARIANTS, Preset

TABLES = ("1", "2", "4", "5", "6")
TITLES = {
    "1": "Table 1: the optimisers",
    "2": "Table 2: architecture variants",
    "4": "Table 4: the EBM's negatives",
    "5": "Table 5: candidates n",
    "6": "Table 6: refinements R",
}
#: Every learned method of Table 1 (all from the same bank scoring).
TABLE1_METHODS = ("sort", "dmo", "langevin", "gd", "vaebm-l", "vaebm-s")
#: The paper's success rates (%) per table, row and task (CB PC PB PK PR PU RT SW TP).
PAPER = {
    "1": {"(a) Ours-5": (97, 89, 85, 51, 85, 25, 32, 74, 94), "(b) Ours-1": (95, 89, 87, 38, 77, 19, 31, 85, 94),
          "(c) Langevin": (71, 77, 83, 0, 46, 11, 0, 18, 77), "(d) GD": (54, 78, 61, 18, 40, 5, 36, 48, 81),
          "(e) VAEBM-L": (64, 88, 81, 27, 35, 10, 32, 48, 77), "(f) VAEBM-S": (62, 82, 79, 27, 40, 9, 32, 50, 74)},
    "2": {"(a) Ours": (97, 89, 85, 51, 85, 25, 32, 74, 94), "(b) w/o concat": (96, 85, 94, 55, 91, 13, 26, 85, 93),
          "(c) with GAP": (5, 3, 0, 4, 1, 0, 3, 5, 0), "(d) with ViT": (0, 0, 0, 1, 1, 1, 4, 0, 2)},
    "4": {"(a) Ours": (95, 86, 73, 56, 84, 13, 29, 79, 74), "(b) Only VAE": (0, 3, 5, 3, 2, 0, 0, 0, 0)},
    "5": {"R=1, n=1": (99, 83, 84, 37, 54, 14, 32, 57, 84), "R=1, n=8": (97, 89, 85, 51, 85, 25, 32, 74, 94),
          "R=1, n=1000": (97, 88, 68, 71, 86, 26, 32, 83, 95)},
    "6": {"R=1, n=8": (97, 89, 85, 51, 85, 25, 32, 74, 94), "R=5, n=8": (95, 86, 73, 56, 84, 13, 29, 79, 74),
          "R=10, n=8": (95, 88, 76, 57, 78, 16, 7, 79, 92)},
}
_PACKAGES = ("jax", "jaxlib", "flax", "optax", "orbax-checkpoint", "mujoco", "mujoco-mjx", "numpy")


@dataclasses.dataclass(frozen=True)
class Run:
    """One set of networks and what is evaluated with them on each task: ``methods`` at each
    ``(n, R)`` of ``settings`` (an n above the bank's size means the whole bank). ``recipe``
    None: a method of the world alone (the nearest-motion oracle), no networks."""

    name: str
    recipe: str | None
    methods: tuple[str, ...] = ("dmo",)
    settings: tuple[tuple[int, int], ...] = ((8, 1),)
    variant: str = "concat"
    negatives: str = "in-data+vae"
    dmo_train_steps: int | None = None  # R the DMO trains with; None: the preset's

    def networks(self, preset: Preset) -> Preset:
        """``preset`` as this run trains its networks."""
        return preset.with_variant(self.variant).with_recipe(self.recipe)

    def row_settings(self) -> dict:
        """What ``comparison.row_label`` names this run's rows by."""
        return {"recipe": self.recipe, "variant": self.variant, "negatives": self.negatives,
                "dmo_train_steps": self.dmo_train_steps}


def table_runs(table: str, recipe: str, variants: Sequence[str] = VARIANTS) -> list[Run]:
    """The runs of ``table``; Table 1 runs every recipe, the others ``recipe``; Table 2 the
    architectures of ``variants``."""
    if table == "1":
        runs = [Run("nearest", None, ("nearest",))]
        for r in RECIPES:
            runs += [Run(r, r, TABLE1_METHODS), Run(f"{r}-dmo-trained-R1", r, dmo_train_steps=1)]
        return runs
    if table == "2":
        return [Run(f"{recipe}-{v}", recipe, variant=v) for v in variants]
    if table == "4":
        from .losses import NEGATIVE_MODES

        return [Run(f"{recipe}-{m}", recipe, negatives=m) for m in NEGATIVE_MODES]
    if table == "5":
        return [Run(f"{recipe}-n", recipe, settings=((1, 1), (8, 1), (1000, 1)))]
    if table == "6":
        return [Run(f"{recipe}-R", recipe, settings=((8, 1), (8, 5), (8, 10)))]
    raise ValueError(f"unknown table {table!r}; expected one of {', '.join(TABLES)}")


def provenance(preset: Preset, episodes: int, command: Sequence[str], earlier: Sequence[str] = ()) -> dict:
    """Where and how a table file's results were made: the machine and packages of the run that
    last added results, and every command that added some (``earlier`` ones first)."""
    import jax

    versions = {}
    for name in _PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            pass
    device = jax.devices()[0]
    return {"preset": preset.name, "episodes": episodes,
            "date": datetime.date.today().isoformat(),
            "machine": {"system": platform.platform(terse=True), "processor": platform.machine(),
                        "cores": os.cpu_count(), "device": f"{device.platform}: {device.device_kind}"},
            "python": platform.python_version(), "versions": versions,
            "commands": list(dict.fromkeys([*earlier, " ".join(["bin/reproduce", *command])]))}


def commands(made: dict) -> list[str]:
    """The commands that made a table file, from its ``provenance`` (files that kept only the last
    one name it ``command``)."""
    return made.get("commands") or ([made["command"]] if "command" in made else [])


def _record(result: dict, run: Run, preset: Preset) -> dict:
    """What a table keeps of one ``evaluate_methods`` result of ``run`` with ``preset``."""
    keep = ("task", "method", "n", "R", "successes", "episodes", "success_rate", "episode_success",
            "first_error_m", "first_depth_error_m", "start_error_m", "predict_seconds", "coarse")
    return {"run": run.name, **{k: result[k] for k in keep if k in result}, "settings": _settings(run, preset)}


def _settings(run: Run, preset: Preset) -> dict:
    """What the rows of ``run`` on ``preset`` are made with (``comparison.row_label`` names them by it;
    rows of older files, which record no ``image_size``, differ from it and are remade)."""
    from .selection import PHASES
    from .training import mined_steps

    if run.recipe is None:
        return {}
    networks = run.networks(preset)
    return {**run.row_settings(), "dmo_inputs": networks.train.dmo_inputs, "depth_cue": networks.head.depth_cue,
            "ebm_mined_steps": mined_steps(networks.train, run.negatives), "image_size": preset.image_size,
            "selection_scenes": networks.train.selection_scenes, "selection_phases": PHASES}


def load_table(path: Path, preset: Preset, episodes: int) -> dict | None:
    """The table file at ``path`` (None if there is none); raises ValueError when it was made
    with another preset or number of scenes: its results must not be mixed with new ones."""
    if not path.is_file():
        return None
    try:
        payload = json.loads(path.read_text())
        made = payload["provenance"]
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as err:
        raise ValueError(f"{path} is not a table file of bin/reproduce ({err}); move it away") from None
    if (made.get("preset"), made.get("episodes")) != (preset.name, episodes):
        raise ValueError(f"{path} holds results of preset {made.get('preset')!r} on {made.get('episodes')} scenes, "
                         f"not {preset.name!r} on {episodes}; use another --results directory")
    return payload


def _done(payload: dict | None, run: Run, task: str, preset: Preset) -> bool:
    """Whether ``payload`` holds ``run``'s rows on ``task`` made with today's settings."""
    return payload is not None and any(r["run"] == run.name and r["task"] == task
                                       and r["settings"] == _settings(run, preset) for r in payload["results"])


def evaluate_run(run: Run, task: str, preset: Preset, episodes: int, data, workdir, backend: str = "auto",
                 seed: int = 0, log: Callable[[str], None] = print) -> list[dict]:
    """Train what ``run`` needs on ``task`` with ``preset``'s settings (skipping what is trained)
    and evaluate it on the first ``episodes`` test scenes; ``evaluate_methods``' results."""
    from envs import evaluation
    from envs.dataset import load_split

    from .evaluation import evaluate_methods
    from .workflow import TEST_EPISODES, generate_missing_splits, train_task

    generate_missing_splits(task, data, preset.image_size, max(TEST_EPISODES, episodes), log)
    if run.recipe is None:
        return [{"task": task, **evaluation.evaluate_world_method(task, m, episodes, data, backend)}
                for m in run.methods]
    networks = run.networks(preset)
    train_task(task, networks, data, workdir, run.negatives, run.dmo_train_steps, seed, log=log)
    bank = len(load_split(data, task, "train", preset.image_size).motions)
    settings = tuple(dict.fromkeys((min(n, bank), R) for n, R in run.settings))
    results = evaluate_methods(task, list(run.methods), preset=networks, workdir=workdir, data_root=data,
                               settings=settings, episodes=episodes, backend=backend, negatives=run.negatives,
                               dmo_train_steps=run.dmo_train_steps, seed=seed)
    return [{**r, "task": task} for r in results]


def reproduce(tables: Sequence[str], tasks: Sequence[str], preset: Preset, episodes: int, *, results_dir,
              data, workdir, recipe: str | None = None, variants: Sequence[str] = VARIANTS, backend: str = "auto",
              seed: int = 0, command: Sequence[str] = (), log: Callable[[str], None] = print) -> dict[str, Path]:
    """Make whatever results of ``tables`` on ``tasks`` are missing from ``results_dir`` and
    return each table's file. ``recipe``: the networks of Tables 2-6 (None: the preset's);
    ``variants``: Table 2's architectures (rows of others already in its file stay)."""
    from envs.commands.common import write_json

    results_dir = Path(results_dir)
    results_dir.mkdir(parents=True, exist_ok=True)
    recipe = recipe or preset.recipe
    files = {}
    for table in tables:
        path = files[table] = results_dir / f"table{table}.json"
        payload = load_table(path, preset, episodes)
        for run in table_runs(table, recipe, variants):
            for task in tasks:
                if _done(payload, run, task, preset):
                    log(f"[table {table}] {task} {run.name}: done")
                    continue
                ours = lambda r: r["run"] == run.name and r["task"] == task  # noqa: E731
                if payload and any(map(ours, payload["results"])):  # made with settings the preset no longer has
                    log(f"[table {table}] {task} {run.name}: replacing rows made with other settings")
                    payload["results"] = [r for r in payload["results"] if not ours(r)]
                log(f"[table {table}] {task} {run.name}: training what is missing, then evaluating on "
                    f"{episodes} scenes")
                t0 = time.perf_counter()
                records = [_record(r, run, preset) for r in evaluate_run(run, task, preset, episodes, data, workdir,
                                                                         backend, seed, log)]
                earlier = commands(payload["provenance"]) if payload else ()
                payload = {"provenance": provenance(preset, episodes, command, earlier),
                           "results": (payload or {}).get("results", []) + records}
                write_json(path, payload)  # after every run and task: a kill loses at most one
                log(f"[table {table}] {task} {run.name}: " + ", ".join(
                    f"{row_label(r, r['settings'])} {100 * r['success_rate']:.0f} %" for r in records)
                    + f" ({time.perf_counter() - t0:.0f} s)")
    return files


def render(path: Path, table: str) -> str:
    """Markdown for one table file: how it was made, then each row's success per task (%) with
    the paper's rows below."""
    from envs.evaluation import TASK_ORDER, success_table

    from .comparison import load_evaluations

    made = json.loads(Path(path).read_text())["provenance"]
    rows = [(label, {t: float(s.mean()) for t, s in per_task.items()})
            for label, per_task in load_evaluations([path]).items()]
    rows += [(f"paper {label}", {t: v / 100 for t, v in zip(TASK_ORDER, values)})
             for label, values in PAPER[table].items()]
    machine, made_by = made["machine"], ", then ".join(f"`{c}`" for c in commands(made))
    device = "/".join(dict.fromkeys(machine["device"].split(": ")))
    return (f"{made_by}: preset `{made['preset']}`, the first {made['episodes']} test scenes of each task, "
            f"{made['date']}, {machine['cores']} cores, device {device}, jax {made['versions'].get('jax', '?')}. "
            f"Rows \"paper\" are the paper's.\n\n" + success_table(rows))


def update_report(report: Path, sections: dict[str, str]) -> None:
    """Replace each table's text in ``report`` between ``<!-- table<N> -->`` and
    ``<!-- /table<N> -->`` (appending a section with the markers where they are missing)."""
    from envs.dataset import atomic_write_text

    text = report.read_text() if report.is_file() else "# Benchmarks\n"
    for table, body in sections.items():
        begin, end = f"<!-- table{table} -->", f"<!-- /table{table} -->"
        if begin in text and end in text.split(begin, 1)[1]:
            head, rest = text.split(begin, 1)
            text = head + begin + "\n" + body + "\n" + end + rest.split(end, 1)[1]
        else:
            text = text.rstrip("\n") + f"\n\n### {TITLES[table]}\n\n{begin}\n{body}\n{end}\n"
    atomic_write_text(report, text)
