"""Training the motion VAE, the EBM and the DMO (docs/method.md, "Training").

One generic loop (:func:`fit`) runs a jitted pure ``train_step(state, batch, key, extra)``
for any of the three models: data parallel over all devices (batch sharded on a ``data``
mesh axis, parameters replicated), orbax checkpoints with automatic resume, a progress
bar, JSON-lines metrics with held-out evaluations, and a non-finite guard that skips a
step whose loss or gradients are not finite. Batches and keys are pure functions of
(seed, step), so a resumed run ends with exactly the parameters of an uninterrupted one.
"""
from __future__ import annotations

import dataclasses
import functools
import json
import os
import time
from pathlib import Path
from typing import Any, Callable

import jax
import jax.numpy as jnp
import numpy as np
import optax
import orbax.checkpoint as ocp
from flax import struct
from jax.sharding import NamedSharding
from jax.sharding import PartitionSpec as P

from envs.progress import Progress

from . import losses, run_metrics
from .config import Preset, TrainConfig, preset_record
from .data import MotionDataset, augment_batch
from .networks import DMONet, EBMNet
from .vae import VAENet

MODELS = ("vae", "ebm", "dmo")


class TrainingError(Exception):
    """Training cannot go on (bad checkpoint, too many non-finite steps, bad settings)."""


@struct.dataclass
class TrainState:
    step: jax.Array
    params: Any
    opt_state: Any
    skipped: jax.Array  # non-finite steps skipped so far

    @classmethod
    def create(cls, params, tx: optax.GradientTransformation) -> "TrainState":
        """Step 0 of a run: ``params`` and ``tx``'s initial state."""
        return cls(jnp.zeros((), jnp.int32), params, tx.init(params), jnp.zeros((), jnp.int32))


def make_optimizer(cfg: TrainConfig) -> optax.GradientTransformation:
    """Adam at ``cfg.lr``, multiplied by ``cfg.lr_decay`` every ``cfg.lr_decay_every`` steps."""
    schedule = optax.exponential_decay(cfg.lr, cfg.lr_decay_every, cfg.lr_decay, staircase=True)
    return optax.adam(schedule)


def maybe_initialize_distributed() -> None:
    """Multi-host training: call ``jax.distributed.initialize`` when ``DMO_COORDINATOR``,
    ``DMO_NUM_PROCESSES`` and ``DMO_PROCESS_ID`` are set (one process per host)."""
    if os.environ.get("DMO_COORDINATOR"):
        try:
            processes, process = int(os.environ.get("DMO_NUM_PROCESSES", "")), int(os.environ.get("DMO_PROCESS_ID", ""))
        except ValueError:
            processes = process = -1
        if not 0 <= process < processes:
            raise TrainingError(f"DMO_COORDINATOR is set, so DMO_NUM_PROCESSES must be a positive integer and "
                                f"DMO_PROCESS_ID one in [0, DMO_NUM_PROCESSES); got DMO_NUM_PROCESSES="
                                f"{os.environ.get('DMO_NUM_PROCESSES')!r}, DMO_PROCESS_ID={os.environ.get('DMO_PROCESS_ID')!r}")
        jax.distributed.initialize(coordinator_address=os.environ["DMO_COORDINATOR"], num_processes=processes,
                                   process_id=process)


def data_mesh(devices=None) -> jax.sharding.Mesh:
    devices = np.asarray(jax.devices() if devices is None else devices)
    return jax.sharding.Mesh(devices, ("data",))


def devices_for_batch(batch_size: int) -> list:
    """All devices; in a single process, the most local devices that split the batch evenly
    (a 12-image batch on 8 devices trains on 6)."""
    devices = jax.devices()
    if jax.process_count() > 1:
        return devices
    return devices[:max(k for k in range(1, len(devices) + 1) if batch_size % k == 0)]


def replicate(mesh: jax.sharding.Mesh, tree):
    """Put a pytree on every device of ``mesh`` (parameters, optimiser state)."""
    return jax.device_put(tree, NamedSharding(mesh, P()))


