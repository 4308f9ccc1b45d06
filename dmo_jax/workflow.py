"""Per-task pipeline behind ``bin/train_all``: data (generated if missing) -> VAE -> EBM -> DMO.

Work directory layout (``WORKDIR/<task>/<preset>/``)::

    vae/                       checkpoints/, metrics.jsonl   (shared by every variant)
    <variant>/ebm-<negatives>/ checkpoints/, metrics.jsonl   (-near<k>of<pool> with near negatives, -graded<s>cm with graded targets)
    <variant>/dmo-R<r>/        checkpoints/, metrics.jsonl   (-<inputs> unless the paper's)

The EBM's and DMO's names end in ``-cue`` (``-cue<range>cm`` when bounded) when their head reads
the depth cue.

A model whose checkpoint has reached its step count is loaded, not retrained; an
interrupted one resumes from its last checkpoint.
"""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from . import training
from .config import PRESETS, Preset
from .data import MotionDataset, motions_fingerprint, network_image
from .neighbours import split_neighbours


@dataclasses.dataclass(frozen=True)
class RunPaths:
    root: Path

    @classmethod
    def of(cls, workdir, task: str, preset: Preset) -> "RunPaths":
        """``<workdir>/<task>/<preset>``, with ``-<size>px`` where the image size is not the preset's own."""
        own = PRESETS.get(preset.name)
        size = "" if own is None or own.image_size == preset.image_size else f"-{preset.image_size}px"
        return cls(Path(workdir) / task / f"{preset.name}{size}")

    def vae(self) -> Path:
        return self.root / "vae"

    def ebm(self, preset: Preset, negatives: str) -> Path:
        """The EBM of ``preset``'s variant trained with ``negatives`` (and its near negatives,
        graded targets, mined steps and depth cue, if any)."""
        near, pool = training.near_negatives_meta(preset.train, negatives)
        suffix = f"-near{near}of{pool}" if near else ""
        if preset.train.ebm_target_scale:
            suffix += f"-graded{preset.train.ebm_target_scale * 100:g}cm"
        mined = training.mined_steps(preset.train, negatives)
        suffix += f"-mined{mined}" if mined else ""
        return self.root / preset.variant / f"ebm-{negatives}{suffix}{_cue_suffix(preset)}"

    def dmo(self, preset: Preset, train_steps: int) -> Path:
        """The DMO of ``preset``'s variant trained with ``train_steps`` unrolled steps (and its inputs
        when they are not the paper's, and its depth cue, if any)."""
        inputs = preset.train.dmo_inputs
        return self.root / preset.variant / (f"dmo-R{train_steps}" + ("" if inputs == "decoded" else f"-{inputs}")
                                             + _cue_suffix(preset))

    def selection(self, preset: Preset, negatives: str, train_steps: int) -> Path:
        """The selection head of the EBM and DMO above (``dmo_jax.selection``)."""
        return (self.root / preset.variant / "selection" /
                f"{self.ebm(preset, negatives).name}+{self.dmo(preset, train_steps).name}"
                f"-{preset.train.selection_scenes}.json")


def _cue_suffix(preset: Preset) -> str:
    """``-cue`` for a head reading the depth cue (``-cue10cm`` bounded to 0.1 m), else nothing."""
    head = preset.head
    return f"-cue{head.depth_cue_range * 100:g}cm" if head.depth_cue_range else "-cue" if head.depth_cue else ""


#: Held-out episodes evaluated during training (a longer test split is for bin/evaluate).
HELDOUT_EPISODES = 100


#: Scenes of a task's training split (the bank) and, at least, of its test split, where generated.
TRAIN_EPISODES, TEST_EPISODES = 1000, 100


def generate_missing_splits(task_name: str, data_root, image_size: int, test_episodes: int = TEST_EPISODES,
                            log=print) -> None:
    """Generate the task's splits missing under ``data_root``: :data:`TRAIN_EPISODES` training
    scenes and ``test_episodes`` test scenes, at ``image_size`` px."""
    from envs import dataset as ds
    from envs.tasks import get_task

    for split, n in (("train", TRAIN_EPISODES), ("test", test_episodes)):
        if not (ds.split_dir(data_root, task_name, split) / "meta.json").is_file():
            log(f"[{task_name}] generating the {split} split ({n} episodes at {image_size}px) in {data_root}")
            ds.generate_split(get_task(task_name, image_size), split, n, data_root)


