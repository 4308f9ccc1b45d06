"""Training: losses decrease, resume is exact, data parallel equals single device, checkpoints
describe themselves."""
import dataclasses
import json
import os
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dmo_jax import data as data_lib
from dmo_jax import training
from dmo_jax.config import get_preset, preset_record
from envs import dataset
from envs.tasks import get_task
from helpers import run_on_two_devices

TINY = get_preset("tiny")


def _fast(preset, steps, **kw):
    return dataclasses.replace(preset, train=dataclasses.replace(
        preset.train, lr=1e-3, vae_steps=steps, ebm_steps=steps, dmo_steps=steps, **kw))


@pytest.fixture(scope="module")
def task_data(tmp_path_factory):
    root = tmp_path_factory.mktemp("data")
    task = get_task("reach_target", TINY.image_size)
    dataset.generate_split(task, "train", 16, root, batch=16, verbose=False)
    dataset.generate_split(task, "test", 8, root, batch=16, verbose=False)
    train = data_lib.MotionDataset.from_split(dataset.load_split(root, "reach_target", "train"))
    test = data_lib.MotionDataset.from_split(dataset.load_split(root, "reach_target", "test"))
    return train, test, (task.world.camera.intrinsics.astype(np.float32), TINY.image_size)


@pytest.fixture(scope="module")
def vae_params(task_data, tmp_path_factory):
    params, _ = training.fit(training.vae_spec(_fast(TINY, 30)), task_data[0], tmp_path_factory.mktemp("vae"),
                             verbose=False)
    return params


def _losses(workdir):
    return [json.loads(l)["loss"] for l in (Path(workdir) / "metrics.jsonl").read_text().splitlines()]


def _decreases(values, k=5):
    return np.mean(values[-k:]) < 0.9 * np.mean(values[:k])


def test_vae_loss_decreases(task_data, tmp_path):
    training.fit(training.vae_spec(_fast(TINY, 30)), task_data[0], tmp_path, log_every=1, verbose=False)
    assert _decreases(_losses(tmp_path))


def test_vae_kl_weight_warms_up_linearly_then_stays(task_data, tmp_path):
    preset = _fast(TINY, 14, vae_kl_warmup=10)
    training.fit(training.vae_spec(preset), task_data[0], tmp_path, log_every=1, verbose=False)
    records = [json.loads(l) for l in (tmp_path / "metrics.jsonl").read_text().splitlines()]
    assert [r["step"] for r in records] == list(range(1, 15))
    for r in records:  # the loss of step s (logged as s + 1) weighs the KL by min(1, s / 10) * 0.01
        weight = preset.train.vae_kl_weight * min(1.0, (r["step"] - 1) / 10)
        assert r["loss"] == pytest.approx(r["recon"] + weight * r["kl"], rel=1e-5)
    assert records[0]["loss"] == pytest.approx(records[0]["recon"]) and records[0]["kl"] > 0


def test_ebm_loss_decreases(task_data, vae_params, tmp_path):
    spec = training.ebm_spec(_fast(TINY, 40), heldout=task_data[1], augment=False)
    _, summary = training.fit(spec, task_data[0], tmp_path, extra=vae_params, log_every=1, verbose=False)
    assert _decreases(_losses(tmp_path))
    assert 0.0 <= summary["heldout_top1"] <= 1.0
    # the record for people: TensorBoard event files a TensorBoard reader loads, and a plot
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    events = EventAccumulator(str(tmp_path / "tensorboard"))
    events.Reload()
    loss = events.Scalars("train/loss")
    assert [e.step for e in loss] == list(range(1, 41))
    np.testing.assert_allclose([e.value for e in loss], _losses(tmp_path), rtol=1e-6)
    assert [e.step for e in events.Scalars("heldout/top1")][-1] == 40
    png = (tmp_path / "metrics.png").read_bytes()
    assert png.startswith(b"\x89PNG") and len(png) > 5000


def test_dmo_loss_decreases(task_data, vae_params, tmp_path):
    spec = training.dmo_spec(_fast(TINY, 30), heldout=task_data[1], heldout_camera=task_data[2], augment=False)
    _, summary = training.fit(spec, task_data[0], tmp_path, extra=vae_params, log_every=1, verbose=False)
    assert _decreases(_losses(tmp_path))
    assert summary["heldout_position_before"] > 0


