"""Success evaluation of learned methods: bin/train_all -> bin/evaluate end to end on
the tiny preset, sweeps, JSON, visualisations (a figure and an MP4 per episode)."""
import json
import shutil

import numpy as np
import pytest

from dmo_jax import workflow
from dmo_jax.config import get_preset
from envs import dataset

TINY = get_preset("tiny")
TASK = "reach_target"  # the task of the shared `trained` fixture (conftest.py)


def _evaluate(capsys, *args):
    """``bin/evaluate args`` in this process, on the compiled programs of the tests before it: what
    it printed (``.out``, ``.err``)."""
    from dmo_jax.commands import evaluate

    capsys.readouterr()
    evaluate.main(list(args))
    return capsys.readouterr()


def _check_summary(summary):
    assert 0.0 <= summary["ebm"]["heldout_near_top1"] <= 1.0
    assert summary["dmo"]["heldout_near_position_before"] > 0 and summary["dmo"]["heldout_near_position_after"] > 0


def test_evaluate_a_learned_method_end_to_end(trained, tmp_path, capsys):
    data, work, summary = trained
    _check_summary(summary)
    out = tmp_path / "r.json"
    printed = _evaluate(capsys, "--task", TASK, "--method", "dmo,sort", "--preset", "tiny", "--data", str(data),
                        "--workdir", str(work), "--episodes", "2", "--n", "2", "--sweep", "R=0,2", "--backend",
                        "mujoco", "--json", str(out), "--save-viz", str(tmp_path / "viz"), "--each-candidate")
    table = printed.out.splitlines()
    # the long parts report their progress: the bank's ranking and each prediction
    progress = [line.split(" (")[0] for line in printed.err.splitlines()]
    assert {"rank the bank: 2/2", "predict dmo n=2 R=0: 2/2", "predict sort n=2: 2/2",
            "predict dmo n=2 R=2: 2/2"} <= set(progress)
    assert table[0].startswith("| method | CB | PC | PB | PK | PR | PU | RT | SW | TP | avg |")
    # sort ignores R: one row, not one per R
    assert [l.split("|")[1].strip() for l in table[2:]] == ["dmo n=2 R=0 {image_size=32}", "sort n=2 {image_size=32}",
                                                         "dmo n=2 R=2 {image_size=32}"]
    payload = json.loads(out.read_text())
    assert payload["settings"]["method"] == ["dmo", "sort"] and payload["settings"]["preset"] == "tiny"
    assert [(r["method"], r["task"], r["n"], r["R"], r["episodes"]) for r in payload["results"]] == [
        ("dmo", TASK, 2, 0, 2), ("sort", TASK, 2, None, 2), ("dmo", TASK, 2, 2, 2)]
    # with R = 0 the DMO returns the EBM's ranking, as sort does
    assert payload["results"][0]["episode_success"] == payload["results"][1]["episode_success"]
    assert payload["results"][2]["mean_start_error_m"] > 0 and payload["results"][2]["mean_optimised_error_m"] > 0
    for r in payload["results"]:
        assert r["successes"] == sum(r["episode_success"]) and r["success_rate"] == r["successes"] / 2
        assert all(0 <= c < 2 for c in r["candidate_used"])
        # every candidate executed alone: the one execution used agrees, and the starts are marked
        k = 2 * (r["R"] + 1) if r["method"] == "dmo" else 2
        assert [len(row) for row in r["candidate_success"]] == [len(row) for row in r["candidate_energies"]] == [k, k]
        assert [row[c] for row, c in zip(r["candidate_success"], r["candidate_used"])] == r["episode_success"]
        assert [sum(row) for row in r["candidate_is_start"]] == [2, 2]
        assert r["some_candidate_solves"] >= max(r["success_rate"], r["some_start_solves"])
        # each candidate's distance from the demonstration: the first-ranked one's is first_error_m
        errors = np.array(r["candidate_error_m"])
        assert errors.shape == (2, k) and np.mean(errors[:, 0]) == pytest.approx(r["first_error_m"], abs=1e-4)
        assert sum(b["candidates"] for b in r["success_by_error"]) == 2 * k
        nearest = np.array(r["candidate_success"])[[0, 1], errors.argmin(axis=1)]
        assert r["nearest_candidate_solves"] == nearest.mean()
    assert payload["task"] == TASK and payload["episodes"] == 6
    assert payload["successes"] == sum(r["successes"] for r in payload["results"])
    pngs, mp4s = sorted((tmp_path / "viz").glob(f"{TASK}_*.png")), sorted((tmp_path / "viz").glob("*.mp4"))
    assert len(pngs) == len(mp4s) == 6 and any("_sort_n2_" in p.name for p in pngs)
    assert mp4s[0].read_bytes()[4:8] == b"ftyp"  # an MP4 container
    import imageio.v3 as iio

    chart = iio.imread(tmp_path / "viz" / "success.png")  # the bar chart of success per method and task
    assert chart.shape[:2] == (420, 900) and chart.std() > 10