def shard_batch(mesh: jax.sharding.Mesh, local: dict[str, np.ndarray]) -> dict[str, jax.Array]:
    """This process's part of a batch -> global arrays split along ``data`` (leading axis)."""
    sharding = NamedSharding(mesh, P("data"))
    return {k: jax.make_array_from_process_local_data(sharding, v) for k, v in local.items()}


# --------------------------------------------------------------------------- model specs
@dataclasses.dataclass(frozen=True)
class ModelSpec:
    """What :func:`fit` needs to train one model.

    ``loss_fn(params, batch, key, extra, step) -> (loss, metrics)``; ``eval_fn(params, extra) ->
    metrics`` on held-out data (or None); ``init_fn(key) -> params``; ``meta``: what the
    checkpoint must match to be resumed or loaded; ``near``: each batch also carries every
    positive's ``near`` nearest other training motions (``MotionDataset.batch``).
    """

    name: str
    init_fn: Callable
    loss_fn: Callable
    eval_fn: Callable | None
    steps: int
    batch_size: int
    meta: dict
    config: TrainConfig
    near: int = 0


def vae_spec(preset: Preset, heldout: MotionDataset | None = None, mean_pose=None) -> ModelSpec:
    """``mean_pose [11]``: the training motions' mean pose, where the decoder starts
    (:meth:`VAENet.init_at_mean`); without it the decoder starts near zero."""
    net, cfg = VAENet.from_preset(preset), preset.train
    init_fn = net.init if mean_pose is None else functools.partial(net.init_at_mean, mean_pose=mean_pose)

    def loss_fn(params, batch, key, extra, step):
        return losses.vae_loss(net, params, batch["motions"], key, cfg, step)

    @jax.jit
    def evaluate(params, motions):
        recon = net.decode(params, net.encode(params, motions)[0])
        return {f"recon_{k}": v for k, v in losses.motion_errors(recon, motions).items()}

    def eval_fn(params, extra):
        return evaluate(params, jnp.asarray(heldout.motions))

    return ModelSpec("vae", init_fn, loss_fn, eval_fn if heldout is not None else None, cfg.vae_steps,
                     cfg.vae_batch, {"model": "vae", "preset": preset.name, "config": preset_record(preset)}, cfg)


#: The held-out ranking's negatives: the paper's counts, whatever the preset trains with.
HELDOUT_GT_NEGATIVES, HELDOUT_VAE_NEGATIVES = 31, 32


def heldout_ebm_candidates(preset: Preset, vae_params, motions) -> jax.Array:
    """The EBM's held-out ranking problem: each of ``motions [N, 101, 11]`` first (index 0),
    then the paper's 63 negatives, 31 other held-out motions (indices 1..31) and 32 VAE samples
    at 2 sigma; a fixed key, so every evaluation ranks the same sets."""
    counts = dataclasses.replace(preset.train, ebm_gt_negatives=HELDOUT_GT_NEGATIVES,
                                 ebm_vae_negatives=HELDOUT_VAE_NEGATIVES, ebm_near_negatives=0)
    return losses.ebm_candidates(VAENet.from_preset(preset), vae_params, jnp.asarray(motions),
                                 jax.random.key(1234), counts, "in-data+vae")


#: ``near_top1``: the positive against its this many nearest training motions (the bank's closest rivals).
HELDOUT_NEAR_NEGATIVES = 63


def near_negatives_meta(cfg: TrainConfig, negatives: str) -> list[int]:
    """``[near negatives, pool]`` an EBM trains with (``[0, 0]`` when off, and for only-VAE
    negatives, which draw none): in its checkpoints and its directory's name."""
    return [cfg.ebm_near_negatives, cfg.near_pool] if cfg.ebm_near_negatives and negatives == "in-data+vae" else [0, 0]


def mined_steps(cfg: TrainConfig, negatives: str) -> int:
    """The steps an EBM trains on its own ranking of the bank (``ebm_mined_steps``) after its
    ``ebm_steps``: 0 without near negatives, which the mined motions replace."""
    return cfg.ebm_mined_steps if near_negatives_meta(cfg, negatives)[0] else 0