def test_heldout_top1_in_chunks_equals_each_image_ranked_alone(task_data, vae_params):
    from dmo_jax import losses
    from dmo_jax.networks import EBMNet

    ebm, (_, test, _) = EBMNet(TINY), task_data
    params = ebm.init(jax.random.key(0))
    images = jnp.asarray(test.images[:5])
    candidates = training.heldout_ebm_candidates(TINY, vae_params, test.motions[:5])
    alone = jax.jit(lambda image, cands: ebm.energy(params, ebm.encode(params, image[None])[0], cands))
    energies = np.stack([np.asarray(alone(images[i], candidates[i])) for i in range(5)])
    winners = energies.argmin(axis=1)
    expected = np.mean(winners == 0)
    top1 = {chunk: jax.jit(lambda c, chunk=chunk: losses.ebm_eval(ebm, params, images, c, chunk)["top1"])
            for chunk in (2, 5)}  # 2 leaves a remainder of one image
    for chunk in top1:
        assert float(top1[chunk](candidates)) == pytest.approx(expected)
    # With each image's lowest-energy candidate put in first place, every positive wins.
    swapped = candidates.at[:, 0].set(candidates[jnp.arange(5), winners])
    assert float(top1[2](swapped)) == 1.0


def test_offset_dmo_inputs_carry_the_vae_perturbation_without_its_reconstruction_error(task_data, vae_params):
    from dmo_jax import losses
    from dmo_jax.vae import VAENet

    vae, motions, key = VAENet.from_preset(TINY), jnp.asarray(task_data[0].motions[:4]), jax.random.key(3)
    decoded = losses.dmo_inputs(vae, vae_params, motions, key, TINY.train)
    offset = losses.dmo_inputs(vae, vae_params, motions, key, dataclasses.replace(TINY.train, dmo_inputs="offset"))
    recon = vae.decode(vae_params, vae.encode(vae_params, motions)[0])
    np.testing.assert_allclose(offset[..., :9], (motions + decoded - recon)[..., :9], atol=1e-5)
    assert float(offset[..., 9].min()) >= 0.0 and float(offset[..., 9].max()) <= 1.0
    # At sigma 0 the offset inputs are the clean motions; the paper's are the reconstructions.
    at_mean = dataclasses.replace(TINY.train, dmo_input_sigma=0.0)
    np.testing.assert_allclose(losses.dmo_inputs(vae, vae_params, motions, key, at_mean), recon, atol=1e-6)
    clean = losses.dmo_inputs(vae, vae_params, motions, key, dataclasses.replace(at_mean, dmo_inputs="offset"))
    np.testing.assert_allclose(clean, motions, atol=1e-5)
    with pytest.raises(ValueError, match="dmo_inputs='noisy': expected one of decoded, offset"):
        TINY.with_overrides(["dmo_inputs=noisy"])


def test_resumed_run_ends_with_the_same_parameters(task_data, tmp_path):
    spec = training.vae_spec(_fast(TINY, 12))
    full, _ = training.fit(spec, task_data[0], tmp_path / "full", checkpoint_every=4, verbose=False)
    training.fit(spec, task_data[0], tmp_path / "cut", checkpoint_every=4, stop_after=6, verbose=False)
    resumed, summary = training.fit(spec, task_data[0], tmp_path / "cut", checkpoint_every=4, verbose=False)
    assert summary["steps"] == 12
    jax.tree.map(lambda a, b: np.testing.assert_array_equal(a, b), full, resumed)
    # Metrics of the resumed run do not repeat steps.
    steps = [json.loads(l)["step"] for l in (tmp_path / "cut/metrics.jsonl").read_text().splitlines()]
    assert steps == sorted(set(steps))


def test_checkpoints_are_also_saved_by_elapsed_time(task_data, tmp_path):
    spec = training.vae_spec(_fast(TINY, 4))
    saved = {}
    for name, minutes in (("steps", None), ("time", 0.0)):
        training.fit(spec, task_data[0], tmp_path / name, checkpoint_every=100, checkpoint_minutes=minutes, keep=10,
                     verbose=False)
        saved[name] = sorted(training._checkpoint_manager(tmp_path / name / "checkpoints", 10).all_steps())
    assert saved == {"steps": [4], "time": [1, 2, 3, 4]}


def test_trained_model_is_loaded_not_retrained(task_data, tmp_path):
    spec = training.vae_spec(_fast(TINY, 4))
    first, _ = training.fit(spec, task_data[0], tmp_path, verbose=False)
    again, summary = training.fit(spec, task_data[0], tmp_path, verbose=False)
    jax.tree.map(lambda a, b: np.testing.assert_array_equal(a, b), first, again)
    loaded, meta = training.load_params(tmp_path, spec)
    jax.tree.map(lambda a, b: np.testing.assert_array_equal(a, b), first, loaded)
    assert meta["preset"] == "tiny" and meta["dataset"]["episodes"] == 16


