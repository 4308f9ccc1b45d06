"""Comparing methods scene by scene, from ``bin/evaluate --json`` files.

Every method is evaluated on the same test scenes, so two methods' results on a task are paired:
what decides between them is the scenes one solves and the other does not. With 100 scenes a
success rate alone has a standard error of about 5 points; the exact sign test on those
discordant scenes says whether a difference is more than that noise.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .config import IMAGE_SIZE_BEFORE, HeadConfig, TrainConfig, override_label, recipe_head, recipe_settings

# Two-stage bank scorings (stride, keep) that chose the same motions, and so solved the same
# scenes, as the full scoring in all 2,700 test scenes of the nine tasks (BENCHMARKS.md,
# "Coarse-to-fine bank scoring"): their results share the full scoring's row.
SAME_AS_FULL = {(4, 64), (6, 64), (6, 32)}

# {row label: {task name: per-scene success, int (episodes,)}}, rows in the order first seen.
Rows = dict[str, dict[str, np.ndarray]]


def row_label(result: dict, settings: dict) -> str:
    """``dmo n=8 R=1``, ``sort n=8``, ``nearest``: a result's row (``(coarse 4/32)`` after a
    two-stage bank scoring other than those of ``SAME_AS_FULL``, which share the full scoring's
    row); a DMO trained with a non-default number of unrolled steps (Ours-1, Ours-5) gets ``(trained R=k)`` after it,
    one whose candidates a selection head ranks ``(selection head 300, 8 phases)`` (its training scenes and the
    parts of the motion it reads; files older than the phases: ``(selection head 300)``), one trained on other
    inputs than its recipe's ``(inputs offset)``, heads that read the depth cue where their
    recipe does not, or the reverse (``(depth cue)``, ``(no depth cue)``), an EBM trained on its own ranking of
    the bank where its recipe's is not, or the reverse (``(mined negatives)``, ``(no mined negatives)``),
    another architecture ``(wo_concat)`` or EBM
    negatives ``(only-vae negatives)``, networks of a recipe other than the paper's
    ``[recipe]``, and networks trained with other settings (``--set``) ``{field=value, ...}``,
    which always name the image size where it is known (recorded, set, or the size a file's preset
    had before sizes were recorded), so that rows of networks of two sizes never share a label."""
    if "n" not in result:  # a world method (expert, blind, nearest)
        return result["method"]
    label = f"{result['method']} n={result['n']}" + ("" if result["R"] is None else f" R={result['R']}")
    if result.get("coarse") and tuple(result["coarse"]) not in SAME_AS_FULL:
        label += " (coarse {}/{})".format(*result["coarse"])
    trained = settings.get("dmo_train_steps")
    label += f" (trained R={trained})" if result["method"] == "dmo" and trained is not None else ""
    items = [override_label(i) for i in settings.get("set") or ()]
    # the head ranks the DMO's candidates alone (files older than the field: the --set item, else no head)
    heads = [int(i.partition("=")[2]) for i in items if i.startswith("selection_scenes=")]
    head = settings.get("selection_scenes", heads[-1] if heads else 0)
    phases = settings.get("selection_phases", 1)
    if head and result["method"] == "dmo":
        label += f" (selection head {head}" + ("" if phases == 1 else f", {phases} phases") + ")"
    recipe = settings.get("recipe") or "paper"
    own = recipe_settings(recipe, TrainConfig())
    inputs = settings.get("dmo_inputs") or own["dmo_inputs"]
    label += f" (inputs {inputs})" if result["method"] == "dmo" and inputs != own["dmo_inputs"] else ""
    variant, negatives = settings.get("variant") or "concat", settings.get("negatives") or "in-data+vae"
    cue = settings.get("depth_cue", "depth_cue=true" in items)  # (files older than the field: off unless set)
    if cue != recipe_head(recipe, HeadConfig(variant=variant)).depth_cue:
        label += " (depth cue)" if cue else " (no depth cue)"
    # (files older than the field: not mined)
    mined = bool(settings.get("ebm_mined_steps"))
    if mined != bool(own["ebm_mined_steps"]) and negatives == "in-data+vae":
        label += " (mined negatives)" if mined else " (no mined negatives)"
    label += "" if variant == "concat" else f" ({variant})"
    label += "" if negatives == "in-data+vae" else f" ({negatives} negatives)"
    label += "" if recipe == "paper" else f" [{recipe}]"
    overrides = [item for item in items
                 if not item.startswith(("dmo_inputs=", "depth_cue=", "ebm_mined_steps=", "image_size=",
                                         "selection_scenes="))]
    sizes = [item.partition("=")[2] for item in items if item.startswith("image_size=")]
    size = settings.get("image_size") or (sizes[-1] if sizes else IMAGE_SIZE_BEFORE.get(settings.get("preset")))
    overrides = sorted(overrides + ([f"image_size={size}"] if size else []))
    return label + (f" {{{', '.join(overrides)}}}" if overrides else "")


def _labelled_results(paths):
    """``(path, label, result)`` for every result in the given ``bin/evaluate --json`` files;
    raises ValueError when a file is missing or is not an evaluation file."""
    for path in map(Path, paths):
        try:
            payload = json.loads(path.read_text())
        except FileNotFoundError:
            raise ValueError(f"{path}: no such file") from None
        except (OSError, json.JSONDecodeError) as err:
            raise ValueError(f"{path}: not a readable JSON file ({err})") from None
        results = payload.get("results") if isinstance(payload, dict) else None
        if not isinstance(results, list) or not all(isinstance(r, dict) and "episode_success" in r for r in results):
            raise ValueError(f"{path}: not a `bin/evaluate --json` file (expected a 'results' list whose entries "
                             "have 'episode_success')")
        for result in results:
            # a result's own settings (bin/reproduce's tables hold several runs) override the file's
            yield path, row_label(result, {**payload.get("settings", {}), **result.get("settings", {})}), result


def load_evaluations(paths) -> Rows:
    """Per-scene successes of every (row, task) in the given ``bin/evaluate --json`` files.

    Raises ValueError when a file is missing, is not an evaluation file, or gives a row and
    task another file already gave with other outcomes (results of different networks must not
    be mixed silently; the same outcomes, e.g. one EBM's ranking evaluated beside two DMOs, are
    one row).
    """
    rows: Rows = {}
    source: dict[tuple[str, str], str] = {}
    for path, label, result in _labelled_results(paths):
        task = result["task"]
        outcomes = result["episode_success"]
        if not (isinstance(outcomes, list) and outcomes and all(o in (0, 1) and not isinstance(o, float)
                                                                for o in outcomes)):
            raise ValueError(f"{path}: the episode_success of '{label}' on {task} must be a non-empty list of "
                             "0/1 or true/false outcomes, one per scene")
        outcomes = np.asarray(outcomes, dtype=int)
        if (label, task) in source:
            if np.array_equal(rows[label][task], outcomes):
                continue
            raise ValueError(f"{path}: '{label}' on {task} is also in {source[label, task]}, with other outcomes; "
                             "compare results of different networks in separate calls")
        source[label, task] = str(path)
        rows.setdefault(label, {})[task] = outcomes
    return rows


def load_distances(paths) -> dict[str, dict[str, tuple[float, float]]]:
    """``{row: {task: (distance, in depth)}}``: the first-ranked motion's mean 3-D distance from
    the scene's demonstration, and its part along the camera axis (metres), for the rows of
    learned methods (``bin/evaluate``'s ``first_error_m`` / ``first_depth_error_m``)."""
    out: dict[str, dict[str, tuple[float, float]]] = {}
    for _, label, result in _labelled_results(paths):
        if "first_error_m" in result:
            out.setdefault(label, {})[result["task"]] = (result["first_error_m"], result["first_depth_error_m"])
    return out


def load_choices(paths) -> dict[str, dict[str, dict]]:
    """``{row: {task: result}}`` for the rows whose candidates were each executed alone
    (``bin/evaluate --each-candidate``: ``some_candidate_solves`` and the rest of
    ``evaluation.candidate_outcomes``)."""
    out: dict[str, dict[str, dict]] = {}
    for _, label, result in _labelled_results(paths):
        if "some_candidate_solves" in result:
            out.setdefault(label, {})[result["task"]] = result
    return out


def choice_table(choices: dict[str, dict[str, dict]]) -> str:
    """Markdown: per row and task (:func:`load_choices`), the success of the chosen motions, of the
    best start and of the best candidate (each executed alone) in %, then how often a start and an
    optimised motion succeed alone: what the choice among the candidates costs."""
    from envs.evaluation import ABBREVIATIONS, TASK_ORDER

    tasks = [t for t in TASK_ORDER if any(t in per_task for per_task in choices.values())]
    head = " | ".join(ABBREVIATIONS[t] for t in tasks)
    rule = "|---" * (len(tasks) + 1) + "|"
    pct = lambda x: f"{100 * x:.0f}"  # noqa: E731
    chosen = ["| chosen / best start / best candidate, % | " + head + " |", rule]
    alone = ["| a start / an optimised motion succeeds alone, % | " + head + " |", rule]
    for label, per_task in choices.items():
        rs = [per_task.get(t) for t in tasks]
        chosen.append(f"| {label} | " + " | ".join(
            "–" if r is None else f"{pct(r['success_rate'])} / {pct(r['some_start_solves'])} / "
            f"{pct(r['some_candidate_solves'])}" for r in rs) + " |")
        alone.append(f"| {label} | " + " | ".join(
            "–" if r is None else pct(r["start_success_rate"]) + (
                f" / {pct(r['optimised_success_rate'])}" if "optimised_success_rate" in r else "") for r in rs) + " |")
    return "\n".join(chosen) + "\n\n" + "\n".join(alone)


def precision_table(choices: dict[str, dict[str, dict]]) -> str:
    """Markdown: for each row of ``choices`` (:func:`load_choices`) that records it, how often one of
    its candidates executed alone succeeds, by the candidate's distance from the demonstration
    (``success_by_error`` of ``evaluation.candidate_outcomes``; rows of the table) and task
    (columns), in % with the number of candidates; then how often the candidate nearest the
    demonstration solves its scene. Empty when no row records it."""
    from envs.evaluation import ABBREVIATIONS, TASK_ORDER

    tables = []
    for label, per_task in choices.items():
        tasks = [t for t in TASK_ORDER if "success_by_error" in per_task.get(t, {})]
        if not tasks:
            continue
        lines = [f"| {label}: a candidate succeeds alone, % (candidates), by its distance from the "
                 "demonstration | " + " | ".join(ABBREVIATIONS[t] for t in tasks) + " |", "|---" * (len(tasks) + 1) + "|"]
        for i, first in enumerate(per_task[tasks[0]]["success_by_error"]):
            low, high = 100 * first["from_m"], first["to_m"]
            name = f"{low:g}–{100 * high:g} cm" if high is not None else f"≥ {low:g} cm"
            cells = []
            for t in tasks:
                b = per_task[t]["success_by_error"][i]
                cells.append("–" if b["success_rate"] is None else f"{100 * b['success_rate']:.0f} ({b['candidates']:,})")
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
        lines.append("| the candidate nearest the demonstration solves its scene | " + " | ".join(
            f"{100 * per_task[t]['nearest_candidate_solves']:.0f}" for t in tasks) + " |")
        tables.append("\n".join(lines))
    return "\n\n".join(tables)


def select_rows(rows: Rows, labels: list[str]) -> Rows:
    """``rows`` restricted to ``labels``, in that order."""
    missing = [label for label in labels if label not in rows]
    if missing:
        raise ValueError(f"no row {', '.join(repr(m) for m in missing)} in these files; rows: {', '.join(rows)}")
    return {label: rows[label] for label in labels}


def sign_test(wins: int, losses: int) -> float:
    """Exact two-sided sign test: the probability of a split at least this uneven between
    ``wins`` and ``losses`` discordant scenes if either method were as likely to win each."""
    from scipy.stats import binomtest  # here: importing scipy.stats takes ~0.6 s, and bin/evaluate needs none of it

    return 1.0 if wins + losses == 0 else float(binomtest(wins, wins + losses, 0.5).pvalue)


def paired_counts(a: np.ndarray, b: np.ndarray) -> tuple[int, int]:
    """(scenes only ``a`` solves, scenes only ``b`` solves)."""
    if a.shape != b.shape:
        raise ValueError(f"cannot pair {a.shape[0]} scenes with {b.shape[0]}; evaluate both on the same episodes")
    return int(np.sum((a == 1) & (b == 0))), int(np.sum((a == 0) & (b == 1)))


def distance_table(distances: dict[str, dict[str, tuple[float, float]]]) -> str:
    """Markdown: per row and task, the first-ranked motion's distance from the demonstration in
    cm, with its part in depth in brackets (:func:`load_distances`)."""
    from envs.evaluation import ABBREVIATIONS, TASK_ORDER

    tasks = [t for t in TASK_ORDER if any(t in per_task for per_task in distances.values())]
    lines = ["| first-ranked motion's distance from the demonstration, cm (in depth) | "
             + " | ".join(ABBREVIATIONS[t] for t in tasks) + " |", "|---" * (len(tasks) + 1) + "|"]
    for label, per_task in distances.items():
        cells = [f"{100 * per_task[t][0]:.1f} ({100 * per_task[t][1]:.1f})" if t in per_task else "–" for t in tasks]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def comparison_report(rows: Rows, reference: str, alpha: float = 0.05) -> str:
    """Markdown: the success table, then ``reference`` against every other row scene by scene
    (``+wins / −losses``, ``*`` where the sign test gives p < ``alpha``), then how many tasks
    ``reference`` leads every other row on."""
    from envs.evaluation import ABBREVIATIONS, TASK_ORDER, success_table

    if reference not in rows:
        raise ValueError(f"no row '{reference}' to compare against; rows: {', '.join(rows)}")
    lines = [success_table([(label, {t: float(s.mean()) for t, s in per_task.items()})
                            for label, per_task in rows.items()]), ""]
    tasks = [t for t in TASK_ORDER if t in rows[reference]]
    others = [label for label in rows if label != reference]
    counts = {(label, task): paired_counts(rows[reference][task], rows[label][task])
              for label in others for task in tasks if task in rows[label]}
    p_values = {key: sign_test(*wins_losses) for key, wins_losses in counts.items()}
    lines += [f"| {reference}: scenes won / lost against | " + " | ".join(ABBREVIATIONS[t] for t in tasks) + " |",
              "|---" * (len(tasks) + 1) + "|"]
    for label in others:
        cells = [f"+{counts[label, t][0]} / −{counts[label, t][1]}" + ("*" if p_values[label, t] < alpha else "")
                 if (label, t) in counts else "–" for t in tasks]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    ahead, level, behind_significantly = [], [], {}
    for task in tasks:
        margins = [w - l for (label, t), (w, l) in counts.items() if t == task]
        if margins and min(margins) > 0:
            ahead.append(task)
        elif margins and min(margins) == 0:
            level.append(task)
        behind = [label for (label, t), (w, l) in counts.items() if t == task and l > w and p_values[label, t] < alpha]
        if behind:
            behind_significantly[task] = behind
    abbreviate = lambda names: ", ".join(ABBREVIATIONS[t] for t in names) or "none"  # noqa: E731
    lines += ["", f"`*`: exact sign test on the scenes only one of the two solves, p < {alpha}.",
              f"{reference} solves more scenes than every other row on {len(ahead)} of {len(tasks)} tasks "
              f"({abbreviate(ahead)}), as many as the best of them on {len(level)} ({abbreviate(level)}); "
              f"significantly fewer than some row on {len(behind_significantly)}"
              + "".join(f"; {ABBREVIATIONS[t]}: {', '.join(v)}" for t, v in behind_significantly.items()) + "."]
    return "\n".join(lines)
