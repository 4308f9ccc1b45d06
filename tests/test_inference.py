"""Inference and baselines: predict() under jit and vmap, the full-bank/R=0 case,
zero-step baselines, the Langevin sampler's stationary law, and the evaluation path."""
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dmo_jax import inference
from dmo_jax.config import get_preset
from dmo_jax.inference import Models, OptimizerSettings, predict
from dmo_jax.networks import DMONet, EBMNet
from dmo_jax.vae import VAENet
from helpers import random_motions, random_params, run_on_two_devices

TINY = get_preset("tiny")


@pytest.fixture(scope="module")
def models():
    return Models(random_params(EBMNet(TINY), 0), random_params(DMONet(TINY), 1),
                  random_params(VAENet(TINY.vae), 2))


@pytest.fixture(scope="module")
def bank():
    return inference.project_motions(random_motions(jax.random.key(3), 12))


def _images(b):
    return jax.random.uniform(jax.random.key(4), (b, TINY.image_size, TINY.image_size, 4))


def test_predict_is_jittable_and_vmaps_over_images(models, bank):
    images = _images(2)
    key = jax.random.key(0)
    batched = predict(models, images, bank, key, preset=TINY, method="dmo", n=3, R=2)
    assert batched.candidates.shape == (2, 3 * 3, 101, 11)
    assert batched.energies.shape == (2, 9) and batched.motion.shape == (2, 101, 11)
    assert bool(jnp.all(jnp.diff(batched.energies, axis=-1) >= 0)), "candidates must be ranked"
    for i in range(2):  # the DMO path is deterministic: per-image calls agree with the batch
        single = predict(models, images[i], bank, key, preset=TINY, method="dmo", n=3, R=2)
        np.testing.assert_allclose(single.energies, batched.energies[i], rtol=1e-4, atol=1e-4)
        np.testing.assert_allclose(single.motion, batched.motion[i], rtol=1e-4, atol=1e-4)
    # predict is usable inside a caller's own jit (e.g. a policy loop)
    wrapped = jax.jit(lambda img: predict(models, img, bank, key, preset=TINY, method="sort", n=4).motion)
    assert wrapped(images[0]).shape == (101, 11)