def test_checkpoint_of_other_settings_fails_clearly(task_data, tmp_path):
    training.fit(training.vae_spec(_fast(TINY, 2)), task_data[0], tmp_path, verbose=False)
    other = training.vae_spec(get_preset("cpu"))
    with pytest.raises(training.TrainingError, match="preset: checkpoint has 'tiny', expected 'cpu'"):
        training.load_params(tmp_path, other)
    with pytest.raises(training.TrainingError, match="seed: checkpoint has 0, expected 1"):
        training.fit(training.vae_spec(_fast(TINY, 2)), task_data[0], tmp_path, seed=1, verbose=False)
    with pytest.raises(training.TrainingError, match="at step 2, beyond the 1 steps"):
        training.fit(training.vae_spec(_fast(TINY, 1)), task_data[0], tmp_path, verbose=False)


def test_checkpoint_refuses_another_depth_cue_range_image_size_or_negative_count(task_data, vae_params, tmp_path):
    # the cue's range changes what the network computes but no parameter shape
    cue = _fast(TINY, 1).with_overrides(["depth_cue=true"])
    training.fit(training.ebm_spec(cue), task_data[0], tmp_path, extra=vae_params, verbose=False)
    ranged = cue.with_overrides(["depth_cue_range=0.1"])
    with pytest.raises(training.TrainingError, match=r"depth_cue_range: checkpoint has 0.0, expected 0.1"):
        training.load_params(tmp_path, training.ebm_spec(ranged))
    # so do other negatives: an EBM trained against 3 in-data negatives is not the one asked for with 2
    fewer = cue.with_overrides(["ebm_gt_negatives=2"])
    with pytest.raises(training.TrainingError, match=r"negative_counts: checkpoint has \[3, 4\], expected \[2, 4\]"):
        training.load_params(tmp_path, training.ebm_spec(fewer))
    # the image size changes no parameter shape either
    with pytest.raises(training.TrainingError, match=r"image_size: checkpoint has 32, expected 64"):
        training.load_params(tmp_path, training.ebm_spec(cue.with_overrides(["image_size=64"])))
    # what it was trained with is recorded whole, for bin/evaluate --show-preset
    assert training.load_meta(tmp_path)["config"] == preset_record(cue)


def test_more_steps_continue_a_finished_run(task_data, tmp_path):
    longer = training.vae_spec(_fast(TINY, 6))
    direct, _ = training.fit(longer, task_data[0], tmp_path / "direct", verbose=False)
    training.fit(training.vae_spec(_fast(TINY, 3)), task_data[0], tmp_path / "cont", verbose=False)
    continued, summary = training.fit(longer, task_data[0], tmp_path / "cont", verbose=False)
    assert summary["steps"] == 6
    jax.tree.map(lambda a, b: np.testing.assert_array_equal(a, b), direct, continued)


def test_non_finite_steps_are_skipped_then_stop_the_run(task_data, tmp_path):
    spec = training.vae_spec(_fast(TINY, 10))
    bad = dataclasses.replace(spec, loss_fn=lambda p, b, k, e, s: (jnp.nan * spec.loss_fn(p, b, k, e, s)[0], {}))
    with pytest.raises(training.TrainingError, match="non-finite.*Last good checkpoint"):
        training.fit(bad, task_data[0], tmp_path, max_consecutive_skips=3, verbose=False)


def test_a_run_whose_last_loss_is_not_finite_fails_however_short(task_data, tmp_path):
    spec = training.vae_spec(_fast(TINY, 2))  # fewer steps than the non-finite guard waits for
    bad = dataclasses.replace(spec, loss_fn=lambda p, b, k, e, s: (jnp.nan * spec.loss_fn(p, b, k, e, s)[0], {}))
    with pytest.raises(training.TrainingError, match="the last step's loss or gradients were not finite"):
        training.fit(bad, task_data[0], tmp_path, verbose=False)
    params, _ = training.load_params(tmp_path, spec)  # what was saved is the last finite parameters
    assert all(np.isfinite(x).all() for x in jax.tree.leaves(params))


def test_non_finite_parameters_are_never_saved_however_short_the_run(task_data, tmp_path):
    spec = training.vae_spec(_fast(TINY, 2))  # fewer steps than the non-finite guard waits for
    nan_init = dataclasses.replace(spec, init_fn=lambda k: jax.tree.map(lambda x: x * jnp.nan, spec.init_fn(k)))
    with pytest.raises(training.TrainingError, match="parameters are not finite at step 2; not saved"):
        training.fit(nan_init, task_data[0], tmp_path, verbose=False)
    with pytest.raises(training.TrainingError, match="no checkpoint"):
        training.load_params(tmp_path, spec)


def test_augmentation_changes_rgb_only():
    img = jax.random.uniform(jax.random.key(0), (6, 32, 32, 4))
    out = data_lib.augment_batch(img, jax.random.key(1))
    np.testing.assert_array_equal(out[..., 3], img[..., 3])
    assert float(out.min()) >= 0.0 and float(out.max()) <= 1.0
    np.testing.assert_array_equal(out, data_lib.augment_batch(img, jax.random.key(1)))