def ebm_spec(preset: Preset, negatives: str = "in-data+vae", heldout: MotionDataset | None = None,
             augment: bool = True, heldout_near: np.ndarray | None = None,
             camera: tuple | None = None) -> ModelSpec:
    """``extra`` = the trained VAE's parameters (they make the negatives). ``heldout_near
    [N, 63, 101, 11]``: each held-out motion's nearest training motions, for ``near_top1``.
    ``camera`` ``(K, image_size)``: the data's, needed to train with ``ebm_target_scale``."""
    if negatives not in losses.NEGATIVE_MODES:
        raise ValueError(f"unknown negatives {negatives!r}; expected one of {losses.NEGATIVE_MODES}")
    net, vae, cfg = EBMNet(preset), VAENet.from_preset(preset), preset.train
    near_meta = near_negatives_meta(cfg, negatives)

    def loss_fn(params, batch, key, vae_params, step):
        k_neg, k_aug, k_loss = jax.random.split(key, 3)
        images = augment_batch(batch["images"], k_aug) if augment else batch["images"]
        cands = losses.ebm_candidates(vae, vae_params, batch["motions"], k_neg, cfg, negatives, batch.get("near"))
        targets = None
        if cfg.ebm_target_scale:
            if camera is None:
                raise TrainingError("graded EBM targets (ebm_target_scale > 0) need the data's camera")
            targets = losses.graded_targets(cands, *camera, cfg.ebm_target_scale)
        return losses.ebm_loss(net, params, images, cands, k_loss, targets)

    @jax.jit  # compiled once per run, the VAE's negatives included
    def evaluate(params, vae_params, images, motions, rivals):
        metrics = losses.ebm_eval(net, params, images, heldout_ebm_candidates(preset, vae_params, motions))
        if rivals is not None:
            energies = losses.ebm_energies(net, params, images, jnp.concatenate([motions[:, None], rivals], axis=1))
            metrics["near_top1"] = jnp.mean(jnp.argmin(energies, axis=-1) == 0)
            if camera is not None:  # the bank without the positive, as at prediction: how far is the first choice?
                first = jnp.take_along_axis(rivals, jnp.argmin(energies[:, 1:], axis=-1)[:, None, None, None], 1)[:, 0]
                metrics["near_first_error"] = jnp.mean(
                    jax.vmap(lambda m, t: losses.position_error(m, t, *camera))(first, motions))
        return metrics

    def eval_fn(params, vae_params):
        rivals = None if heldout_near is None else jnp.asarray(heldout_near)
        return evaluate(params, vae_params, jnp.asarray(heldout.images), jnp.asarray(heldout.motions), rivals)

    return ModelSpec("ebm", net.init, loss_fn, eval_fn if heldout is not None else None,
                     cfg.ebm_steps + mined_steps(cfg, negatives), cfg.ebm_batch,
                     {"model": "ebm", "preset": preset.name, "variant": preset.variant, **_head_meta(preset),
                      "negatives": negatives, "near_negatives": near_meta, "target_scale": cfg.ebm_target_scale,
                      "negative_counts": [cfg.ebm_gt_negatives, cfg.ebm_vae_negatives],
                      "config": preset_record(preset)},
                     cfg, near_meta[1])


#: ``near_position_*``: the DMO on each held-out scene's this many nearest training motions.
HELDOUT_NEAR_STARTS = 8


