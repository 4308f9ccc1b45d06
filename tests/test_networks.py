"""Networks: shapes, F reuse, vmap, sampler, parameter counts, DMO identity, VAE."""
import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dmo_jax.benchmarks.reference import plain_encoder_forward
from dmo_jax.config import DEFAULT_PRESET, PRESETS, VARIANTS, get_preset, override_label
from dmo_jax.encoder import ConvNeXtUNet
from dmo_jax.networks import DMONet, EBMNet, bilinear_sample, count_params
from dmo_jax.vae import VAENet
from dmo_jax.workflow import RunPaths
from envs.commands.common import DEFAULT_IMAGE_SIZE, default_data_dir
from envs.motion import NUM_STEPS, POSE_DIM, time_grid
from helpers import random_motions, random_params


@functools.lru_cache(maxsize=None)
def jitted(net):
    """The net's pure functions, jitted (eager op-by-op execution compiles every op separately)."""
    names = ("encode", "energy") if isinstance(net, EBMNet) else ("encode", "refine")
    return [jax.jit(getattr(net, k), static_argnames=("train",)) for k in names]


@pytest.fixture(scope="module")
def tiny_ebm():
    net = EBMNet.from_name("tiny")
    params = random_params(net, 0)
    s = net.preset.image_size
    images = jax.random.uniform(jax.random.key(1), (2, s, s, 4))
    return net, params, images


# --------------------------------------------------------------------------- shapes
@pytest.mark.parametrize("preset", list(PRESETS))
@pytest.mark.parametrize("variant", VARIANTS)
def test_output_shapes(preset, variant):
    """Abstract evaluation for every preset and variant (nothing big is computed)."""
    ebm, dmo = EBMNet.from_name(preset, variant), DMONet.from_name(preset, variant)
    s, w = ebm.preset.image_size, ebm.preset.head.feature_channels
    image = jax.ShapeDtypeStruct((3, s, s, 4), jnp.float32)
    feature = jax.ShapeDtypeStruct((s, s, w), jnp.float32)
    motions = jax.ShapeDtypeStruct((5, NUM_STEPS, POSE_DIM), jnp.float32)
    ep, dp = ebm.param_shapes(), dmo.param_shapes()
    assert jax.eval_shape(ebm.encode, ep, image).shape == (3, s, s, w)
    assert jax.eval_shape(ebm.energy, ep, feature, motions).shape == (5,)
    assert jax.eval_shape(dmo.refine, dp, feature, motions).shape == (5, NUM_STEPS, POSE_DIM)


@pytest.mark.parametrize("variant", VARIANTS)
def test_tiny_forward_runs_and_is_finite(variant):
    ebm, dmo = EBMNet.from_name("tiny", variant), DMONet.from_name("tiny", variant)
    ep, dp = random_params(ebm, 0), random_params(dmo, 1)
    (_, energy), (_, refine) = jitted(ebm), jitted(dmo)
    s, w = ebm.preset.image_size, ebm.preset.head.width
    feature = jax.random.normal(jax.random.key(2), (s, s, w))  # heads only; the encoder is shared
    motions = random_motions(jax.random.key(3), 3)
    e = energy(ep, feature, motions)
    r = refine(dp, feature, motions)
    assert e.shape == (3,) and r.shape == motions.shape
    assert np.all(np.isfinite(e)) and np.all(np.isfinite(r))
    assert not np.allclose(e, e[0]), "different motions should get different energies"


def test_paper_parameter_counts():
    assert count_params(EBMNet.from_name("paper").param_shapes()) == 35_866_625
    assert count_params(DMONet.from_name("paper").param_shapes()) == 35_883_858
    assert count_params(VAENet.from_preset("paper").param_shapes()) == 7_772_178