_TWO_DEVICES = r"""
import sys, json
sys.path.insert(0, sys.argv[1])
sys.path.insert(0, sys.argv[1] + "/tests")
from envs.platform import setup
setup()
import jax, optax, numpy as np
from dmo_jax import training, data as data_lib
from dmo_jax.config import get_preset, preset_record
import dataclasses
assert jax.device_count() == 2, jax.devices()
rng = np.random.default_rng(0)
motions = np.concatenate([rng.uniform(-1, 1, (8, 101, 10)), np.tile(np.linspace(0, 1, 101)[None, :, None], (8, 1, 1))], -1)
ds = data_lib.MotionDataset(rng.uniform(0, 1, (8, 32, 32, 4)).astype(np.float32), motions.astype(np.float32))
p = get_preset("tiny")
# a two-level encoder: what is compared is the sharding of one step, and this compiles faster
p = dataclasses.replace(p, encoder=dataclasses.replace(p.encoder, dims=(8, 16), enc_depths=(1, 1), dec_depths=(1,)),
                        train=dataclasses.replace(p.train, ebm_batch=4))
from helpers import random_params  # not init: its op-by-op compilation would take longer than the step
vae = random_params(training.VAENet.from_preset(p), 3)
spec = training.ebm_spec(p)
tx = optax.sgd(1e4)  # the update is (a multiple of) the gradient: the comparison is of gradients
params = random_params(training.EBMNet(p))
step = jax.jit(training.make_train_step(spec, tx))
out = {}
for name, devices in (("one", jax.devices()[:1]), ("two", jax.devices())):
    mesh = training.data_mesh(devices)
    state = training.replicate(mesh, training.TrainState(jax.numpy.zeros((), "int32"), params, tx.init(params), jax.numpy.zeros((), "int32")))
    new, metrics = step(state, training.shard_batch(mesh, ds.batch(0, 0, 4)), jax.random.key(7), training.replicate(mesh, vae))
    out[name] = (jax.device_get(new.params), float(metrics["loss"]), len(new.params["params"]) and len(jax.tree.leaves(new.params)[0].sharding.device_set))
grad_one = [(b - a) / 1e4 for a, b in zip(jax.tree.leaves(out["one"][0]), jax.tree.leaves(params))]
grad_two = [(b - a) / 1e4 for a, b in zip(jax.tree.leaves(out["two"][0]), jax.tree.leaves(params))]
scale = max(float(np.max(np.abs(g))) for g in grad_one)
diff = max(float(np.max(np.abs(a - b))) for a, b in zip(grad_one, grad_two))
print(json.dumps({"loss_one": out["one"][1], "loss_two": out["two"][1], "grad_scale": scale, "grad_diff": diff,
                  "devices_two": out["two"][2]}))
"""


def test_two_device_step_equals_one_device_step(tmp_path):
    r = run_on_two_devices(_TWO_DEVICES)
    assert r["devices_two"] == 2  # parameters really live on both devices
    assert r["loss_two"] == pytest.approx(r["loss_one"], rel=1e-5)
    assert r["grad_scale"] > 1e-5
    assert r["grad_diff"] < 1e-3 * r["grad_scale"]


def test_a_second_writer_of_a_run_fails_naming_the_first(task_data, tmp_path):
    spec = training.vae_spec(_fast(TINY, 2))
    from envs.dataset import writer_lock

    with writer_lock(tmp_path / ".lock", training.TrainingError):  # as another bin/train_all would
        with pytest.raises(training.TrainingError, match=f"being written by process {os.getpid()}; wait"):
            training.fit(spec, task_data[0], tmp_path, verbose=False)
    assert not (tmp_path / "metrics.jsonl").exists()
    _, summary = training.fit(spec, task_data[0], tmp_path, verbose=False)  # free again once the first is done
    assert summary["steps"] == 2


def test_a_checkpoint_knows_its_task_and_data(task_data, tmp_path):
    spec = training.vae_spec(_fast(TINY, 2))
    training.fit(spec, task_data[0], tmp_path, verbose=False)
    other = data_lib.MotionDataset(task_data[0].images, task_data[0].motions[::-1].copy())
    with pytest.raises(training.TrainingError, match="was trained on other data"):
        training.fit(spec, other, tmp_path, verbose=False)  # a finished run reused on other data
    with pytest.raises(training.TrainingError, match="was trained on other data"):
        training.load_params(tmp_path, spec, data_lib.motions_fingerprint(other.motions))
    training.load_params(tmp_path, spec, data_lib.motions_fingerprint(task_data[0].motions))
    of_task = lambda task: dataclasses.replace(spec, meta={**spec.meta, "task": task})
    training.fit(of_task("close_box"), task_data[0], tmp_path / "cb", verbose=False)
    with pytest.raises(training.TrainingError, match="task: checkpoint has 'close_box', expected 'reach_target'"):
        training.load_params(tmp_path / "cb", of_task("reach_target"))
