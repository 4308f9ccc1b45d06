"""Bank neighbours and the training recipes built on them: each motion's nearest training motions
(stored beside the data, rebuilt when it changes), the EBM's near negatives and the motions the
EBM itself ranks first (mined negatives). The bank recipe end to end is in test_evaluation."""
import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dmo_jax import losses, mining, neighbours
from dmo_jax.config import RECIPES, CoarseRanking, get_preset
from dmo_jax.data import MotionDataset
from dmo_jax.inference import Models, top_candidates
from dmo_jax.networks import EBMNet
from dmo_jax.vae import VAENet
from envs.motion import NUM_STEPS, POSE_DIM

from helpers import random_params

TINY = get_preset("tiny")
K = np.array([[50.0, 0, 31.5], [0, 50.0, 31.5], [0, 0, 1]], np.float32)


def _motions(n, seed=0):
    """``n`` motions whose poses scatter around a random point per motion (positions differ)."""
    rng = np.random.default_rng(seed)
    m = np.zeros((n, NUM_STEPS, POSE_DIM), np.float32)
    m[..., 0:2] = rng.uniform(-0.8, 0.8, (n, 1, 2)) + 0.05 * rng.standard_normal((n, NUM_STEPS, 2))
    m[..., 2] = rng.uniform(1.2, 1.8, (n, 1))
    m[..., 3], m[..., 7] = 1.0, 1.0  # identity rotation
    m[..., 10] = np.linspace(0, 1, NUM_STEPS)
    return m


def _distances(query, bank):
    q, b = neighbours.positions(query, K, 64), neighbours.positions(bank, K, 64)
    return np.linalg.norm(q[:, None] - b[None], axis=-1).mean(axis=-1)


def test_neighbours_exclude_the_motion_itself_and_come_sorted(tmp_path):
    bank = _motions(40)
    index = neighbours.split_neighbours(tmp_path, bank, bank, K, 64, k=10, is_bank=True)
    assert index.shape == (40, 10) and index.dtype == np.int32
    assert not (index == np.arange(40)[:, None]).any()
    d = _distances(bank, bank)
    picked = np.take_along_axis(d, index, axis=1)
    assert (np.diff(picked, axis=1) >= 0).all()
    np.fill_diagonal(d, np.inf)
    np.testing.assert_allclose(picked, np.sort(d, axis=1)[:, :10])  # no closer motion was left out
    # held-out motions: their nearest among the training motions
    query = _motions(5, seed=1)
    (tmp_path / "test").mkdir()
    held = neighbours.split_neighbours(tmp_path / "test", query, bank, K, 64, k=10)
    np.testing.assert_allclose(np.take_along_axis(_distances(query, bank), held, axis=1),
                               np.sort(_distances(query, bank), axis=1)[:, :10])


def test_neighbours_are_stored_reused_and_rebuilt_when_the_data_changes(tmp_path):
    bank = _motions(30)
    first = neighbours.split_neighbours(tmp_path, bank, bank, K, 64, k=8, is_bank=True)
    stored = (tmp_path / neighbours.INDEX_FILE).read_bytes()
    calls = []
    again = neighbours.split_neighbours(tmp_path, bank, bank, K, 64, k=8, is_bank=True, log=calls.append)
    assert calls == [] and np.array_equal(first, again)  # read back, not recomputed
    other = bank.copy()
    other[0, :, 0:2] = other[1, :, 0:2]  # motion 0 moves onto motion 1
    changed = neighbours.split_neighbours(tmp_path, other, other, K, 64, k=8, is_bank=True, log=calls.append)
    assert len(calls) == 1 and changed[0, 0] == 1 and changed[1, 0] == 0
    # the same data gives the same bytes, and a torn fingerprint only costs a rebuild
    neighbours.split_neighbours(tmp_path, bank, bank, K, 64, k=8, is_bank=True)
    assert (tmp_path / neighbours.INDEX_FILE).read_bytes() == stored
    (tmp_path / neighbours.INFO_FILE).write_text('{"k": 8, "fing')
    np.testing.assert_array_equal(neighbours.split_neighbours(tmp_path, bank, bank, K, 64, k=8, is_bank=True), first)
    assert json.loads((tmp_path / neighbours.INFO_FILE).read_text())["k"] == 8
    # a dataset that cannot be written to still gives its neighbours, and says it could not keep them
    missing = tmp_path / "not_there"
    np.testing.assert_array_equal(neighbours.split_neighbours(missing, bank, bank, K, 64, k=8, is_bank=True,
                                                              log=calls.append), first)
    assert "used for this run only" in calls[-1]