# --------------------------------------------------------------------------- reuse / vmap
def test_energy_with_reused_feature_equals_recomputed(tiny_ebm):
    net, params, images = tiny_ebm
    encode, energy = jitted(net)
    motions = random_motions(jax.random.key(4), 6)
    feature = encode(params, images[0])
    reused = np.concatenate([energy(params, feature, motions[:2]), energy(params, feature, motions[2:])])
    recomputed = jax.jit(net.module.apply)(params, images[0], motions)  # image -> F -> energy in one call
    np.testing.assert_allclose(reused, recomputed, rtol=1e-5, atol=1e-5)


def test_vmapped_heads_equal_per_candidate_calls(tiny_ebm):
    net, params, images = tiny_ebm
    dmo = DMONet.from_name("tiny")
    dparams = random_params(dmo, 5)
    (encode, energy), (_, refine) = jitted(net), jitted(dmo)
    motions = random_motions(jax.random.key(6), 4)
    feature = encode(params, images[0])
    dfeature = jax.random.normal(jax.random.key(7), feature.shape)

    e_vmap = jax.jit(jax.vmap(lambda m: energy(params, feature, m)))(motions)  # m: [101, 11]
    e_loop = np.stack([energy(params, feature, motions[i : i + 1])[0] for i in range(4)])
    np.testing.assert_allclose(e_vmap, e_loop, rtol=1e-5, atol=1e-5)

    r_vmap = jax.jit(jax.vmap(lambda m: refine(dparams, dfeature, m)))(motions)
    r_loop = np.stack([refine(dparams, dfeature, motions[i : i + 1])[0] for i in range(4)])
    np.testing.assert_allclose(r_vmap, r_loop, rtol=1e-5, atol=1e-5)

    # over images: batched encoder + vmapped head == one image at a time
    per_image = jax.jit(jax.vmap(lambda f: energy(params, f, motions)))(encode(params, images))
    for b in range(images.shape[0]):
        single = energy(params, encode(params, images[b]), motions)
        np.testing.assert_allclose(per_image[b], single, rtol=1e-5, atol=1e-5)


# --------------------------------------------------------------------------- sampler
def reference_sample(feature, u, v):
    """Bilinear sampling as a sum over all pixels of tent weights (align corners, zero outside)."""
    h, w, _ = feature.shape
    x = (u + 1) / 2 * (w - 1)
    y = (v + 1) / 2 * (h - 1)
    wx = np.maximum(0.0, 1.0 - np.abs(x - np.arange(w)))
    wy = np.maximum(0.0, 1.0 - np.abs(y - np.arange(h)))
    return np.einsum("i,j,ijc->c", wy, wx, feature)


def test_bilinear_sampler_matches_reference():
    rng = np.random.default_rng(0)
    feature = rng.normal(size=(7, 9, 3))
    pts = list(rng.uniform(-1.3, 1.3, size=(200, 2)))
    edges = [-1.0, 1.0, -1.0 - 1e-3, 1.0 + 1e-3, 0.0, 3.0, -3.0]
    pts += [(a, b) for a in edges for b in edges]  # corners, borders, just outside, far outside
    pts += [(-1.0, rng.uniform(-1, 1)) for _ in range(5)] + [(rng.uniform(-1, 1), 1.0) for _ in range(5)]
    pts = np.asarray(pts)
    got = np.asarray(bilinear_sample(jnp.asarray(feature, jnp.float32), jnp.asarray(pts, jnp.float32)))
    want = np.stack([reference_sample(feature, u, v) for u, v in pts])
    np.testing.assert_allclose(got, want, atol=1e-5)
    np.testing.assert_allclose(got[np.abs(pts).max(-1) >= 3.0], 0.0)
    # exact pixel centres return the pixel
    np.testing.assert_allclose(got[np.all(pts == [-1.0, -1.0], axis=1)][0], feature[0, 0], atol=1e-6)