def dmo_spec(preset: Preset, train_steps: int | None = None, heldout: MotionDataset | None = None,
             heldout_camera: tuple | None = None, augment: bool = True,
             heldout_near: np.ndarray | None = None) -> ModelSpec:
    """``extra`` = the trained VAE's parameters (they make the perturbed inputs). The held-out
    errors are on the DMO's kind of inputs made from the held-out motions and, given
    ``heldout_near [N, >= 8, 101, 11]`` (each held-out motion's nearest training motions), on
    its 8 nearest bank motions, what prediction feeds it (``near_position_before`` / ``_after``)."""
    net, vae, cfg = DMONet(preset), VAENet.from_preset(preset), preset.train
    r = cfg.dmo_train_steps if train_steps is None else train_steps
    if r < 1:
        raise ValueError(f"the DMO needs at least one training iteration, got {r}")

    def loss_fn(params, batch, key, vae_params, step):
        k_in, k_aug, k_loss = jax.random.split(key, 3)
        images = augment_batch(batch["images"], k_aug) if augment else batch["images"]
        inputs = losses.dmo_inputs(vae, vae_params, batch["motions"], k_in, cfg)
        return losses.dmo_loss(net, params, images, inputs, batch["motions"], k_loss, r, cfg.uv_weight)

    @jax.jit  # compiled once per run, the VAE's inputs included
    def evaluate(params, vae_params, images, motions, starts):
        inputs = losses.dmo_inputs(vae, vae_params, motions, jax.random.key(4321), cfg)
        metrics = losses.dmo_eval(net, params, images, inputs, motions, cfg.dmo_infer_iters, *heldout_camera, r)
        if starts is not None:
            metrics.update(losses.dmo_position_change(net, params, images, starts, motions, cfg.dmo_infer_iters,
                                                      *heldout_camera))
        return metrics

    def eval_fn(params, vae_params):
        starts = None if heldout_near is None else jnp.asarray(heldout_near[:, :HELDOUT_NEAR_STARTS])
        return evaluate(params, vae_params, jnp.asarray(heldout.images), jnp.asarray(heldout.motions), starts)

    return ModelSpec("dmo", net.init, loss_fn, eval_fn if heldout is not None else None, cfg.dmo_steps,
                     cfg.dmo_batch, {"model": "dmo", "preset": preset.name, "variant": preset.variant,
                                     **_head_meta(preset),
                                     "train_iters": r, "inputs": cfg.dmo_inputs,
                                     "config": preset_record(dataclasses.replace(
                                         preset, train=dataclasses.replace(cfg, dmo_train_steps=r)))}, cfg)


# --------------------------------------------------------------------------- the loop
def make_train_step(spec: ModelSpec, tx: optax.GradientTransformation):
    """The pure step ``(state, batch, key, extra) -> (state, metrics)``; a step whose loss or
    gradients are not finite leaves parameters and optimiser state unchanged."""

    def train_step(state: TrainState, batch, key, extra):
        (loss, metrics), grads = jax.value_and_grad(spec.loss_fn, has_aux=True)(state.params, batch, key, extra,
                                                                               state.step)
        finite = jnp.isfinite(loss) & jnp.all(jnp.array([jnp.all(jnp.isfinite(g)) for g in jax.tree.leaves(grads)]))
        updates, opt_state = tx.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        keep = lambda new, old: jax.tree.map(lambda n, o: jnp.where(finite, n, o), new, old)
        state = TrainState(state.step + 1, keep(params, state.params), keep(opt_state, state.opt_state),
                           state.skipped + (~finite).astype(jnp.int32))
        return state, {"loss": loss, "finite": finite, **metrics}

    return train_step


def _checkpoint_manager(path: Path, keep: int) -> ocp.CheckpointManager:
    return ocp.CheckpointManager(
        path.resolve(), options=ocp.CheckpointManagerOptions(max_to_keep=keep, create=True),
        item_names=("state", "meta"),
    )


def _head_meta(preset: Preset) -> dict:
    """How the head reads depth (``config.HEAD_OVERRIDES``) and the image size: they change what a
    checkpoint computes without changing any parameter's shape, so only this record tells."""
    head = preset.head
    return {"depth_cue": head.depth_cue, "depth_cue_range": head.depth_cue_range, "image_size": preset.image_size}