def test_near_negatives_lie_closer_to_the_positive_than_random_ones(tmp_path):
    bank = _motions(64)
    index = neighbours.split_neighbours(tmp_path, bank, bank, K, 64, k=16, is_bank=True)
    data = MotionDataset(np.zeros((64, 32, 32, 4), np.float32), bank, index)
    batch = data.batch(seed=0, step=3, size=16, near=8)
    assert batch["near"].shape == (16, 8, NUM_STEPS, POSE_DIM)
    vae = VAENet.from_preset(TINY)
    cfg = dataclasses.replace(TINY.train, ebm_gt_negatives=6, ebm_near_negatives=3, near_pool=8)
    cands = np.asarray(losses.ebm_candidates(vae, random_params(vae), jnp.asarray(batch["motions"]),
                                             jax.random.key(0), cfg, near=jnp.asarray(batch["near"])))
    assert cands.shape == (16, 1 + 6 + TINY.train.ebm_vae_negatives, NUM_STEPS, POSE_DIM)
    dist = np.stack([_distances(c[:1], c[1:7])[0] for c in cands])  # [16, 6]: near ones first, then random
    for row, c in zip(range(16), cands):  # the near ones come from the positive's 8 nearest, distinct
        picked = [int(np.flatnonzero((bank == m).all(axis=(1, 2)))[0]) for m in c[1:4]]
        positive = int(np.flatnonzero((bank == c[0]).all(axis=(1, 2)))[0])
        assert len(set(picked)) == 3 and set(picked) <= set(index[positive, :8].tolist())
    assert dist[:, :3].mean() < 0.5 * dist[:, 3:].mean()
    # without near negatives the same keys give the paper's negatives
    paper = losses.ebm_candidates(vae, random_params(vae), jnp.asarray(batch["motions"]), jax.random.key(0),
                                  dataclasses.replace(cfg, ebm_near_negatives=0))
    assert paper.shape == cands.shape


def test_graded_targets_rank_candidates_by_their_distance_from_the_positive():
    bank = _motions(9, seed=3)
    cands = jnp.asarray(bank[None])  # the first motion is the positive
    targets = np.asarray(losses.graded_targets(cands, K, 64, scale=0.3))[0]  # these motions lie ~1 m apart
    dist = _distances(bank[:1], bank)[0]
    np.testing.assert_allclose(targets.sum(), 1.0, rtol=1e-5)
    assert targets.argmax() == 0 and (np.argsort(-targets, kind="stable") == np.argsort(dist, kind="stable")).all()
    # the log-ratio of two candidates' mass is their distance difference over the scale
    np.testing.assert_allclose(np.log(targets[0] / targets[1:]), dist[1:] / 0.3, rtol=1e-3)
    # the loss with a one-hot target is the paper's InfoNCE; a graded one is minimised by other energies
    energies = jnp.asarray(np.random.default_rng(0).standard_normal((1, 9)), jnp.float32)

    class Fixed:  # an "EBM" whose energies are given
        encode = staticmethod(lambda params, images, train, rng: images)
        energy = staticmethod(lambda params, f, m, train, rng: params)

    one_hot = jnp.eye(9)[:1]
    paper, _ = losses.ebm_loss(Fixed, energies[0], jnp.zeros((1, 1)), cands, jax.random.key(0))
    same, _ = losses.ebm_loss(Fixed, energies[0], jnp.zeros((1, 1)), cands, jax.random.key(0), one_hot)
    np.testing.assert_allclose(paper, same, rtol=1e-6)
    best = jnp.asarray(dist / 0.3, jnp.float32)  # energies equal to distance / scale match the targets
    graded, _ = losses.ebm_loss(Fixed, best, jnp.zeros((1, 1)), cands, jax.random.key(0), targets[None])
    worse, _ = losses.ebm_loss(Fixed, best.at[1].add(-2.0), jnp.zeros((1, 1)), cands, jax.random.key(0), targets[None])
    assert float(graded) < float(worse)
    with pytest.raises(ValueError, match="ebm_target_scale must be >= 0"):
        get_preset("cpu").with_overrides(["ebm_target_scale=-0.01"])