@pytest.mark.parametrize("method, R", [("dmo", 2), ("langevin", 0), ("vaebm-s", 0)])
def test_top_candidates_then_refine_equals_predict(models, bank, method, R):
    images, key = _images(2), jax.random.key(5)
    whole = predict(models, images, bank, key, preset=TINY, method=method, n=3, R=R)
    ranking = inference.top_candidates(models, images, bank, preset=TINY, n=3)
    assert ranking.motions.shape == (2, 3, 101, 11) and ranking.energies.shape == (2, 3)
    ebm = EBMNet(TINY)
    np.testing.assert_allclose(ranking.feature, jax.vmap(lambda x: ebm.encode(models.ebm, x))(images), atol=1e-6)
    sort = predict(models, images, bank, key, preset=TINY, method="sort", n=3)
    np.testing.assert_array_equal(ranking.motions, sort.candidates)  # the bank's top 3, best first
    np.testing.assert_allclose(ranking.energies, sort.energies, rtol=1e-6, atol=1e-6)  # two programs: to rounding
    split = inference.refine(models, images, ranking, key, preset=TINY, method=method, R=R)
    np.testing.assert_allclose(split.candidates, whole.candidates, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(split.energies, whole.energies, rtol=1e-5, atol=1e-5)
    if method != "dmo":
        return
    # bare starting motions, or a ranking without F: F and the starts' energies are recomputed
    # (before any method runs: checked with one)
    for start in (ranking.motions, ranking._replace(feature=None)):
        again = inference.refine(models, images, start, key, preset=TINY, method=method, R=R)
        np.testing.assert_allclose(again.candidates, whole.candidates, rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(again.energies, whole.energies, rtol=1e-5, atol=1e-5)


def test_refine_rejects_starts_that_do_not_fit_the_images(models, bank):
    images = _images(2)
    ranking = inference.top_candidates(models, images, bank, preset=TINY, n=3)
    start = ranking.motions
    with pytest.raises(ValueError, match=r"start.energies must be \[2, 3\], one per motion, got \[2, 2\]"):
        inference.refine(models, images, ranking._replace(energies=ranking.energies[:, :2]), jax.random.key(0),
                         preset=TINY)
    with pytest.raises(ValueError, match=r"start must be \[n, 101, 11\] for one image or \[B, n, 101, 11\]"):
        inference.refine(models, images, start[0], jax.random.key(0), preset=TINY)
    with pytest.raises(ValueError, match=r"got start \(1, 3, 101, 11\) for image \(2, 32, 32, 4\)"):
        inference.refine(models, images, start[:1], jax.random.key(0), preset=TINY)
    with pytest.raises(ValueError, match="start contains 1 NaN"):
        inference.refine(models, images, start.at[0, 0, 0, 0].set(jnp.nan), jax.random.key(0), preset=TINY)


def test_full_bank_without_refinement_returns_the_minimum_energy_motion(models, bank):
    image = _images(1)[0]
    ebm = EBMNet(TINY)
    energies = ebm.energy(models.ebm, ebm.encode(models.ebm, image), bank)
    out = predict(models, image, bank, jax.random.key(0), preset=TINY, method="dmo", n=len(bank), R=0)
    np.testing.assert_allclose(out.motion, bank[int(jnp.argmin(energies))], atol=1e-6)
    np.testing.assert_allclose(out.energies, jnp.sort(energies), rtol=1e-5, atol=1e-5)


def test_chunked_bank_scoring_equals_scoring_at_once(models, bank):
    image = _images(1)[0]
    one = predict(models, image, bank, jax.random.key(0), preset=TINY, method="sort", n=5, chunk=len(bank))
    chunked = predict(models, image, bank, jax.random.key(0), preset=TINY, method="sort", n=5, chunk=5)
    np.testing.assert_allclose(one.energies, chunked.energies, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("method", ["langevin", "gd", "dfo"])
def test_baseline_with_zero_step_returns_its_start(models, bank, method):
    image = _images(1)[0]
    n = 4
    start = predict(models, image, bank, jax.random.key(0), preset=TINY, method="sort", n=n).candidates
    still = OptimizerSettings(langevin_step=0.0, dfo_noise=0.0)
    out = predict(models, image, bank, jax.random.key(1), preset=TINY, method=method, n=n, settings=still)
    assert out.candidates.shape == (2 * n, 101, 11)
    distance = jnp.abs(out.candidates[:, None] - start[None]).max(axis=(2, 3)).min(axis=1)
    assert float(distance.max()) < 1e-5


def test_vaebm_with_zero_step_returns_the_decoded_start(models, bank):
    image = _images(1)[0]
    n = 3
    start = predict(models, image, bank, jax.random.key(0), preset=TINY, method="sort", n=n).candidates
    vae = VAENet(TINY.vae)
    decoded = inference.project_motions(vae.decode(models.vae, vae.encode(models.vae, start)[0]))
    out = predict(models, image, bank, jax.random.key(1), preset=TINY, method="vaebm-s", n=n,
                  settings=OptimizerSettings(vaebm_s_step=0.0))
    expected = jnp.concatenate([start, decoded.at[..., 10].set(start[..., 10])])
    distance = jnp.abs(out.candidates[:, None] - expected[None]).max(axis=(2, 3)).min(axis=1)
    assert float(distance.max()) < 1e-4


def test_langevin_samples_a_gaussian_with_its_mean_and_variance():
    mean, var = jnp.array([0.5, -1.0]), jnp.array([1.0, 0.25])
    energy = lambda x: 0.5 * jnp.sum((x - mean) ** 2 / var, axis=-1)
    x0 = jnp.zeros((4000, 2))
    samples = jax.jit(lambda k: inference.langevin(energy, x0, k, step=0.01, iters=1500))(jax.random.key(0))
    np.testing.assert_allclose(samples.mean(0), mean, atol=0.05)
    np.testing.assert_allclose(samples.var(0), var, rtol=0.1)
    # without noise the same loop is gradient descent: it collapses onto the minimum
    descent = inference.langevin(energy, x0, jax.random.key(0), step=0.01, iters=1500, noise=False)
    np.testing.assert_allclose(descent, jnp.broadcast_to(mean, descent.shape), atol=1e-3)


@pytest.mark.parametrize("kwargs, message", [
    (dict(method="nope"), "unknown method"),
    (dict(n=0), "n must be"),
    (dict(n=13), "n must be"),
    (dict(R=-1), "R must be"),
    (dict(n=4, coarse=inference.CoarseRanking(4, 3)), r"coarse.keep must be in \[n = 4, bank size 12\]"),
    (dict(coarse=inference.CoarseRanking(0, 8)), r"coarse.stride must be in \[1, 100\]"),
    (dict(coarse=(4, 8)), "coarse must be a CoarseRanking"),
])
def test_bad_requests_fail_clearly(models, bank, kwargs, message):
    with pytest.raises(ValueError, match=message):
        predict(models, _images(1)[0], bank, jax.random.key(0), preset=TINY, **kwargs)


def test_coarse_ranking_keeps_full_energies_and_is_exact_when_it_keeps_the_whole_bank(models, bank):
    images, key = _images(2), jax.random.key(0)
    full = inference.top_candidates(models, images, bank, preset=TINY, n=4)
    whole = inference.top_candidates(models, images, bank, preset=TINY, n=4, coarse=inference.CoarseRanking(4, 12))
    np.testing.assert_array_equal(whole.motions, full.motions)
    np.testing.assert_allclose(whole.energies, full.energies, rtol=1e-5, atol=1e-5)
    coarse = inference.CoarseRanking(stride=4, keep=6)
    ranking = inference.top_candidates(models, images, bank, preset=TINY, n=4, coarse=coarse)
    ebm = EBMNet(TINY)
    for i in range(2):  # the kept motions carry their energies on all 101 poses, ranked, and come from
        # the 6 best on poses 0, 4, ..., 100
        np.testing.assert_allclose(ranking.energies[i], ebm.energy(models.ebm, ranking.feature[i], ranking.motions[i]),
                                   rtol=1e-5, atol=1e-5)
        assert bool(jnp.all(jnp.diff(ranking.energies[i]) >= 0))
        rough = ebm.energy(models.ebm, ranking.feature[i], bank[:, ::4])
        pool = np.asarray(bank)[np.argsort(np.asarray(rough))[:6]]
        assert all((pool == m).all(axis=(1, 2)).any() for m in np.asarray(ranking.motions[i]))
    out = predict(models, images, bank, key, preset=TINY, method="dmo", n=4, R=1, coarse=coarse)
    assert out.candidates.shape == (2, 8, 101, 11)


def test_the_preset_sets_the_default_bank_scoring_where_it_keeps_more_than_n_and_less_than_the_bank(models, bank):
    images = _images(2)
    coarse = inference.CoarseRanking(stride=4, keep=6)
    own = dataclasses.replace(TINY, coarse=coarse)
    by_preset = inference.top_candidates(models, images, bank, preset=own, n=4)
    explicit = inference.top_candidates(models, images, bank, preset=TINY, n=4, coarse=coarse)
    full = inference.top_candidates(models, images, bank, preset=own, n=4, coarse=None)
    np.testing.assert_array_equal(by_preset.motions, explicit.motions)
    np.testing.assert_array_equal(full.motions, inference.top_candidates(models, images, bank, preset=TINY, n=4).motions)
    assert inference.resolve_coarse(own, "preset", 4, 12) == coarse
    assert inference.resolve_coarse(own, "preset", 6, 12) is None  # keeping n: nothing to gain
    assert inference.resolve_coarse(dataclasses.replace(TINY, coarse=inference.CoarseRanking(4, 12)), "preset", 4,
                                    12) is None  # keeping the whole bank
    assert inference.resolve_coarse(TINY, "preset", 4, 12) is None  # the paper's full scoring


@pytest.mark.parametrize("variant,cue", [("concat", False), ("concat", True), ("wo_concat", True), ("gap", False)])
def test_a_cached_bank_gives_the_same_ranking_and_energies(bank, variant, cue):
    preset = TINY.with_variant(variant).with_overrides([f"head.depth_cue={str(cue).lower()}"])
    models = Models(random_params(EBMNet(preset), 0), random_params(DMONet(preset), 1))
    images, key = _images(2), jax.random.key(0)
    cache = inference.cache_bank(models, bank, preset=preset)
    assert cache.pose.shape == (12, 101, 2 * 16 if variant == "concat" else 16)
    for coarse in (None, inference.CoarseRanking(stride=4, keep=6)):
        plain = inference.top_candidates(models, images, bank, preset=preset, n=4, coarse=coarse)
        cached = inference.top_candidates(models, images, cache, preset=preset, n=4, coarse=coarse)
        np.testing.assert_array_equal(cached.motions, plain.motions)
        np.testing.assert_allclose(cached.energies, plain.energies, rtol=1e-5, atol=1e-6)
    # chunked as predict() scores a bank
    energies = inference.chunked_energy(EBMNet(preset), models.ebm, plain.feature[0], cache.motions, 5, cache.pose)
    np.testing.assert_allclose(energies, EBMNet(preset).energy(models.ebm, plain.feature[0], bank), rtol=1e-5,
                               atol=1e-6)
    if variant == "concat" and cue:  # and inside predict(), which ranks through top_candidates for every variant
        out = predict(models, images, cache, key, preset=preset, method="dmo", n=4, R=1, chunk=5)
        np.testing.assert_allclose(out.energies, predict(models, images, bank, key, preset=preset, method="dmo", n=4,
                                                         R=1).energies, rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match=r"bank.pose must be floating-point \[12, 101, "):
        predict(models, images, cache._replace(pose=cache.pose[:, :50]), key, preset=preset)
    with pytest.raises(ValueError, match="bank must be"):
        inference.cache_bank(models, bank[:, :50], preset=preset)


def test_wrong_image_size_and_empty_bank_fail_clearly(models, bank):
    with pytest.raises(ValueError, match=r"image must be \[32, 32, 4\]"):
        predict(models, jnp.zeros((64, 64, 4)), bank, jax.random.key(0), preset=TINY)
    with pytest.raises(ValueError, match="empty"):
        predict(models, _images(1)[0], bank[:0], jax.random.key(0), preset=TINY)
    with pytest.raises(ValueError, match="needs the DMO"):
        predict(Models(models.ebm), _images(1)[0], bank, jax.random.key(0), preset=TINY, method="dmo")


def test_the_evaluation_path_gives_the_expert_its_success_rate(tmp_path):
    from envs import dataset, evaluation
    from envs.tasks import get_task

    task = get_task("reach_target", TINY.image_size)
    dataset.generate_split(task, "test", 6, tmp_path, batch=6, verbose=False)
    test = dataset.load_split(tmp_path, "reach_target", "test")
    ranked = np.stack([np.asarray(test.motions), np.asarray(test.motions)[::-1]], axis=1)  # expert first
    result = evaluation.run_episodes("reach_target", test, ranked, backend="mujoco")
    assert result["success_rate"] == 1.0 and result["candidate_used"] == [0] * 6
    world = evaluation.evaluate_world_method("reach_target", "expert", 6, tmp_path, backend="mujoco")
    assert world["episode_success"] == result["episode_success"]


    # the nearest oracle picks, from a bank, the motion whose positions lie closest to the scene's
    demos = np.asarray(test.motions)
    near, far = demos.copy(), demos.copy()
    near[..., 2], far[..., 2] = near[..., 2] + 0.01, far[..., 2] - 0.03  # depth z, metres
    bank = dataclasses.replace(test, motions=np.concatenate([far[::-1], near[::-1]]))
    np.testing.assert_array_equal(evaluation.nearest_bank_motions(bank, demos), near)
    bank = dataclasses.replace(test, motions=np.concatenate([far, demos[::-1], near]))
    np.testing.assert_array_equal(evaluation.nearest_bank_motions(bank, demos), demos)


def test_the_no_reuse_benchmark_computes_what_predict_computes(models, bank):
    """bin/benchmark --only predict compares predict() with a variant that re-encodes the image
    for every evaluation; the comparison is only fair if both return the same motion."""
    from dmo_jax.benchmarks.reference import predict_without_reuse

    image = _images(1)[0]
    out = predict(models, image, bank, jax.random.key(0), preset=TINY, method="dmo", n=3, R=1)
    plain = jax.jit(lambda m, i, b: predict_without_reuse(m, i, b, preset=TINY, n=3, R=1, chunk=4))
    np.testing.assert_allclose(plain(models, image, bank), out.motion, rtol=1e-4, atol=1e-4)


_SPLIT_OVER_TWO_DEVICES = r"""
import sys, json
sys.path.insert(0, sys.argv[1])
sys.path.insert(0, sys.argv[1] + "/tests")
from envs.platform import setup
setup()
import jax, numpy as np
from dmo_jax import inference
from dmo_jax.config import CoarseRanking, get_preset
from dmo_jax.networks import EBMNet
from helpers import random_motions, random_params
assert jax.device_count() == 2, jax.devices()
p = get_preset("tiny")
models = inference.Models(random_params(EBMNet(p), 0))
bank = inference.cache_bank(models, inference.project_motions(random_motions(jax.random.key(3), 12)), preset=p)
images = jax.random.uniform(jax.random.key(4), (4, p.image_size, p.image_size, 4))
coarse = CoarseRanking(stride=6, keep=6)
split = inference.top_candidates(models, images, bank, preset=p, n=3, coarse=coarse)
whole = inference._top_candidates_jit(models, images, bank, preset=p, n=3, chunk=inference.default_chunk(),
                                      coarse=coarse, devices=1)
print(json.dumps({"devices": [inference.image_devices(b) for b in (1, 3, 4)],
                  "split_on": len(split.energies.sharding.device_set), "whole_on": len(whole.energies.sharding.device_set),
                  "equal": all(bool(np.array_equal(a, b)) for a, b in zip(split, whole))}))
"""


def test_a_batch_ranked_over_two_devices_equals_it_ranked_on_one():
    r = run_on_two_devices(_SPLIT_OVER_TWO_DEVICES)
    assert r["devices"] == [1, 1, 2]  # the most devices that split the batch evenly
    assert (r["split_on"], r["whole_on"]) == (2, 1)
    assert r["equal"]  # motions, energies and F, bit for bit
