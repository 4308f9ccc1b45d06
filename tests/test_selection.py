"""The selection head: fitted on executed training candidates, it ranks the DMO's candidates."""
import json
import shutil

import jax
import numpy as np
import pytest

from dmo_jax import inference, selection, workflow
from dmo_jax.config import get_preset
from dmo_jax.data import network_image
from dmo_jax.networks import EBMNet
from envs.dataset import load_split

TASK = "reach_target"  # the task of the shared `trained` fixture (conftest.py)


def test_the_fit_learns_what_tells_success_apart_and_else_keeps_the_energys_choice():
    rng = np.random.default_rng(0)
    m, k, p, w = 80, 6, 3, 4
    phases, energies = rng.normal(size=(m, k, p, w)), rng.normal(size=(m, k))
    success = phases[..., 1, 2] > 0.8  # what one phase says; the lowest energy knows nothing of it
    weights = selection.fit_weights(phases, energies, success)
    chosen = np.argmax(np.asarray(selection.selection_scores(weights, phases, energies)), axis=1)
    by_energy = np.argmin(energies, axis=1)
    rows = np.arange(m)
    assert success[rows, chosen].mean() > success[rows, by_energy].mean() + 0.3
    # scenes where all or none succeed carry no choice: the energy's ranking stays
    weights = selection.fit_weights(phases, energies, np.tile(rows[:, None] % 2 == 0, (1, k)))
    scores = np.asarray(selection.selection_scores(weights, phases, energies))
    np.testing.assert_array_equal(np.argsort(-scores, axis=1), np.argsort(energies, axis=1))


def test_the_head_trains_once_and_ranks_the_dmos_candidates_only(trained_bank, tmp_path):
    shared_data, shared_work, summary = trained_bank  # the bank recipe fits a head (conftest.py)
    data, work = shutil.copytree(shared_data, tmp_path / "data"), shutil.copytree(shared_work, tmp_path / "runs")
    preset = get_preset("tiny", recipe="bank")
    first = summary["selection"]
    assert 0 <= first["lowest_energy_succeeds"] <= first["some_candidate_succeeds"] <= 1
    again = workflow.train_task(TASK, preset, data, work, log=lambda m: None)["selection"]
    assert again == first  # loaded, not fitted again

    bank = np.asarray(load_split(data, TASK, "train").motions, np.float32)
    models = workflow.load_models(work, TASK, preset, ["sort", "dmo"], bank=bank)
    width = selection.PHASES * preset.head.width
    assert models.selection.shape == (width + 1,) and np.all(np.isfinite(models.selection))
    test = load_split(data, TASK, "test")
    image = network_image(test.rgb[:1], test.depth[:1])[0]
    key = jax.random.key(0)
    dmo = inference.predict(models, image, bank, key, preset=preset, method="dmo", n=2, R=1)
    ebm = EBMNet(preset)
    feature = ebm.encode(models.ebm, image)
    _, phases = ebm.pooled_and_phases(models.ebm, feature, dmo.candidates, selection.PHASES)
    scores = np.asarray(selection.selection_scores(models.selection, phases, dmo.energies))
    assert np.all(np.diff(scores) <= 1e-5)  # best first by the head's score
    # the same candidates and energies as ranked by energy
    by_energy = inference.predict(models._replace(selection=None), image, bank, key, preset=preset, method="dmo",
                                  n=2, R=1)
    np.testing.assert_allclose(np.sort(dmo.energies), by_energy.energies, rtol=1e-5, atol=1e-5)
    sort = inference.predict(models, image, bank, key, preset=preset, method="sort", n=2)
    assert np.all(np.diff(np.asarray(sort.energies)) >= 0)  # sort still by energy

    other = preset.with_overrides(["selection_scenes=2"])
    with pytest.raises(ValueError, match="no selection head.*train it first"):
        workflow.load_models(work, TASK, other, "dmo", bank=bank)
    assert workflow.load_models(work, TASK, other, "sort", bank=bank).selection is None
    path = workflow.RunPaths.of(work, TASK, preset).selection(preset, "in-data+vae", preset.train.dmo_train_steps)
    stored = json.loads(path.read_text())
    assert len(stored["weights"]) == width + 1 and stored["phases"] == selection.PHASES
    # a head stored with another feature layout is not loaded but fitted again
    path.write_text(json.dumps({**stored, "phases": 1}))
    with pytest.raises(ValueError, match="no selection head"):
        workflow.load_models(work, TASK, preset, "dmo", bank=bank)