def _check_meta(saved: dict, expected: dict, path: Path) -> None:
    """Raise unless ``saved`` holds every ``expected`` setting that decides what a checkpoint
    computes. The whole preset it records (``"config"``) is not compared: more steps continue a
    run, and prediction settings such as the bank's coarse scoring change no network."""
    diff = {k: (saved.get(k), v) for k, v in expected.items() if k != "config" and saved.get(k) != v}
    if diff:
        detail = ", ".join(f"{k}: checkpoint has {a!r}, expected {b!r}" for k, (a, b) in diff.items())
        raise TrainingError(f"checkpoint at {path} was made with other settings ({detail}); "
                            "use another --workdir or the matching settings")


def _restore(mngr: ocp.CheckpointManager, step: int, args, path: Path):
    """``mngr.restore`` with any failure (orbax raises many exception types for unreadable,
    truncated or foreign checkpoints) turned into one :class:`TrainingError` line."""
    try:
        return mngr.restore(step, args=args)
    except Exception as err:  # noqa: BLE001 - re-raised as TrainingError with the cause attached
        lines = [l.strip() for l in str(err).splitlines() if l.strip()]
        detail = f"{type(err).__name__}: {lines[0]}" if lines else type(err).__name__
        raise TrainingError(f"cannot read checkpoint step {step} in {path} ({detail}); remove that step's "
                            "directory to fall back to the previous checkpoint, or retrain") from err


def _check_data(saved: dict, fingerprint: str | None, path: Path) -> None:
    """Raise unless the checkpoint's training data (``saved["dataset"]["fingerprint"]``) is the data
    of ``fingerprint`` (None: not checked)."""
    had = (saved.get("dataset") or {}).get("fingerprint")
    if fingerprint is not None and had != fingerprint:
        raise TrainingError(f"checkpoint at {path} was trained on other data (training motions {had}, these are "
                            f"{fingerprint}); use another --workdir or the data it was trained on")


def _latest(workdir: str | Path) -> tuple[ocp.CheckpointManager, int, Path, dict]:
    """The checkpoint manager, latest step, directory and metadata of the run in ``workdir``."""
    path = Path(workdir) / "checkpoints"
    mngr = _checkpoint_manager(path, 1) if path.is_dir() else None
    step = None if mngr is None else mngr.latest_step()
    if step is None:
        raise TrainingError(f"no checkpoint in {path}: train this model first (bin/train_all)")
    return mngr, step, path, _restore(mngr, step, ocp.args.Composite(meta=ocp.args.JsonRestore()), path)["meta"]


def load_meta(workdir: str | Path) -> dict:
    """The metadata of the latest checkpoint of the run in ``workdir`` (the directory given to
    :func:`fit`), unchecked: the settings it was trained with (``"config"``: the whole preset,
    :func:`dmo_jax.config.preset_record`), its data and step count."""
    return _latest(workdir)[3]


def load_params(workdir: str | Path, spec: ModelSpec, data_fingerprint: str | None = None):
    """Parameters and metadata of the latest checkpoint of the run in ``workdir`` (the directory
    given to :func:`fit`), checked against ``spec.meta`` and, when given, against the
    fingerprint of the training motions (``data.motions_fingerprint``) it must have learnt from."""
    mngr, step, path, meta = _latest(workdir)
    _check_meta(meta, spec.meta, path)
    _check_data(meta, data_fingerprint, path)
    abstract = jax.eval_shape(spec.init_fn, jax.random.key(0))
    state = _restore(mngr, step, ocp.args.Composite(
        state=ocp.args.PyTreeRestore(item={"params": abstract},
                                     restore_args=jax.tree.map(lambda _: ocp.RestoreArgs(restore_type=np.ndarray), {"params": abstract}),
                                     partial_restore=True)), path)
    return jax.tree.map(jnp.asarray, state["state"]["params"]), meta