# --------------------------------------------------------------------------- DMO
def test_dmo_with_zeroed_final_layers_returns_input():
    net = DMONet.from_name("tiny")
    params = random_params(net, 7)
    _, refine = jitted(net)
    head = dict(params["params"]["head"])
    for name in list(head):
        if name.endswith("_fc1"):
            head[name] = jax.tree.map(jnp.zeros_like, head[name])
    zeroed = {"params": {**params["params"], "head": head}}
    s = net.preset.image_size
    feature = jax.random.normal(jax.random.key(8), (s, s, net.preset.head.width))
    motions = random_motions(jax.random.key(9), 3)
    np.testing.assert_array_equal(refine(zeroed, feature, motions), motions)

    # with the non-zeroed parameters: time passes through, grasp stays in [0, 1]
    out = refine(params, feature, motions.at[..., 9].set(5.0))
    np.testing.assert_array_equal(out[..., 10], motions[..., 10])
    assert np.all((out[..., 9] >= 0) & (out[..., 9] <= 1))


# --------------------------------------------------------------------------- encoder
def test_encoder_fast_ops_equal_plain_convolutions():
    """Patch convs as matmuls, shifted-sum depthwise conv, one-pass norms == plain XLA convs."""
    cfg = get_preset("tiny").encoder
    image = jax.random.uniform(jax.random.key(10), (2, 32, 32, 4))
    params = {"params": random_params(EBMNet.from_name("tiny"), 11)["params"]["encoder"]}
    want = jax.jit(plain_encoder_forward, static_argnums=2)(params["params"], image, cfg)
    for impl in ("shift", "conv"):
        got = jax.jit(ConvNeXtUNet(dataclasses.replace(cfg, dwconv_impl=impl)).apply)(params, image)
        np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-4)


def test_train_mode_needs_rng_and_is_stochastic(tiny_ebm):
    net, params, images = tiny_ebm
    encode, energy = jitted(net)
    motions = random_motions(jax.random.key(12), 2)
    feature = encode(params, images[0])
    with pytest.raises(ValueError, match="rng"):
        energy(params, feature, motions, train=True)
    a = energy(params, feature, motions, train=True, rng=jax.random.key(1))
    b = energy(params, feature, motions, train=True, rng=jax.random.key(2))
    assert not np.allclose(a, b)


# --------------------------------------------------------------------------- VAE
def test_vae_shapes_and_time_channel():
    vae = VAENet.from_preset("tiny")
    params = random_params(vae, 13)
    motions = random_motions(jax.random.key(14), 3)
    mu, logvar = jax.jit(vae.encode)(params, motions)
    assert mu.shape == logvar.shape == (3, vae.config.latent_dim)
    out = jax.jit(vae.decode)(params, mu)
    assert out.shape == motions.shape
    np.testing.assert_array_equal(out[..., 10], np.broadcast_to(time_grid(), (3, NUM_STEPS)))
    sample = jax.jit(vae.sample_around, static_argnames=("num_samples",))
    samples = sample(params, motions, jax.random.key(15), 2.0, num_samples=4)
    assert samples.shape == (3, 4, NUM_STEPS, POSE_DIM)
    assert not np.allclose(samples[:, 0], samples[:, 1])
    # k_sigma = 0 decodes the posterior mean
    np.testing.assert_allclose(sample(params, motions, jax.random.key(16), 0.0), out, atol=1e-5)


def test_vae_initialised_at_the_mean_pose_decodes_it_for_any_latent():
    vae = VAENet.from_preset("tiny")
    mean_pose = np.array([0.1, -0.2, 1.5, 1, 0, 0, 0, -1, 0, 0.3, 0.0], np.float32)  # z 1.5 m, as the camera sees
    params = vae.init_at_mean(jax.random.key(0), mean_pose)
    out = vae.decode(params, jax.random.normal(jax.random.key(1), (3, vae.config.latent_dim)))
    np.testing.assert_allclose(out[..., :10], np.broadcast_to(mean_pose[:10], (3, NUM_STEPS, 10)), atol=1e-6)
    default = vae.decode(vae.init(jax.random.key(0)), jnp.zeros((1, vae.config.latent_dim)))
    assert np.abs(default[..., 2] - 1.5).mean() > 0.5  # what the mean start is for
    with pytest.raises(ValueError, match="mean_pose must be 11 finite numbers"):
        vae.init_at_mean(jax.random.key(0), mean_pose[:10])