def test_ebm_misses_explains_the_heldout_ranking_of_train_all(trained, capsys):
    from dmo_jax import training
    from dmo_jax.commands import ebm_misses

    data, work, _ = trained
    argv = ["--task", TASK, "--preset", "tiny", "--data", str(data), "--workdir", str(work)]
    capsys.readouterr()
    ebm_misses.main(argv)
    stdout = capsys.readouterr().out
    result = json.loads(stdout[: stdout.rindex("}") + 1])
    metrics = workflow.RunPaths.of(work, TASK, TINY).ebm(TINY, "in-data+vae") / "metrics.jsonl"
    top1 = [r["heldout_top1"] for r in map(json.loads, metrics.read_text().splitlines()) if "heldout_top1" in r]
    assert result["episodes"] == 4 and result["top1"] == pytest.approx(top1[-1])
    assert len(result["misses"]) == round((1 - result["top1"]) * 4)
    # the label says what won: another scene's recorded motion, or a VAE sample
    vae_params, _ = training.load_params(workflow.RunPaths.of(work, TASK, TINY).vae(), training.vae_spec(TINY))
    test = dataset.load_split(data, TASK, "test")
    cands = np.asarray(training.heldout_ebm_candidates(TINY, vae_params, test.motions))
    for m in result["misses"]:
        winner = cands[m["episode"], m["candidate"]]
        recorded = any(np.array_equal(winner, test.motions[j]) for j in range(4) if j != m["episode"])
        assert m["winner"] == ("in-data" if recorded else "vae") and m["distance_m"] >= 0
    # the near-tie each positive faces: the closest of its other scenes' motions (candidates 1..31)
    from dmo_jax.losses import position_error

    K = np.asarray(test.meta["intrinsics"], np.float32)
    for i, nearest in enumerate(result["nearest_in_data_m"]):
        expected = min(float(position_error(cands[i, w][None], cands[i, 0][None], K, TINY.image_size))
                       for w in range(1, 32))
        assert nearest == pytest.approx(expected, abs=1e-4)
    # networks with the depth cue are others than those without it: asked for, they are missing, by name
    with pytest.raises(SystemExit) as exit_info:
        ebm_misses.main(argv + ["--set", "depth_cue=true"])
    assert exit_info.value.code == 2
    assert "ebm-in-data+vae-cue/checkpoints: train this model first" in capsys.readouterr().err


def test_every_baseline_evaluates_in_one_call_sharing_the_bank(trained, tmp_path, capsys):
    from dmo_jax.evaluation import evaluate_method

    data, work, _ = trained
    methods = ["sort", "langevin", "gd", "vaebm-l", "vaebm-s", "dfo"]
    out = tmp_path / "all.json"
    table = _evaluate(capsys, "--task", TASK, "--method", ",".join(methods), "--preset", "tiny", "--data", str(data),
                      "--workdir", str(work), "--episodes", "2", "--n", "2", "--backend", "mujoco", "--json", str(out)).out
    assert [l.split("|")[1].strip() for l in table.splitlines()[2:]] == [f"{m} n=2 {{image_size=32}}" for m in methods]
    payload = json.loads(out.read_text())
    assert payload["method"] == methods and [r["method"] for r in payload["results"]] == methods
    for r in payload["results"]:
        assert r["episodes"] == 2 and 0 <= r["success_rate"] <= 1
        assert 0 <= r["best_start_error_m"] <= r["start_error_m"] and 0 <= r["optimised_first"] <= 1
        assert 0 < r["first_depth_error_m"] <= r["first_error_m"]  # depth is one part of the 3-D distance
    sort = payload["results"][0]
    assert sort["optimised_first"] == 0 and sort["first_error_m"] == sort["start_error_m"]
    # a method evaluated alone gets what it gets beside the others
    gd = evaluate_method(TASK, "gd", preset=TINY, workdir=work, data_root=data, n=2, episodes=2, backend="mujoco")
    together = payload["results"][methods.index("gd")]
    for key in ("episode_success", "candidate_used", "first_error_m", "optimised_first"):
        assert gd[key] == together[key], key
    # a coarse scoring that keeps the whole bank keeps the full scoring's top n: recall 1
    from dmo_jax.config import CoarseRanking

    bank_size = len(dataset.load_split(data, TASK, "train").motions)
    whole = evaluate_method(TASK, "sort", preset=TINY, workdir=work, data_root=data, n=2, episodes=2, backend="mujoco",
                            coarse=CoarseRanking(4, bank_size), measure_recall=True)
    assert whole["coarse"] == [4, bank_size] and whole["coarse_recall"] == 1.0
    assert whole["episode_success"] == sort["episode_success"] and sort["coarse"] is None  # tiny: full scoring