def fit(
    spec: ModelSpec,
    dataset: MotionDataset,
    workdir: str | Path,
    extra: Any = None,
    seed: int = 0,
    log_every: int = 50,
    eval_every: int | None = None,
    checkpoint_every: int = 250,
    checkpoint_minutes: float | None = 10.0,
    keep: int = 3,
    max_consecutive_skips: int = 20,
    stop_after: int | None = None,
    verbose: bool = True,
    devices=None,
) -> tuple[Any, dict]:
    """Train ``spec`` on ``dataset`` in ``workdir`` (resuming any checkpoint there).

    Returns (params, summary). ``stop_after`` ends the run early at that step (after saving),
    as an interruption would. ``extra``: a pytree passed to every step (the VAE parameters
    for the EBM and the DMO), replicated on all devices. A checkpoint is saved every
    ``checkpoint_every`` steps, at the end, and whenever ``checkpoint_minutes`` have passed since
    the last save, so a slow model loses at most that much work when interrupted (ViT's EBM took
    about 30 minutes per 250 steps on a shared 2-core machine).
    """
    workdir = Path(workdir)
    workdir.mkdir(parents=True, exist_ok=True)
    from envs.dataset import writer_lock

    with writer_lock(workdir / ".lock", TrainingError):
        return _fit(spec, dataset, workdir, extra, seed, log_every, eval_every, checkpoint_every, checkpoint_minutes,
                    keep, max_consecutive_skips, stop_after, verbose, devices)