def test_mined_rivals_are_the_ebms_lowest_energy_other_motions_and_are_stored_per_data(tmp_path):
    preset = get_preset("tiny", recipe="bank")
    ebm = EBMNet(preset)
    params = random_params(ebm)
    rng = np.random.default_rng(1)
    data = MotionDataset(rng.uniform(0, 1, (6, preset.image_size, preset.image_size, 4)).astype(np.float32),
                         _motions(6))
    table = mining.ranked_rivals(params, preset, data, k=3, batch=4, log=lambda m: None)
    assert table.shape == (6, 3) and table.dtype == np.int32
    for i, row in enumerate(table):
        energies = np.asarray(ebm.energy(params, ebm.encode(params, jnp.asarray(data.images[i])),
                                         jnp.asarray(data.motions)))
        others = [j for j in np.argsort(energies, kind="stable") if j != i]
        assert list(row) == others[:3]  # never the image's own motion; lowest energy first

    mining.store_rivals(tmp_path, table, data, step=20)
    assert np.array_equal(mining.stored_rivals(tmp_path, data, 3), table)
    assert mining.stored_rivals(tmp_path, data, 4) is None  # another K
    assert mining.stored_rivals(tmp_path, dataclasses.replace(data, motions=_motions(6, seed=2)), 3) is None
    with pytest.raises(ValueError, match="k must be in"):
        mining.ranked_rivals(params, preset, data, k=6)


def test_mining_ranks_the_bank_with_the_presets_mining_scoring():
    full = get_preset("tiny", recipe="bank")
    preset = dataclasses.replace(full, mining_coarse=CoarseRanking(stride=50, keep=5))
    params = random_params(EBMNet(preset))
    rng = np.random.default_rng(3)
    data = MotionDataset(rng.uniform(0, 1, (8, preset.image_size, preset.image_size, 4)).astype(np.float32),
                         _motions(8))
    table = mining.ranked_rivals(params, preset, data, k=3, batch=4, log=lambda m: None)
    for i, row in enumerate(table):
        ranked = np.asarray(top_candidates(Models(params), jnp.asarray(data.images[i]), jnp.asarray(data.motions),
                                           preset=preset, n=4, coarse=preset.mining_coarse).motions)
        others = [m for m in ranked if not np.array_equal(m, data.motions[i])]
        np.testing.assert_array_equal(data.motions[row], others[:3])
    # the coarse scoring ranks otherwise than the full one here, so the table shows which one ran
    assert not np.array_equal(table, mining.ranked_rivals(params, full, data, k=3, batch=4, log=lambda m: None))


def test_recipe_settings_and_their_errors():
    assert RECIPES == ("paper", "bank")
    cpu = get_preset("cpu", recipe="bank")
    assert (cpu.recipe, cpu.train.ebm_near_negatives, cpu.train.near_pool, cpu.train.ebm_target_scale,
            cpu.train.ebm_mined_steps, cpu.train.dmo_inputs, cpu.train.selection_scenes) == \
        ("bank", 6, 16, 0.01, 200, "decoded", 300)
    assert get_preset("paper").recipe == "paper" and get_preset("paper").train.ebm_near_negatives == 0
    paper = get_preset("cpu", recipe="paper").train
    assert (paper.ebm_near_negatives, paper.ebm_target_scale, paper.ebm_mined_steps, paper.dmo_inputs,
            paper.selection_scenes) == (0, 0.0, 0, "decoded", 0)
    with pytest.raises(ValueError, match="unknown recipe 'ibc'"):
        get_preset("cpu", recipe="ibc")
    with pytest.raises(ValueError, match="exceeds ebm_gt_negatives"):
        get_preset("cpu").with_overrides(["ebm_near_negatives=12"])
    with pytest.raises(ValueError, match="exceeds near_pool"):
        get_preset("cpu").with_overrides(["ebm_near_negatives=6", "near_pool=4"])