# --------------------------------------------------------------------------- config
def test_unknown_names_raise_clear_errors():
    with pytest.raises(ValueError, match="tiny, cpu, paper"):
        get_preset("huge")
    with pytest.raises(ValueError, match="concat, wo_concat, gap, vit"):
        get_preset("tiny", variant="resnet")


def test_train_overrides_replace_only_the_named_settings():
    cpu = get_preset("cpu")
    longer = cpu.with_overrides(["dmo_steps=2400", "uv_weight=30", "ebm_vae_negatives=0"])
    assert (longer.train.dmo_steps, longer.train.uv_weight, longer.train.ebm_vae_negatives) == (2400, 30.0, 0)
    assert longer.train.ebm_steps == cpu.train.ebm_steps and longer.encoder == cpu.encoder
    assert cpu.with_overrides([]) == cpu
    cue = cpu.with_overrides(["depth_cue_range=0.1"])
    assert (cue.head.depth_cue, cue.head.depth_cue_range, cue.train) == (True, 0.1, cpu.train)
    assert not cpu.with_overrides(["depth_cue=false"]).head.depth_cue
    # one syntax, SECTION.FIELD=VALUE; the section may be left out, and results name it the same
    assert cpu.with_overrides(["train.dmo_steps=2400", "train.uv_weight=30", "train.ebm_vae_negatives=0"]) == longer
    assert cpu.with_overrides(["head.depth_cue_range=0.1"]) == cue
    assert [override_label(i) for i in ("train.lr=0.1", "lr=0.1", "head.depth_cue=true")] == \
        ["lr=0.1", "lr=0.1", "depth_cue=true"]
    for bad in ("head.width=64", "encoder.out_dim=8", "train.depth_cue=true", "nope=1"):
        with pytest.raises(ValueError, match=f"--set '{bad}': expected SECTION.FIELD=VALUE"):
            cpu.with_overrides([bad])
    # ranges from the dataclass: counts positive, those a field lets be 0 (off) >= 0, numbers finite
    assert cpu.with_overrides(["selection_scenes=0", "ebm_mined_steps=0"]).train.selection_scenes == 0
    for bad, why in (("ebm_steps=0", "ebm_steps must be positive"), ("uv_weight=-1", "uv_weight must be >= 0"),
                     ("selection_scenes=-1", "selection_scenes must be >= 0"),
                     ("lr=nan", "lr must be a finite number"), ("ebm_steps=1.5", "ebm_steps takes a int")):
        with pytest.raises(ValueError, match=f"--set '{bad}': {why}"):
            cpu.with_overrides([bad])
    # the image size: any multiple of the encoder's total stride, run in a directory of its own
    smaller = cpu.with_overrides(["image_size=64"])
    assert smaller == cpu.with_overrides(["preset.image_size=64"]) and smaller.image_size == 64
    assert (smaller.name, smaller.train, smaller.head) == (cpu.name, cpu.train, cpu.head)
    assert RunPaths.of("runs", "reach_target", smaller).root.name == "cpu-64px"
    assert RunPaths.of("runs", "reach_target", cpu).root.name == "cpu"
    # bin/generate_data writes by default where the default preset's commands look
    assert default_data_dir(DEFAULT_IMAGE_SIZE) == default_data_dir(get_preset(DEFAULT_PRESET).image_size) == "data/96px"
    for bad in ("image_size=100", "image_size=0"):
        with pytest.raises(ValueError, match=f"--set '{bad}': Preset: image_size must be a positive multiple of 32"):
            cpu.with_overrides([bad])


def test_the_bank_recipe_reads_the_depth_cue_where_the_variant_can():
    assert get_preset("cpu").head.depth_cue and get_preset("paper", recipe="bank").head.depth_cue
    assert not get_preset("cpu", recipe="paper").head.depth_cue and not get_preset("paper").head.depth_cue
    assert get_preset("cpu", "wo_concat").head.depth_cue  # it samples F at each pose too
    for variant in ("gap", "vit"):  # they sample F at no pose, so there is no pose's pixel to read
        assert not get_preset("cpu", variant).head.depth_cue
        assert get_preset("cpu", variant).with_variant("concat") == get_preset("cpu")