def _fit(spec, dataset, workdir, extra, seed, log_every, eval_every, checkpoint_every, checkpoint_minutes, keep,
         max_consecutive_skips, stop_after, verbose, devices):
    mesh = data_mesh(devices if devices is not None else devices_for_batch(spec.batch_size))
    n_dev = mesh.devices.size
    if spec.batch_size % n_dev:
        raise TrainingError(f"batch size {spec.batch_size} is not divisible by the {n_dev} devices")
    if spec.batch_size // jax.process_count() > len(dataset):
        raise TrainingError(f"{spec.name}: batch size {spec.batch_size} exceeds the {len(dataset)} training "
                            "episodes; generate more data (bin/generate_data --train N)")
    tx = make_optimizer(spec.config)
    meta = {**spec.meta, "steps": spec.steps, "batch_size": spec.batch_size, "seed": seed,
            "dataset": dataset.statistics()}

    mngr = _checkpoint_manager(workdir / "checkpoints", keep)
    latest = mngr.latest_step()  # only committed checkpoints count; unfinished saves are ignored
    if latest is not None:  # a checkpoint of other settings fails before anything is compiled
        saved_meta = _restore(mngr, latest, ocp.args.Composite(meta=ocp.args.JsonRestore()), workdir)["meta"]
        # More steps continue a run: the learning rate, batches and keys depend on the step only.
        _check_meta(saved_meta, {k: v for k, v in meta.items() if k not in ("dataset", "steps")}, workdir)
        _check_data(saved_meta, meta["dataset"]["fingerprint"], workdir)
        if latest > spec.steps:
            raise TrainingError(f"checkpoint at {workdir} is at step {latest}, beyond the {spec.steps} steps "
                                f"asked for; use another --workdir or at least {latest} steps")
    params = spec.init_fn(jax.random.fold_in(jax.random.key(seed), 0))
    state = TrainState.create(params, tx)
    if latest is not None:
        restored = _restore(mngr, latest, ocp.args.Composite(state=ocp.args.StandardRestore(_host(state))), workdir)
        state = jax.tree.map(jnp.asarray, restored["state"])
    state = replicate(mesh, state)
    extra = replicate(mesh, extra) if extra is not None else None
    step_fn = jax.jit(make_train_step(spec, tx), donate_argnums=0)
    metrics_path = workdir / "metrics.jsonl"
    _truncate_metrics(metrics_path, int(state.step))

    start = int(state.step)
    end = spec.steps if stop_after is None else min(stop_after, spec.steps)
    title = " ".join(str(x) for x in (spec.meta.get("task"), spec.meta.get("preset"), workdir.name) if x)
    progress = Progress(f"train {spec.name}", spec.steps, initial=start) if verbose and start < end else None
    base_key = jax.random.key(seed)
    t0, consecutive_skips, last, pending = time.perf_counter(), 0, {}, None
    last_save = t0

    def count_skips(finite, skips):
        skips = 0 if bool(finite) else skips + 1
        if skips > max_consecutive_skips:
            raise TrainingError(
                f"{spec.name}: {skips} consecutive steps with non-finite loss or gradients; "
                f"stopped. Last good checkpoint: step {mngr.latest_step()} in {workdir / 'checkpoints'}")
        return skips

    for step in range(start, end):
        local = dataset.batch(seed, step, spec.batch_size // jax.process_count(), jax.process_index(), spec.near)
        state, metrics = step_fn(state, shard_batch(mesh, local), jax.random.fold_in(base_key, step + 1), extra)
        done = step + 1
        # The previous step's flag is read only now, so the host prepares this batch while
        # the device still runs the previous step (a skipped step leaves the state as it was).
        if pending is not None:
            consecutive_skips = count_skips(pending, consecutive_skips)
        pending = metrics["finite"]
        evaluate = spec.eval_fn is not None and (done == spec.steps or bool(eval_every and done % eval_every == 0))
        if done % log_every == 0 or done == end or evaluate:
            last = {k: float(v) for k, v in metrics.items()}
            record = {"step": done, **last, "skipped": int(state.skipped), "time": round(time.perf_counter() - t0, 2)}
            if evaluate:
                record.update({f"heldout_{k}": float(v) for k, v in spec.eval_fn(state.params, extra).items()})
            _append_jsonl(metrics_path, record)
            if evaluate and done < end:  # the last one is exported after the loop
                run_metrics.export(workdir, title)
            if progress:
                progress.update(done, f"loss {last['loss']:.4f}")
        overdue = checkpoint_minutes is not None and time.perf_counter() - last_save >= 60 * checkpoint_minutes
        if done % checkpoint_every == 0 or done == end or overdue:
            last_save = time.perf_counter()
            host = _host(state)
            if not all(np.isfinite(x).all() for x in jax.tree.leaves(host.params)):
                raise TrainingError(f"{spec.name}: parameters are not finite at step {done}; not saved. Last good "
                                    f"checkpoint: step {mngr.latest_step()} in {workdir / 'checkpoints'}")
            mngr.save(done, args=ocp.args.Composite(state=ocp.args.StandardSave(host),
                                                    meta=ocp.args.JsonSave(meta)))
    if pending is not None:
        count_skips(pending, consecutive_skips)
    mngr.wait_until_finished()
    if pending is not None and not bool(pending):
        raise TrainingError(f"{spec.name}: the last step's loss or gradients were not finite (the step was "
                            f"skipped: the parameters saved at step {end} are the last finite ones, in "
                            f"{workdir / 'checkpoints'}); check the settings and the data")
    if progress:
        progress.close()
    if start < end:
        run_metrics.export(workdir, title)
    summary = {"model": spec.name, "steps": int(state.step), "seconds": round(time.perf_counter() - t0, 2),
               "skipped_steps": int(state.skipped), **_last_heldout(metrics_path)}
    return jax.device_get(state.params), summary


def _host(tree):
    return jax.device_get(tree)


def _append_jsonl(path: Path, record: dict) -> None:
    with open(path, "a") as f:
        f.write(json.dumps(record) + "\n")
        f.flush()
        os.fsync(f.fileno())


def _truncate_metrics(path: Path, step: int) -> None:
    """Drop metric lines written after the checkpoint being resumed (they will be redone), and a
    last line torn by a crash in the middle of writing it."""
    if not path.exists():
        return

    def kept(line: str) -> bool:
        try:
            return json.loads(line)["step"] <= step
        except (ValueError, KeyError, TypeError):
            return False

    from envs.dataset import atomic_write_text

    lines = [l for l in path.read_text().splitlines() if l.strip() and kept(l)]
    atomic_write_text(path, "".join(l + "\n" for l in lines))


def _last_heldout(path: Path) -> dict:
    if not path.exists():
        return {}
    for line in reversed(path.read_text().splitlines()):
        record = json.loads(line)
        heldout = {k: v for k, v in record.items() if k.startswith("heldout_")}
        if heldout:
            return heldout
    return {}