def load_task_data(task_name: str, data_root, preset: Preset, generate: bool = True, log=print):
    """Train and held-out datasets of a task at the preset's image size (generated if missing,
    :func:`generate_missing_splits`), each with its motions' nearest training motions
    (``dmo_jax.neighbours``, computed once and stored in the split), plus the camera
    ``(K, image_size)`` they were rendered with. The held-out set is the test split's first
    :data:`HELDOUT_EPISODES`."""
    from envs import dataset as ds

    if generate:
        generate_missing_splits(task_name, data_root, preset.image_size, log=log)
    for split in ("train", "test"):
        if not (ds.split_dir(data_root, task_name, split) / "meta.json").is_file():
            raise ds.DatasetError(f"no {split} data for {task_name} in {data_root}")
    train, test = ds.load_split(data_root, task_name, "train"), ds.load_split(data_root, task_name, "test")
    if train.meta["image_size"] != preset.image_size:
        raise ds.DatasetError(
            f"{data_root}/{task_name} has {train.meta['image_size']}px images but preset {preset.name!r} "
            f"needs {preset.image_size}px; use another --data directory")
    camera = (np.asarray(train.meta["intrinsics"], np.float32), preset.image_size)
    bank = np.asarray(train.motions, np.float32)
    near = {split: split_neighbours(ds.split_dir(data_root, task_name, split), np.asarray(s.motions, np.float32), bank,
                                    *camera, is_bank=split == "train", log=log)
            for split, s in (("train", train), ("test", test))}
    held = slice(0, min(len(test), HELDOUT_EPISODES))
    heldout = MotionDataset(network_image(test.rgb[held], test.depth[held]), np.asarray(test.motions[held], np.float32),
                            near["test"][held])
    return MotionDataset(network_image(train.rgb, train.depth), bank, near["train"]), heldout, camera


def heldout_rivals(train: MotionDataset, heldout: MotionDataset) -> np.ndarray:
    """``[N, 63, 101, 11]``: each held-out motion's nearest training motions (``near_top1``)."""
    return train.motions[heldout.neighbours[:, :training.HELDOUT_NEAR_NEGATIVES]]


def train_task(task_name: str, preset: Preset, data_root, workdir, negatives: str = "in-data+vae",
               dmo_train_steps: int | None = None, seed: int = 0, log=print) -> dict:
    """Train (or load) the VAE, EBM and DMO of one task; returns a summary per model. Each model
    is evaluated on the held-out scenes at the end of its run only: at 96 px an EBM evaluation
    mid-run cost 22-37 s of the cpu preset's 15 minutes."""
    train, heldout, camera = load_task_data(task_name, data_root, preset, log=log)
    paths = RunPaths.of(workdir, task_name, preset)
    r = preset.train.dmo_train_steps if dmo_train_steps is None else dmo_train_steps
    summary = {}
    t0 = time.perf_counter()
    vae_spec = _of_task(training.vae_spec(preset, heldout, mean_pose=train.motions.mean(axis=(0, 1))), task_name)
    vae_params, summary["vae"] = training.fit(vae_spec, train, paths.vae(), seed=seed)
    rivals = heldout_rivals(train, heldout)
    ebm_spec = _of_task(training.ebm_spec(preset, negatives, heldout, heldout_near=rivals, camera=camera), task_name)
    ebm_params, summary["ebm"] = _train_ebm(preset, ebm_spec, negatives, train, paths.ebm(preset, negatives),
                                            vae_params, seed, log)
    dmo_spec = _of_task(training.dmo_spec(preset, r, heldout, camera, heldout_near=rivals), task_name)
    dmo_params, summary["dmo"] = training.fit(dmo_spec, train, paths.dmo(preset, r), extra=vae_params, seed=seed)
    if preset.train.selection_scenes:
        from envs.dataset import load_split

        from .inference import Models
        from .selection import train_selection

        summary["selection"] = train_selection(
            task_name, Models(ebm_params, dmo_params), preset, load_split(data_root, task_name, "train"),
            paths.selection(preset, negatives, r), log)
    summary["total_seconds"] = round(time.perf_counter() - t0, 1)
    return summary


def _train_ebm(preset: Preset, spec: training.ModelSpec, negatives: str, train: MotionDataset, run_dir: Path,
               vae_params, seed: int, log) -> tuple:
    """Train (or load) the EBM of ``spec`` (made from ``preset``): ``(params, summary)``; with mined steps (``training.mined_steps``) in two
    parts: its ``ebm_steps``, then the rest on its own ranking of the bank (``dmo_jax.mining``),
    stored in ``run_dir`` so that a resumed run trains on the same table."""
    from . import mining

    cfg = preset.train
    mined = training.mined_steps(cfg, negatives)
    fit = lambda data, **kw: training.fit(spec, data, run_dir, extra=vae_params, seed=seed, **kw)  # noqa: E731
    if not mined:
        return fit(train)
    params, first = fit(train, stop_after=cfg.ebm_steps)
    t0 = time.perf_counter()
    table = mining.stored_rivals(run_dir, train, cfg.near_pool)
    if table is None:
        if first["steps"] > cfg.ebm_steps:
            raise training.TrainingError(
                f"{run_dir} holds an EBM trained past its {cfg.ebm_steps} steps without the ranking it was mined "
                f"from ({mining.INDEX_FILE}); retrain it in another --workdir")
        table = mining.ranked_rivals(params, preset, train, cfg.near_pool, log=log)
        mining.store_rivals(run_dir, table, train, cfg.ebm_steps)
    mining_seconds = time.perf_counter() - t0
    params, summary = fit(dataclasses.replace(train, neighbours=table))
    summary["seconds"] = round(summary["seconds"] + first["seconds"] + mining_seconds, 2)
    summary["mining_seconds"] = round(mining_seconds, 2)  # included in seconds
    return params, summary


