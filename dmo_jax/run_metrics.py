"""A training run's metrics for people: TensorBoard event files and a plot.

``training.fit`` records every logged step in ``RUN/metrics.jsonl``, which stays the record (a
resumed run drops the lines after its checkpoint and redoes them). :func:`export` rewrites
``RUN/tensorboard/`` (``tensorboard --logdir RUN/tensorboard``) and ``RUN/metrics.png`` from it,
so both show exactly what the record holds.
"""
from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

#: Record fields that are not curves.
_NOT_SCALARS = ("step", "time", "finite", "skipped")


def read_metrics(path: str | Path) -> list[dict]:
    """The records of a ``metrics.jsonl`` (a line torn by a crash is skipped)."""
    records = []
    for line in Path(path).read_text().splitlines():
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(record, dict) and isinstance(record.get("step"), int):
            records.append(record)
    return records


def _curves(records: list[dict]) -> dict[str, list[tuple[int, float]]]:
    curves: dict[str, list[tuple[int, float]]] = {}
    for record in records:
        for name, value in record.items():
            if name not in _NOT_SCALARS and isinstance(value, (int, float)) and math.isfinite(value):
                curves.setdefault(name, []).append((record["step"], float(value)))
    return curves


def write_events(records: list[dict], out_dir: str | Path) -> None:
    """TensorBoard event files of ``records`` in ``out_dir`` (replaced whole: written beside it,
    then moved into place)."""
    from tensorboardX import SummaryWriter

    out_dir = Path(out_dir)
    tmp = out_dir.with_name(out_dir.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    writer = SummaryWriter(logdir=str(tmp))
    for name, points in _curves(records).items():
        tag = f"heldout/{name[len('heldout_'):]}" if name.startswith("heldout_") else f"train/{name}"
        for step, value in points:
            writer.add_scalar(tag, value, step)
    writer.close()
    shutil.rmtree(out_dir, ignore_errors=True)
    tmp.rename(out_dir)


def plot_metrics(records: list[dict], path: str | Path, title: str) -> None:
    """``path`` (PNG, written atomically): the training loss, and the held-out metrics, against the step."""
    from envs.camera import write_atomically
    from envs.video import agg_figure

    curves = _curves(records)
    heldout = {k[len("heldout_"):]: v for k, v in curves.items() if k.startswith("heldout_")}
    panels = [("training loss", {"loss": curves.get("loss", [])})] + ([("held-out", heldout)] if heldout else [])
    fig = agg_figure(500 * len(panels), 360)
    for i, (name, lines) in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), i + 1)
        for label, points in lines.items():
            if points:
                ax.plot(*zip(*points), marker="o" if len(points) < 10 else None, label=label)
        ax.set(title=name, xlabel="step")
        ax.grid(alpha=0.3)
        if len(lines) > 1:
            ax.legend(fontsize=7)
    fig.suptitle(title)
    fig.tight_layout()
    write_atomically(path, lambda tmp: fig.savefig(tmp))


def export(run_dir: str | Path, title: str) -> None:
    """Rewrite ``run_dir/tensorboard/`` and ``run_dir/metrics.png`` from ``run_dir/metrics.jsonl``."""
    run_dir = Path(run_dir)
    records = read_metrics(run_dir / "metrics.jsonl")
    if records:
        write_events(records, run_dir / "tensorboard")
        plot_metrics(records, run_dir / "metrics.png", title)