def test_show_preset_prints_the_resolved_preset_and_where_each_checkpoint_differs(trained, capsys):
    _, work, _ = trained
    out = _evaluate(capsys, "--task", TASK, "--method", "dmo", "--preset", "tiny", "--workdir", str(work),
                    "--show-preset", "--set", "train.lr=0.002").out
    shown = json.loads(out[:out.index("\n}\n") + 2])
    assert shown["train"]["lr"] == 0.002 and shown["image_size"] == TINY.image_size
    assert f"ebm {workflow.RunPaths.of(work, TASK, TINY).root}" in out  # the EBM and the DMO, not the VAE
    assert out.count("trained with this preset except (checkpoint -> now) train.lr: 0.0001 -> 0.002") == 2
    assert "vae " not in out
    out = _evaluate(capsys, "--task", TASK, "--method", "langevin", "--preset", "tiny", "--workdir", str(work),
                    "--show-preset").out
    assert "trained with this preset\n" in out + "\n"


def test_motion_diagnostics_report_how_much_higher_the_first_motion_reaches_down():
    from dmo_jax.evaluation import motion_diagnostics
    from envs.motion import pose_to_vector, time_grid

    K = np.array([[50.0, 0, 31.5], [0, 50.0, 31.5], [0, 0, 1]], np.float32)
    cam_pos = np.array([1.65, 0.0, 1.88], np.float32)
    look = np.array([[0, -1, 0], [-0.5, 0, -0.866], [0.866, 0, -0.5]], np.float32)  # rows: camera x, y, z in world
    cam_rot = look.T  # camera-to-world
    t = time_grid()
    path = np.stack([0.4 + 0.1 * t, 0.05 * t, 0.9 - 0.1 * np.sin(np.pi * t)], axis=-1)  # dips to 0.8 m
    vec = lambda p: np.asarray(pose_to_vector(p, np.broadcast_to(np.eye(3), (101, 3, 3)), np.ones(101), t,
                                              cam_pos, cam_rot, K, 64))
    demo, raised = vec(path), vec(path + np.array([0, 0, 0.01]))
    out = motion_diagnostics(demo[None, None], np.stack([raised, demo])[None], demo[None], K, 64, (cam_pos, cam_rot))
    assert out["first_lowest_offset_m"] == pytest.approx(0.01, abs=1e-4)


def test_the_bank_recipe_trains_and_evaluates_end_to_end(trained_bank, tmp_path, capsys):
    from dmo_jax import mining, neighbours

    shared_data, shared_work, summary = trained_bank  # beside the paper's recipe (conftest.py; copied: shared)
    data, work = shutil.copytree(shared_data, tmp_path / "data"), shutil.copytree(shared_work, tmp_path / "runs")
    _check_summary(summary)
    assert summary["selection"]["scenes"] == 20  # the recipe's 300, capped at the training split
    out = tmp_path / "bank.json"
    stdout = _evaluate(capsys, "--task", TASK, "--method", "sort,dmo", "--preset", "tiny", "--recipe", "bank",
                       "--data", str(data), "--workdir", str(work), "--episodes", "4", "--n", "2", "--backend",
                       "mujoco", "--json", str(out)).out
    assert [l.split("|")[1].strip() for l in stdout.splitlines()[2:]] == [
        "sort n=2 [bank] {image_size=32}", "dmo n=2 R=1 (selection head 300, 8 phases) [bank] {image_size=32}"]
    payload = json.loads(out.read_text())
    assert payload["settings"]["recipe"] == "bank"
    dmo = next(r for r in payload["results"] if r["method"] == "dmo")
    assert dmo["mean_start_error_m"] > 0 and dmo["mean_optimised_error_m"] > 0
    # one VAE; an EBM and a DMO per recipe (the bank's heads read the depth cue)
    nets = sorted(p.name for p in (work / TASK / "tiny" / "concat").iterdir())
    assert nets == ["dmo-R2", "dmo-R2-cue", "ebm-in-data+vae", "ebm-in-data+vae-near2of16-graded1cm-mined8-cue",
                    "selection"]
    assert (data / TASK / "train" / neighbours.INDEX_FILE).is_file()
    # the bank EBM trained its last 8 steps on its own ranking of the bank, stored beside it
    ebm_dir = work / TASK / "tiny" / "concat" / nets[-2]
    assert np.load(ebm_dir / mining.INDEX_FILE).shape == (20, 16)
    assert json.loads((ebm_dir / mining.INFO_FILE).read_text())["step"] == 20