def test_depth_cue_carries_the_image_depth_in_f_and_changes_the_mix_input():
    tiny = get_preset("tiny")
    cue = tiny.with_overrides(["depth_cue=true"])
    ebm = EBMNet(cue)
    params = ebm.init(jax.random.key(0))
    image = jax.random.uniform(jax.random.key(1), (32, 32, 4))
    feature = ebm.encode(params, image)
    assert feature.shape == (32, 32, tiny.head.width + 1)
    np.testing.assert_array_equal(feature[..., -1], image[..., 3])
    mix = params["params"]["trunk"]["mix_mlp"]["Dense_0"]["kernel"]
    plain = EBMNet(tiny).param_shapes()["params"]["trunk"]["mix_mlp"]["Dense_0"]["kernel"]
    assert mix.shape[0] == plain.shape[0] + 1  # one more input: image depth minus pose depth
    assert ebm.energy(params, feature, jnp.full((2, 101, 11), 0.5)).shape == (2,)
    with pytest.raises(ValueError, match=r"feature must be one image's F \[H, W, 17\]"):
        ebm.energy(params, feature[..., :-1], jnp.full((2, 101, 11), 0.5))
    with pytest.raises(ValueError, match=r"depth_cue needs a variant that samples F at each pose \(concat, "
                       r"wo_concat\), not 'gap'"):
        get_preset("tiny", "gap").with_overrides(["depth_cue=true"])
    with pytest.raises(ValueError, match="depth_cue takes a bool, got 'yes'"):
        tiny.with_overrides(["depth_cue=yes"])


def test_wo_concat_reads_the_depth_cue_in_its_sampled_image_tokens():
    tiny = get_preset("tiny", "wo_concat")
    ebm = EBMNet(tiny.with_overrides(["depth_cue=true"]))
    params = ebm.init(jax.random.key(0))
    assert params["params"]["trunk"]["depth_cue"]["kernel"].shape == (1, tiny.head.width)
    assert "depth_cue" not in EBMNet(tiny).param_shapes()["params"]["trunk"]
    feature = ebm.encode(params, jax.random.uniform(jax.random.key(1), (32, 32, 4)))
    motions = jnp.full((2, 101, 11), 0.5)
    assert not np.allclose(ebm.energy(params, feature, motions),
                           ebm.energy(params, feature.at[..., -1].add(0.1), motions))


def test_depth_cue_range_saturates_the_gap_behind_poses_far_in_front():
    tiny = get_preset("tiny")
    ebm_linear = EBMNet(tiny.with_overrides(["depth_cue=true"]))
    ebm_ranged = EBMNet(tiny.with_overrides(["depth_cue=true", "depth_cue_range=0.01"]))
    params = ebm_linear.init(jax.random.key(0))
    feature = ebm_linear.encode(params, jax.random.uniform(jax.random.key(1), (32, 32, 4), minval=0.4))
    farther = feature.at[..., -1].add(0.1)  # everything the camera sees 0.25 m farther away
    motions = jnp.full((2, 101, 11), 0.5)  # poses at 0.5 m depth, >= 0.5 m in front of any surface
    np.testing.assert_array_equal(ebm_ranged.energy(params, feature, motions),
                                  ebm_ranged.energy(params, farther, motions))
    assert not np.allclose(ebm_linear.energy(params, feature, motions), ebm_linear.energy(params, farther, motions))
    with pytest.raises(ValueError, match="depth_cue_range must be >= 0 and needs depth_cue=true"):
        tiny.with_overrides(["depth_cue_range=0.1"])
    with pytest.raises(ValueError, match="depth_cue_range must be >= 0"):
        tiny.with_overrides(["depth_cue=true", "depth_cue_range=-1"])