def _of_task(spec: training.ModelSpec, task_name: str) -> training.ModelSpec:
    """``spec`` whose checkpoints also record, and must match, the task."""
    return dataclasses.replace(spec, meta={**spec.meta, "task": task_name})


def network_runs(workdir, task_name: str, preset: Preset, method, negatives: str = "in-data+vae",
                 dmo_train_steps: int | None = None) -> dict[str, tuple[Path, training.ModelSpec]]:
    """The run directory and spec of each network ``method`` (a method name or a list of them)
    needs, by network name (``"ebm"``, then ``"dmo"``, ``"vae"``), in ``bin/train_all``'s work
    directory."""
    from .inference import METHOD_REGISTRY, METHODS

    methods = (method,) if isinstance(method, str) else tuple(method)
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise ValueError(f"unknown method {unknown[0]!r}; expected one of {', '.join(METHODS)}")
    if not isinstance(preset, Preset):
        raise ValueError(f"preset must be a dmo_jax.config.Preset (dmo_jax.get_preset(name)), got {preset!r}")
    paths = RunPaths.of(workdir, task_name, preset)
    needs = {net for m in methods for net in METHOD_REGISTRY[m].needs}
    r = preset.train.dmo_train_steps if dmo_train_steps is None else dmo_train_steps
    runs = {"ebm": (paths.ebm(preset, negatives), training.ebm_spec(preset, negatives))}
    if "dmo" in needs:
        runs["dmo"] = (paths.dmo(preset, r), training.dmo_spec(preset, r))
    if "vae" in needs:
        runs["vae"] = (paths.vae(), training.vae_spec(preset))
    return {net: (path, _of_task(spec, task_name)) for net, (path, spec) in runs.items()}


def describe_networks(workdir, task_name: str, preset: Preset, method, negatives: str = "in-data+vae",
                      dmo_train_steps: int | None = None) -> str:
    """For each network ``method`` needs: its run directory and where the preset its checkpoint
    recorded differs from ``preset`` (``bin/evaluate --show-preset``)."""
    from .config import record_differences

    lines = []
    for net, (path, spec) in network_runs(workdir, task_name, preset, method, negatives, dmo_train_steps).items():
        try:
            saved = training.load_meta(path).get("config")
        except training.TrainingError as err:
            lines.append(f"{net} {path}: {err}")
            continue
        if saved is None:
            lines.append(f"{net} {path}: its checkpoint records no preset (written before checkpoints did)")
            continue
        diff = record_differences(saved, spec.meta["config"])  # the preset as this network would train now
        lines.append(f"{net} {path}: " + ("trained with this preset" if not diff else
                                          "trained with this preset except (checkpoint -> now) " + "; ".join(diff)))
    return "\n".join(lines)


def load_models(workdir, task_name: str, preset: Preset, method, negatives: str = "in-data+vae",
                dmo_train_steps: int | None = None, bank: np.ndarray | None = None):
    """The trained networks ``method`` (a method name or a list of them) needs
    (``dmo_jax.inference.Models``), from ``bin/train_all``'s work directory; raises
    ``training.TrainingError`` naming what is missing or mismatched: networks of another task or
    preset, other settings, or (given the training motions ``bank [N, 101, 11]``) other data."""
    from .inference import METHOD_REGISTRY, Models

    runs = network_runs(workdir, task_name, preset, method, negatives, dmo_train_steps)
    data = None if bank is None else motions_fingerprint(bank)
    nets = {net: training.load_params(path, spec, data)[0] for net, (path, spec) in runs.items()}
    selection = None
    methods = (method,) if isinstance(method, str) else tuple(method)
    if preset.train.selection_scenes and any(METHOD_REGISTRY[m].selected for m in methods):
        from .selection import load_weights

        if bank is None:
            raise ValueError("load_models: a selection head is loaded only with the training motions (bank)")
        r = preset.train.dmo_train_steps if dmo_train_steps is None else dmo_train_steps
        selection = load_weights(RunPaths.of(workdir, task_name, preset).selection(preset, negatives, r), bank)
    return Models(nets["ebm"], nets.get("dmo"), nets.get("vae"), selection)
