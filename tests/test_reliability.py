"""Reliability.

1. Malformed inputs: every command (called in-process through its module's ``main(argv)``) and
   ``dmo_jax.inference.predict`` fail with one line saying what was wrong and what was
   expected — exit status 2 and ``error: ...`` on stderr (no traceback) for commands,
   ``ValueError`` for ``predict``. Two parametrized tables.
2. Crash safety: a tiny VAE training run is SIGKILLed at three moments (before its first
   checkpoint, in the middle of saving one, between two) and resumed each time; it ends with
   exactly the parameters of an uninterrupted run, and no unfinished checkpoint is ever taken
   for the latest one. Data generation SIGKILLed while writing its second batch file resumes
   to the same bytes as an uninterrupted run.
3. Determinism: the same seed gives byte-identical datasets (2, across processes) and
   identical evaluation results on the native back-end.
"""
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp
import pytest

from dmo_jax import training
from dmo_jax.commands import benchmark, compare, cost, evaluate, reproduce, train_all
from dmo_jax.config import get_preset
from dmo_jax.data import motions_fingerprint
from dmo_jax.inference import Models, predict
from dmo_jax.networks import DMONet, EBMNet
from dmo_jax.vae import VAENet
from envs import dataset
from envs.commands import execute, generate_data, render, task_report
from envs.motion import time_grid
from helpers import random_params

ROOT = Path(__file__).resolve().parents[1]
TINY = get_preset("tiny")
TASK = "reach_target"

COMMANDS = {
    "render": render.main, "execute": execute.main, "generate_data": generate_data.main,
    "task_report": task_report.main, "evaluate": evaluate.main, "train_all": train_all.main,
    "cost": cost.main, "benchmark": benchmark.main, "compare": compare.main, "reproduce": reproduce.main,
}


# --------------------------------------------------------------------------- malformed files
def _motions(n, rng):
    m = np.concatenate([rng.uniform(-0.5, 0.5, (n, 101, 2)), rng.uniform(1.0, 1.5, (n, 101, 1)),
                        rng.normal(size=(n, 101, 6)), rng.uniform(0, 1, (n, 101, 1)),
                        np.broadcast_to(time_grid()[None, :, None], (n, 101, 1))], axis=-1)
    return m.astype(np.float32)


def _write_split(root, split, n, size=32, **replace):
    """A synthetic split that ``load_split`` accepts (no simulation); ``replace`` swaps arrays."""
    rng = np.random.default_rng(len(split) + n)
    arrays = {"rgb": rng.integers(0, 256, (n, size, size, 3), dtype=np.uint8),
              "depth": rng.uniform(1.0, 2.5, (n, size, size)).astype(np.float32),
              "motions": _motions(n, rng), "seeds": np.arange(n, dtype=np.int64)}
    arrays.update(replace)
    path = dataset.split_dir(root, TASK, split)
    path.mkdir(parents=True)
    for name, array in arrays.items():
        np.save(path / f"{name}.npy", array)
    meta = {"task": TASK, "split": split, "episodes": n, "image_size": size,
            "intrinsics": np.eye(3).tolist(), "generator_version": dataset.GENERATOR_VERSION}
    (path / "meta.json").write_text(json.dumps(meta))
    return path


def _write_data(root, train=4, test=2, size=32, **replace):
    _write_split(root, "train", train, size, **replace)
    _write_split(root, "test", test, size, **{k: v[:test] for k, v in replace.items()})
    return root


def _save_checkpoint(path, params, meta):
    mngr = training._checkpoint_manager(Path(path) / "checkpoints", 1)
    mngr.save(1, args=ocp.args.Composite(state=ocp.args.StandardSave({"params": params}),
                                         meta=ocp.args.JsonSave(meta)))
    mngr.wait_until_finished()
    mngr.close()


def _unwritable_dir(path):
    """An existing directory this process cannot write in: mode 0o555, or (for root, whom
    permission bits do not stop) /sys, which is read-only for everyone."""
    path.mkdir()
    path.chmod(0o555)
    try:
        with tempfile.NamedTemporaryFile(dir=path):
            pass
    except OSError:
        return path
    return Path("/sys")


@pytest.fixture(scope="module")
def paths(tmp_path_factory):
    """Every malformed file and directory the command table refers to, by name."""
    base = tmp_path_factory.mktemp("malformed")
    rng = np.random.default_rng(0)
    p = {"tmp": base, "missing": base / "does_not_exist"}
    p["unwritable"] = _unwritable_dir(base / "read_only")
    p["afile"] = base / "a_file.txt"
    p["afile"].write_text("not a directory")
    p["nometa"] = base / "nometa"
    (p["nometa"] / TASK / "train").mkdir(parents=True)
    for name, outcomes in (("nan", [1, float("nan")]), ("strings", ["yes", "no"]), ("twos", [2, 0])):
        p[f"eval_{name}"] = base / f"eval_{name}.json"
        p[f"eval_{name}"].write_text(json.dumps({"results": [
            {"method": "sort", "n": 8, "R": None, "task": TASK, "episode_success": outcomes}]}))

    # motion files for bin/execute
    good = _motions(1, rng)[0]
    for name, array in {"nan": np.where(np.arange(11) == 2, np.nan, good), "inf": np.where(good > 0.4, np.inf, good),
                        "short": good[:50], "narrow": good[:, :7], "two": np.stack([good, good]),
                        "ints": good.astype(np.int64), "flat": good.reshape(-1)}.items():
        p[f"m_{name}"] = base / f"motion_{name}.npy"
        np.save(p[f"m_{name}"], array)
    p["m_garbage"] = base / "motion_garbage.npy"
    p["m_garbage"].write_bytes(b"\x93NUMPY garbage, not an array")
    p["m_pickle"] = base / "motion_pickle.npy"
    np.save(p["m_pickle"], np.array([{"a": 1}], dtype=object), allow_pickle=True)
    p["m_text"] = base / "motion_text.npy"
    p["m_text"].write_text("0.1 0.2 0.3\n")
    p["m_npz"] = base / "motion_pair.npz"
    np.savez(p["m_npz"], a=good, b=good)

    # datasets
    p["good"] = _write_data(base / "good")
    p["nan_motions"] = _write_data(base / "nan_motions", motions=np.full((4, 101, 11), np.nan, np.float32))
    p["nan_depth"] = _write_data(base / "nan_depth", depth=np.full((4, 32, 32), np.nan, np.float32))
    p["size64"] = _write_data(base / "size64", size=64)
    p["corrupt"] = _write_data(base / "corrupt")
    (dataset.split_dir(p["corrupt"], TASK, "train") / "motions.npy").write_bytes(b"garbage")
    p["truncated"] = _write_data(base / "truncated")
    rgb = dataset.split_dir(p["truncated"], TASK, "test") / "rgb.npy"
    rgb.write_bytes(rgb.read_bytes()[:1000])
    p["badmeta"] = _write_data(base / "badmeta")
    (dataset.split_dir(p["badmeta"], TASK, "test") / "meta.json").write_text("{not json")
    p["listmeta"] = _write_data(base / "listmeta")
    (dataset.split_dir(p["listmeta"], TASK, "test") / "meta.json").write_text("[1, 2]")
    p["empty"] = base / "empty"
    _write_split(p["empty"], "train", 0)
    _write_split(p["empty"], "test", 2)
    p["wrong_dtype"] = _write_data(base / "wrong_dtype", motions=_motions(4, rng).astype(np.float64))

    # checkpoints (random parameters, written as bin/train_all writes them, trained on `good`'s motions)
    good_motions = dataset.load_split(p["good"], TASK, "train").motions
    ebm_meta = {**training.ebm_spec(TINY).meta, "task": TASK,
                "dataset": {"fingerprint": motions_fingerprint(good_motions)}}
    ebm_params = random_params(EBMNet(TINY))
    run = lambda name: base / name / TASK / "tiny" / "concat" / "ebm-in-data+vae"  # noqa: E731
    _save_checkpoint(run("runs_good"), ebm_params, ebm_meta)
    _save_checkpoint(run("runs_cpu"), ebm_params, {**ebm_meta, "preset": "cpu"})
    _save_checkpoint(run("runs_gap"), ebm_params, {**ebm_meta, "variant": "gap"})
    _save_checkpoint(run("runs_corrupt"), ebm_params, ebm_meta)
    for f in (run("runs_corrupt") / "checkpoints" / "1").rglob("*"):
        if f.is_file() and f.name != "commit_success.txt" and f.name != "_CHECKPOINT_METADATA":
            f.write_bytes(b"\x00garbage")
    p["runs_empty"] = base / "runs_empty"
    (run("runs_empty") / "checkpoints").mkdir(parents=True)
    for name in ("runs_good", "runs_cpu", "runs_gap", "runs_corrupt"):
        p[name] = base / name
    vae_meta = {"model": "vae", "preset": "cpu", "steps": 20, "batch_size": 8, "seed": 0}
    p["runs_vae_cpu"] = base / "runs_vae_cpu"
    _save_checkpoint(p["runs_vae_cpu"] / TASK / "tiny" / "vae", random_params(VAENet(TINY.vae)), vae_meta)
    p["big"] = _write_data(base / "big", train=8, test=2)
    yield p
    (base / "read_only").chmod(0o755)


def _case(command, argv, fragment):
    return pytest.param(command, argv, fragment, id=f"{command}:{fragment[:40]}")


EV = ["--task", TASK, "--method", "sort", "--preset", "tiny", "--episodes", "2"]  # a learned method
TA = ["--tasks", TASK, "--preset", "tiny"]
COMMAND_CASES = [
    # bin/render
    _case("render", ["--out", "{tmp}/x.png", "--size", "0"], "--size must be between 1 and 512 pixels, got 0"),
    _case("render", ["--out", "{tmp}/x.png", "--size", "4096"], "--size must be between 1 and 512 pixels, got 4096"),
    _case("render", ["--out", "{missing}/x.png"], "does not exist"),
    _case("render", ["--out", "{unwritable}/x.png"], "is not writable"),
    _case("render", ["--out", "{tmp}"], "is a directory; expected a file name"),
    _case("render", ["--out", "{tmp}/x.png", "--task", "make_tea"], "unknown task 'make_tea'"),
    _case("render", ["--out", "{tmp}/x.png", "--task", "all", "--seed", "-1"], "--seed must be an integer in [0, 2147483647], got -1"),
    _case("render", ["--out", "{tmp}/x.png", "--size", "big"], "argument --size: invalid int value"),
    # bin/execute
    _case("execute", ["--motion", "{missing}/m.npy"], "cannot read motion file"),
    _case("execute", ["--motion", "{m_garbage}"], "cannot read motion file"),
    _case("execute", ["--motion", "{m_pickle}"], "it holds Python objects, not numbers"),
    _case("execute", ["--motion", "{m_text}"], "motion_text.npy is not a NumPy file"),
    _case("execute", ["--motion", "{m_npz}"], "holds several arrays (.npz)"),
    _case("execute", ["--motion", "{m_nan}"], "holds 101 NaN or inf value(s)"),
    _case("execute", ["--motion", "{m_inf}"], "NaN or inf value(s); expected finite numbers"),
    _case("execute", ["--motion", "{m_short}"], "must be [101, 11]"),
    _case("execute", ["--motion", "{m_narrow}"], "got float32[101, 7]"),
    _case("execute", ["--motion", "{m_two}"], "got float32[2, 101, 11]"),
    _case("execute", ["--motion", "{m_flat}"], "got float32[1111]"),
    _case("execute", ["--motion", "{m_ints}"], "must be floating-point [101, 11] motions, got int64"),
    _case("execute", ["--backend", "gpu"], "argument --backend: invalid choice: 'gpu'"),
    _case("execute", ["--json", "{missing}/r.json"], "does not exist"),
    _case("execute", ["--save-motion", "{unwritable}/m.npy"], "is not writable"),
    # bin/generate_data
    _case("generate_data", ["--task", "make_tea", "--out", "{tmp}/d"], "unknown task 'make_tea'"),
    _case("generate_data", ["--task", "", "--out", "{tmp}/d"], "unknown task ''"),
    _case("generate_data", ["--task", TASK, "--out", "{tmp}/d/128px"], "named for 128px images but --image-size is 96"),
    _case("generate_data", ["--task", TASK, "--train", "0", "--out", "{tmp}/d"], "--train must be a positive integer"),
    _case("generate_data", ["--task", TASK, "--test", "-3", "--out", "{tmp}/d"], "--test must be a positive integer"),
    _case("generate_data", ["--task", TASK, "--image-size", "0"], "--image-size must be between 1 and 512"),
    _case("generate_data", ["--task", TASK, "--image-size", "1024"], "--image-size must be between 1 and 512"),
    _case("generate_data", ["--task", TASK, "--seed", "-1", "--out", "{tmp}/d"], "--seed must be an integer in [0, 2147483647], got -1"),
    _case("generate_data", ["--task", TASK, "--workers", "0", "--out", "{tmp}/d"], "--workers must be a positive"),
    _case("generate_data", ["--task", TASK, "--out", "{afile}"], "cannot create --out directory"),
    _case("generate_data", ["--task", TASK, "--out", "{unwritable}"], "is not writable"),
    _case("generate_data", ["--task", TASK, "--train", "many"], "argument --train: invalid int value"),
    # bin/evaluate: arguments
    _case("evaluate", ["--task", TASK, "--method", "magic"], "--method 'magic': expected distinct names from expert"),
    _case("evaluate", ["--task", TASK, "--method", "sort,magic"], "unknown: magic"),
    _case("evaluate", ["--task", TASK, "--method", "sort,sort"], "--method 'sort,sort': expected distinct names"),
    _case("evaluate", EV + ["--preset", "huge"], "argument --preset: invalid choice: 'huge'"),
    _case("evaluate", EV + ["--variant", "resnet"], "argument --variant: invalid choice: 'resnet'"),
    _case("evaluate", EV + ["--negatives", "none"], "argument --negatives: invalid choice: 'none'"),
    _case("evaluate", ["--task", "make_tea", "--method", "expert"], "unknown task 'make_tea'"),
    _case("evaluate", EV + ["--R", "-1"], "--R must be >= 0, got -1"),
    _case("evaluate", EV + ["--n", "0"], "--n must be a positive integer, got 0"),
    _case("evaluate", EV + ["--episodes", "0"], "--episodes must be a positive integer"),
    _case("evaluate", EV + ["--dmo-train-steps", "0"], "--dmo-train-steps must be a positive integer"),
    _case("evaluate", EV + ["--sweep", "k=1,2"], "--sweep must look like n=1,8,1000"),
    _case("evaluate", EV + ["--sweep", "n=0,8"], "values must be >= 1"),
    _case("evaluate", EV + ["--coarse", "4"], "--coarse must be STRIDE,KEEP (e.g. 6,64) or full, got '4'"),
    _case("evaluate", EV + ["--coarse", "0,64"], "--coarse 0,64: STRIDE and KEEP must be positive"),
    _case("evaluate", ["--task", TASK, "--method", "expert", "--coarse", "4,64"], "--coarse needs a learned method"),
    _case("evaluate", ["--task", TASK, "--method", "nearest", "--each-candidate"], "--each-candidate needs a learned method"),
    _case("evaluate", ["--task", TASK, "--method", "expert", "--sweep", "n=1"], "--sweep needs learned methods only, not expert"),
    _case("evaluate", EV + ["--json", "{missing}/r.json"], "does not exist"),
    _case("evaluate", EV + ["--json", "{unwritable}/r.json"], "is not writable"),
    _case("evaluate", EV + ["--save-viz", "{afile}"], "is not a directory"),
    # bin/evaluate: data and checkpoints
    _case("evaluate", ["--task", TASK, "--method", "expert", "--data", "{missing}"], "no complete dataset"),
    _case("evaluate", ["--task", TASK, "--method", "expert", "--data", "{nan_motions}"],
          "motions.npy contains 2222 NaN or inf value(s)"),
    _case("evaluate", ["--task", TASK, "--method", "blind", "--data", "{corrupt}"], "train: motions.npy:"),
    _case("evaluate", ["--task", TASK, "--method", "expert", "--data", "{truncated}"], "corrupt dataset"),
    _case("evaluate", ["--task", TASK, "--method", "expert", "--data", "{badmeta}"], "corrupt dataset"),
    _case("evaluate", ["--task", TASK, "--method", "expert", "--data", "{listmeta}"], "expected a JSON object"),
    _case("evaluate", ["--task", TASK, "--method", "blind", "--data", "{empty}"], "episodes=0"),
    _case("evaluate", ["--task", TASK, "--method", "expert", "--data", "{wrong_dtype}"],
          "motions.npy is float64[2, 101, 11], expected float32[2, 101, 11]"),
    _case("evaluate", EV + ["--data", "{size64}", "--workdir", "{runs_good}"], "has 64px images but preset 'tiny' needs 32px"),
    _case("evaluate", ["--task", TASK, "--method", "expert", "--data", "{good}", "--episodes", "5"],
          "5 episodes asked for, but the test split of reach_target in"),
    _case("evaluate", EV + ["--data", "{good}", "--workdir", "{runs_empty}"], "no checkpoint in"),
    _case("evaluate", EV + ["--data", "{good}", "--workdir", "{missing}"], "train this model first"),
    _case("evaluate", EV + ["--data", "{good}", "--workdir", "{runs_cpu}"], "preset: checkpoint has 'cpu', expected 'tiny'"),
    _case("evaluate", EV + ["--data", "{good}", "--workdir", "{runs_gap}"],
          "variant: checkpoint has 'gap', expected 'concat'"),
    _case("evaluate", EV + ["--data", "{good}", "--workdir", "{runs_corrupt}"], "cannot read checkpoint step 1"),
    _case("evaluate", EV + ["--data", "{good}", "--workdir", "{runs_good}", "--n", "50"],
          "n must be in [1, bank size 4], got 50"),
    _case("evaluate", EV + ["--data", "{nan_depth}", "--workdir", "{runs_good}"], "depth contains 2048 NaN or inf"),
    # bin/train_all
    _case("train_all", ["--tasks", "make_tea"], "unknown task 'make_tea'"),
    _case("train_all", TA + ["--set", "steps=5"], "--set 'steps=5': expected SECTION.FIELD=VALUE, e.g. train.dmo_steps=2400"),
    _case("train_all", TA + ["--set", "dmo_steps"], "expected SECTION.FIELD=VALUE"),
    _case("train_all", TA + ["--set", "head.width=3"], "--set 'head.width=3': expected SECTION.FIELD=VALUE"),
    _case("train_all", TA + ["--set", "dmo_steps=2.5"], "--set 'dmo_steps=2.5': dmo_steps takes a int, got '2.5'"),
    _case("train_all", TA + ["--set", "dmo_batch=0"], "--set 'dmo_batch=0': dmo_batch must be positive"),
    _case("train_all", TA + ["--set", "lr=-1e-3"], "lr must be >= 0"),
    _case("train_all", TA + ["--set", "lr=nan"], "lr must be a finite number, got nan"),
    _case("train_all", TA + ["--set", "lr=0"], "lr must be > 0, got 0.0"),
    _case("train_all", TA + ["--set", "vae_negative_sigma=inf"], "vae_negative_sigma must be a finite number"),
    _case("train_all", TA + ["--set", "lr_decay=0"], "lr_decay must be in (0, 1], got 0.0"),
    _case("train_all", TA + ["--set", "depth_cue_range=-1"], "depth_cue_range must be >= 0 and needs depth_cue=true"),
    _case("train_all", TA + ["--set", "depth_cue_range=nan"], "depth_cue_range must be a finite number"),
    _case("train_all", TA + ["--recipe", "ibc"], "argument --recipe: invalid choice: 'ibc'"),
    _case("train_all", TA + ["--set", "ebm_near_negatives=4"], "ebm_near_negatives=4 exceeds ebm_gt_negatives=3"),
    _case("train_all", TA + ["--preset", "huge"], "argument --preset: invalid choice: 'huge'"),
    _case("train_all", TA + ["--variant", "resnet"], "argument --variant: invalid choice: 'resnet'"),
    _case("train_all", TA + ["--negatives", "none"], "argument --negatives: invalid choice: 'none'"),
    _case("train_all", TA + ["--dmo-train-steps", "0"], "--dmo-train-steps must be at least 1, got 0"),
    _case("train_all", TA + ["--seed", "-2"], "--seed must be an integer in [0, 2147483647], got -2"),
    _case("train_all", TA + ["--seed", "99999999999999999999"], "--seed must be an integer in [0, 2147483647]"),
    _case("train_all", TA + ["--workdir", "{unwritable}", "--data", "{good}"], "--workdir directory"),
    _case("train_all", TA + ["--workdir", "{afile}", "--data", "{good}"], "cannot create --workdir directory"),
    _case("train_all", TA + ["--workdir", "{tmp}/w1", "--data", "{good}", "--json", "{missing}/s.json"], "does not exist"),
    _case("train_all", TA + ["--workdir", "{tmp}/w2", "--data", "{unwritable}"], "--data directory"),
    _case("train_all", TA + ["--workdir", "{tmp}/w3", "--data", "{corrupt}"], "corrupt dataset"),
    _case("train_all", TA + ["--workdir", "{tmp}/w4", "--data", "{size64}"], "has 64px images but preset 'tiny' needs 32px"),
    _case("train_all", TA + ["--workdir", "{tmp}/w5", "--data", "{nan_motions}"], "NaN or inf"),
    _case("train_all", TA + ["--workdir", "{tmp}/w6", "--data", "{nan_depth}"], "depth contains"),
    _case("train_all", TA + ["--workdir", "{tmp}/w7", "--data", "{good}"], "batch size 8 exceeds the 4 training episodes"),
    _case("generate_data", ["--task", TASK, "--out", "{nometa}", "--image-size", "32"],
          "exists but is not a complete split (no meta.json)"),
    _case("train_all", TA + ["--workdir", "{runs_vae_cpu}", "--data", "{big}"], "preset: checkpoint has 'cpu', expected 'tiny'"),
    # bin/task_report
    _case("task_report", ["--task", "make_tea"], "unknown task 'make_tea'"),
    _case("task_report", ["--task", TASK, "--episodes", "0"], "--episodes must be a positive integer"),
    _case("task_report", ["--task", TASK, "--mjx-episodes", "-1"], "--mjx-episodes must be a positive integer"),
    _case("task_report", ["--task", TASK, "--data", "{missing}"], "no complete dataset"),
    _case("task_report", ["--task", TASK, "--data", "{nan_motions}"], "NaN or inf"),
    # bin/cost, bin/benchmark
    _case("cost", ["--preset", "huge"], "argument --preset: invalid choice: 'huge'"),
    _case("benchmark", ["--only", "everything"], "argument --only: invalid choice: 'everything'"),
    _case("benchmark", ["--only", "data", "--out", "{missing}/b.json"], "does not exist"),
    _case("benchmark", ["--only", "encoder", "--preset", "huge"], "argument --preset: invalid choice: 'huge'"),
    _case("benchmark", ["--only", "encoder", "--repeats", "0"], "--repeats must be a positive integer, got 0"),
    _case("benchmark", ["--only", "execution", "--episodes", "0"], "--episodes must be a positive integer, got 0"),
    # bin/reproduce
    _case("reproduce", ["--tables", "3"], "--tables '3': expected comma-separated tables of 1, 2, 4, 5, 6"),
    _case("reproduce", ["--tables", "2", "--variants", "concat,cnn"],
          "--variants 'concat,cnn': expected comma-separated variants of concat, wo_concat, gap, vit"),
    # bin/compare
    _case("compare", ["{missing}/eval.json"], "does_not_exist/eval.json: no such file"),
    _case("compare", ["{afile}"], "a_file.txt: not a readable JSON file"),
    _case("compare", ["{afile}", "--alpha", "1.5"], "--alpha must lie between 0 and 1, got 1.5"),
    _case("compare", ["{eval_nan}"], "eval_nan.json: the episode_success of 'sort n=8' on reach_target must be"),
    _case("compare", ["{eval_strings}"], "eval_strings.json: the episode_success"),
    _case("compare", ["{eval_twos}"], "eval_twos.json: the episode_success"),
]


@pytest.mark.parametrize("command, argv, fragment", COMMAND_CASES)
def test_command_rejects_malformed_input(paths, capsys, command, argv, fragment):
    args = [a.format(**paths) for a in argv]
    files = lambda: {f: (f.stat().st_size, f.stat().st_mtime_ns) for f in Path(paths["tmp"]).rglob("*") if f.is_file()}
    before = files()
    with pytest.raises(SystemExit) as exit_info:
        COMMANDS[command](args)
    after = files()
    assert {f: after.get(f) for f in before} == before, "a file that was there was changed or removed"
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert "error:" in last and fragment in last, err
    if not fragment.startswith("argument "):  # argparse prints its usage line first; ours is one line
        assert last.startswith("error: ") and err.count("error:") == 1, err


# --------------------------------------------------------------------------- predict()
@pytest.fixture(scope="module")
def good_request():
    rng = np.random.default_rng(1)
    models = Models(random_params(EBMNet(TINY), 0), random_params(DMONet(TINY), 1), random_params(VAENet(TINY.vae), 2))
    image = jnp.asarray(rng.uniform(0, 1, (32, 32, 4)), jnp.float32)
    return dict(models=models, image=image, bank=jnp.asarray(_motions(6, rng)), key=jax.random.key(0),
                preset=TINY, method="sort", n=2, R=1)


def _with(**changes):
    return lambda r: {**r, **{k: (v(r) if callable(v) else v) for k, v in changes.items()}}


def _pcase(fragment, change, name):
    return pytest.param(change, fragment, id=name)


def _set(array, index, value):
    return jnp.asarray(array).at[index].set(value)


PREDICT_CASES = [
    _pcase("image must be floating-point", _with(image=lambda r: (r["image"] * 255).astype(jnp.uint8)), "image-uint8"),
    _pcase("image must be floating-point", _with(image=lambda r: r["image"] > 0.5), "image-bool"),
    _pcase("image values must lie in [0, 1]", _with(image=lambda r: r["image"] * 255), "image-0-255"),
    _pcase("got min -0.5", _with(image=lambda r: _set(r["image"], (0, 0, 0), -0.5)), "image-negative"),
    _pcase("image contains 1 NaN or inf", _with(image=lambda r: _set(r["image"], (3, 4, 1), jnp.nan)), "image-nan"),
    _pcase("image contains 1 NaN or inf", _with(image=lambda r: _set(r["image"], (3, 4, 3), jnp.inf)), "image-inf"),
    _pcase("image must be [32, 32, 4] or [B, 32, 32, 4]", _with(image=lambda r: r["image"][..., :3]), "image-rgb-only"),
    _pcase("got (64, 64, 4)", _with(image=jnp.zeros((64, 64, 4))), "image-other-size"),
    _pcase("got (1, 1, 32, 32, 4)", _with(image=lambda r: r["image"][None, None]), "image-5d"),
    _pcase("got (32, 32)", _with(image=lambda r: r["image"][..., 0]), "image-2d"),
    _pcase("bank contains 1 NaN or inf", _with(bank=lambda r: _set(r["bank"], (2, 50, 0), jnp.nan)), "bank-nan"),
    _pcase("bank contains 11 NaN or inf", _with(bank=lambda r: _set(r["bank"], (0, 7), -jnp.inf)), "bank-inf"),
    _pcase("bank must be [N, 101, 11] motions, got (6, 50, 11)", _with(bank=lambda r: r["bank"][:, :50]), "bank-short"),
    _pcase("bank must be [N, 101, 11] motions, got (6, 101, 10)", _with(bank=lambda r: r["bank"][..., :10]), "bank-narrow"),
    _pcase("bank must be [N, 101, 11] motions, got (101, 11)", _with(bank=lambda r: r["bank"][0]), "bank-one-motion"),
    _pcase("bank must be floating-point", _with(bank=lambda r: r["bank"].astype(jnp.int32)), "bank-int"),
    _pcase("the bank of motions is empty", _with(bank=lambda r: r["bank"][:0]), "bank-empty"),
    _pcase("n must be in [1, bank size 6], got 7", _with(n=7), "n-too-large"),
    _pcase("n must be in [1, bank size 6], got 0", _with(n=0), "n-zero"),
    _pcase("n must be an integer, got 2.5", _with(n=2.5), "n-float"),
    _pcase("R must be >= 0, got -1", _with(R=-1, method="dmo"), "R-negative"),
    _pcase("chunk must be >= 1, got 0", _with(chunk=0), "chunk-zero"),
    _pcase("unknown method 'best'", _with(method="best"), "method-unknown"),
    _pcase("unknown preset 'huge'", _with(preset="huge"), "preset-unknown"),
    _pcase("preset must be a dmo_jax.config.Preset", _with(preset=32), "preset-wrong-type"),
    _pcase("key must be one PRNG key", _with(key=jnp.zeros(2)), "key-float"),
    _pcase("key must be one PRNG key", _with(key=lambda r: jax.random.split(r["key"], 3)), "key-batch"),
    _pcase("needs the DMO parameters", _with(models=lambda r: Models(r["models"].ebm), method="dmo"), "dmo-missing"),
    _pcase("needs the motion VAE parameters", _with(models=lambda r: Models(r["models"].ebm), method="vaebm-l"),
           "vae-missing"),
    _pcase("needs the EBM parameters", _with(models=lambda r: Models(None)), "ebm-missing"),
    _pcase("models must be dmo_jax.inference.Models", _with(models=lambda r: {"ebm": r["models"].ebm}), "models-dict"),
    _pcase("Models.ebm do not fit preset 'tiny' (variant 'concat', 32px)",
           _with(models=lambda r: Models(EBMNet(get_preset("cpu")).param_shapes())), "ebm-of-cpu-preset"),
    _pcase("6 parameter(s) missing", _with(models=lambda r: Models(EBMNet(get_preset("tiny", "wo_concat")).param_shapes())),
           "ebm-of-other-variant"),
    _pcase("6 parameter(s) missing (e.g. ['params']['trunk']['mix_mlp']", _with(models=lambda r: Models(EBMNet(get_preset("tiny", "vit")).param_shapes())),
           "ebm-of-vit-variant"),
    _pcase("Models.dmo do not fit preset 'tiny'",
           _with(models=lambda r: Models(r["models"].ebm, r["models"].ebm), method="dmo"), "dmo-given-ebm"),
    _pcase("the image batch is empty (shape (0, 32, 32, 4))", _with(image=lambda r: r["image"][None][:0]), "images-none"),
    _pcase("the networks produced", _with(models=lambda r: Models(jax.tree.map(lambda x: x * jnp.nan, r["models"].ebm))),
           "ebm-params-nan"),
    _pcase("the networks produced", _with(models=lambda r: r["models"]._replace(
        dmo=jax.tree.map(lambda x: x * jnp.nan, r["models"].dmo)), method="dmo"), "dmo-params-nan"),
    _pcase("the networks produced", _with(bank=lambda r: r["bank"] * 1e30), "bank-huge"),
    _pcase("Models.vae do not fit preset 'tiny'",
           _with(models=lambda r: Models(r["models"].ebm, vae=VAENet(get_preset("cpu").vae).param_shapes()),
                 method="vaebm-s"), "vae-of-cpu-preset"),
]


@pytest.mark.parametrize("change, fragment", PREDICT_CASES)
def test_predict_rejects_malformed_input(good_request, change, fragment):
    request = change(good_request)
    args = [request.pop(k) for k in ("models", "image", "bank", "key")]
    with pytest.raises(ValueError) as info:
        predict(*args, **request)
    message = str(info.value)
    assert fragment in message and "\n" not in message


def test_predict_checks_under_the_callers_trace(good_request):
    """Under a caller's trace (``jax.jit``; ``eval_shape`` traces the same way without compiling)
    values are unknown: a NaN image passes, but shapes and dtypes are still checked."""
    r = dict(good_request)
    models, bank, key = r.pop("models"), r.pop("bank"), r.pop("key")
    image = r.pop("image")
    traced = lambda img: predict(models, img, bank, key, **r)  # noqa: E731
    out = jax.eval_shape(traced, image.at[0, 0, 0].set(jnp.nan))
    assert out.motion.shape == (101, 11) and out.candidates.shape == (2, 101, 11)
    with pytest.raises(ValueError, match="image must be floating-point"):
        jax.eval_shape(traced, (image * 255).astype(jnp.uint8))
    with pytest.raises(ValueError, match=r"image must be \[32, 32, 4\]"):
        jax.eval_shape(traced, image[:16])
    # concrete inputs that are valid pass every check (batched images and a legacy uint32 key too)
    jax.eval_shape(lambda img: predict(models, img, bank, jax.random.PRNGKey(0), **r), jnp.stack([image, image]))


# --------------------------------------------------------------------------- SIGKILL: training
_TRAIN = r"""
import dataclasses, sys, time
from pathlib import Path
sys.path[:0] = [sys.argv[1], sys.argv[1] + "/tests"]
from envs.platform import enable_compilation_cache, setup
setup()
enable_compilation_cache()  # the suite's, shared with the other tests (conftest.py)
import jax, numpy as np
from dmo_jax import data as data_lib, training
from dmo_jax.config import get_preset

workdir, mode, out = Path(sys.argv[2]), sys.argv[3], sys.argv[4]


def pause(why):  # hold still where the test wants the SIGKILL to land
    (workdir / "paused").write_text(why)
    while True:
        time.sleep(60)


if mode.startswith("after-step:"):
    k = int(mode.split(":")[1])
    append = training._append_jsonl
    def logged(path, record):
        append(path, record)
        if record["step"] == k:
            pause(f"step {k} done")
    training._append_jsonl = logged
elif mode.startswith("in-save:"):
    k = mode.split(":")[1]
    from orbax.checkpoint._src.path import atomicity
    finalize = atomicity.AtomicRenameTemporaryPath.finalize
    async def blocked(self):  # every file of the step is written, the commit (marker + rename) is not
        if self.get_final().name == k:
            pause(f"saving {k}")
        await finalize(self)
    atomicity.AtomicRenameTemporaryPath.finalize = blocked

p = get_preset("tiny")
p = dataclasses.replace(p, train=dataclasses.replace(p.train, lr=1e-3, vae_steps=12))
rng = np.random.default_rng(0)
motions = np.concatenate([rng.uniform(-1, 1, (16, 101, 10)), np.tile(np.linspace(0, 1, 101)[None, :, None], (16, 1, 1))], -1)
ds = data_lib.MotionDataset(np.zeros((16, 32, 32, 4), np.float32), motions.astype(np.float32))
# Random initial parameters drawn with numpy (tests/helpers.py): flax's eager ``init`` would cost
# each of the five processes ~3 s of small compilations; resuming does not depend on it.
from helpers import random_params
spec = training.vae_spec(p)
spec = dataclasses.replace(spec, init_fn=lambda key: random_params(training.VAENet.from_preset(p), 7))
params, summary = training.fit(spec, ds, workdir, checkpoint_every=4, log_every=1, keep=3, verbose=False)
np.savez(out, *[np.asarray(x) for x in jax.tree.leaves(params)])
print(summary["steps"])
"""
TMP_SUFFIX = ".orbax-checkpoint-tmp"


def _spawn(args, log, env=None):
    """A Python subprocess running ``python -c args...``; stderr goes to the file ``log`` (a pipe
    nobody reads could fill up and stall it)."""
    with open(log, "w") as err:
        proc = subprocess.Popen([sys.executable, "-c", *map(str, args)], env=env, stdout=subprocess.PIPE,
                                stderr=err, text=True)
    proc.log = Path(log)
    return proc


def _train_process(workdir, mode, out, env):
    return _spawn([_TRAIN, ROOT, workdir, mode, out], f"{out}.{mode.replace(':', '-')}.log", env)


def _wait_for(condition, proc, what, timeout=240):
    deadline = time.monotonic() + timeout
    while not condition():
        if proc.poll() is not None:
            pytest.fail(f"process ended (status {proc.returncode}) before {what}: {proc.log.read_text()[-3000:]}")
        if time.monotonic() > deadline:
            proc.kill()
            pytest.fail(f"timed out waiting for {what}")
        time.sleep(0.02)


def _kill(proc):
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=60)
    assert proc.returncode == -signal.SIGKILL


def _latest(ckpt):
    mngr = training._checkpoint_manager(ckpt, 3)
    try:
        return mngr.latest_step()
    finally:
        mngr.close()


def _committed(ckpt):
    """Step directories under their final name; each must carry orbax's commit marker."""
    steps = sorted(int(d.name) for d in ckpt.iterdir() if d.name.isdigit())
    for s in steps:
        assert (ckpt / str(s) / "commit_success.txt").is_file(), f"step {s} is half-written under its final name"
    return steps


def _steps_logged(workdir):
    lines = (workdir / "metrics.jsonl").read_text().splitlines() if (workdir / "metrics.jsonl").exists() else []
    return [json.loads(line)["step"] for line in lines]


def test_training_killed_three_times_resumes_to_the_uninterrupted_parameters(tmp_path):
    # The five processes inherit the suite's XLA flags and compilation cache (conftest.py), so
    # the first compiles what the others load; every run uses the same flags.
    env = dict(os.environ)
    full = _train_process(tmp_path / "full", "run", tmp_path / "full.npz", env)
    full.communicate(timeout=600)
    assert full.returncode == 0, full.log.read_text()[-3000:]

    work, ckpt = tmp_path / "cut", tmp_path / "cut" / "checkpoints"
    paused = work / "paused"

    # 1. killed after step 2, before the first checkpoint: the resume starts from scratch
    proc = _train_process(work, "after-step:2", tmp_path / "cut.npz", env)
    _wait_for(paused.exists, proc, "step 2")
    _kill(proc)
    assert _latest(ckpt) is None and _committed(ckpt) == [] and _steps_logged(work) == [1, 2]
    paused.unlink()

    # 2. killed in the middle of saving step 8 (all files written, not committed)
    proc = _train_process(work, "in-save:8", tmp_path / "cut.npz", env)
    _wait_for(paused.exists, proc, "the save of step 8")
    _kill(proc)
    unfinished = [d for d in ckpt.iterdir() if d.name.startswith("8" + TMP_SUFFIX)]
    assert len(unfinished) == 1 and not (unfinished[0] / "commit_success.txt").exists()
    assert any(unfinished[0].rglob("*")), "the killed save had written files"
    assert _committed(ckpt) == [4] and _latest(ckpt) == 4
    paused.unlink()

    # 3. killed after step 10, with step 8's checkpoint committed
    proc = _train_process(work, "after-step:10", tmp_path / "cut.npz", env)
    _wait_for(lambda: paused.exists() and (ckpt / "8" / "commit_success.txt").exists(), proc, "step 10")
    _kill(proc)
    assert _committed(ckpt) == [4, 8] and _latest(ckpt) == 8
    assert not [d for d in ckpt.iterdir() if TMP_SUFFIX in d.name], "the redone save replaced the unfinished one"
    paused.unlink()

    # the last resume runs to the end
    last = _train_process(work, "run", tmp_path / "cut.npz", env)
    stdout, _ = last.communicate(timeout=600)
    assert last.returncode == 0 and stdout.split() == ["12"], last.log.read_text()[-3000:]
    with np.load(tmp_path / "full.npz") as a, np.load(tmp_path / "cut.npz") as b:
        assert a.files == b.files and len(a.files) > 10
        for name in a.files:
            np.testing.assert_array_equal(a[name], b[name])
    assert _committed(ckpt) == [4, 8, 12] and _latest(ckpt) == 12
    assert not [d for d in ckpt.iterdir() if TMP_SUFFIX in d.name]
    assert _steps_logged(work) == list(range(1, 13)) == _steps_logged(tmp_path / "full")


def test_torn_metrics_line_is_dropped_on_resume(tmp_path):
    path = tmp_path / "metrics.jsonl"
    path.write_text('{"step": 1, "loss": 1.0}\n{"step": 2, "loss": 0.9}\n{"step": 3, "lo')
    training._truncate_metrics(path, 4)
    assert [json.loads(line)["step"] for line in path.read_text().splitlines()] == [1, 2]


# --------------------------------------------------------------------------- SIGKILL: data, determinism
_GENERATE = r"""
import io, sys, time
from pathlib import Path
sys.path.insert(0, sys.argv[1])
from envs.platform import setup
setup()
import numpy as np
from envs import dataset
from envs.tasks import get_task

root = Path(sys.argv[2])
savez, calls = np.savez, []


def torn_second_chunk(file, **arrays):  # write the first chunk whole, then half of the second, and stop
    calls.append(1)
    if len(calls) < 2:
        return savez(file, **arrays)
    buffer = io.BytesIO()
    savez(buffer, **arrays)
    data = buffer.getvalue()
    file.write(data[: len(data) // 2])
    file.flush()
    (root / "paused").write_text("second chunk half written")
    while True:
        time.sleep(60)


dataset.np.savez = torn_second_chunk
dataset.generate_split(get_task("reach_target", 32), "train", 10, root, batch=8, verbose=False)
"""


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    from envs.tasks import get_task

    root = tmp_path_factory.mktemp("generated")
    task = get_task(TASK, 32)
    dataset.generate_split(task, "train", 10, root, batch=8, verbose=False)
    dataset.generate_split(task, "test", 8, root, batch=8, verbose=False)
    return root, task


def test_generation_killed_mid_write_resumes_to_identical_bytes(tmp_path, generated):
    root, task = generated
    data = tmp_path / "data"
    data.mkdir()
    proc = _spawn([_GENERATE, ROOT, data], tmp_path / "generate.log")
    _wait_for((data / "paused").exists, proc, "the second batch file")
    _kill(proc)
    partial = list(data.glob(f"{TASK}/.train.partial-*"))
    assert len(partial) == 1 and [p.name for p in partial[0].glob("chunk_*.npz")] == ["chunk_000000.npz"]
    assert [p.name for p in partial[0].glob("*.tmp")] == ["chunk_000001.npz.tmp"], "the torn file stays temporary"
    with pytest.raises(dataset.DatasetError, match="no complete dataset"):
        dataset.load_split(data, TASK, "train")
    dataset.generate_split(task, "train", 10, data, batch=8, verbose=False)
    for f in dataset.FILES + ("meta.json",):  # same seed, another process, interrupted: the same bytes
        assert (data / TASK / "train" / f).read_bytes() == (root / TASK / "train" / f).read_bytes(), f
    assert sorted(p.name for p in (data / TASK).iterdir()) == [".train.lock", "train"]  # no partial left


def test_same_seed_gives_identical_bytes_and_another_seed_does_not(tmp_path, generated):
    root, task = generated
    dataset.generate_split(task, "test", 8, tmp_path / "same", batch=8, verbose=False)
    dataset.generate_split(task, "test", 8, tmp_path / "other", base_seed=1, batch=8, verbose=False)
    for f in dataset.FILES:
        reference = (root / TASK / "test" / f).read_bytes()
        assert (tmp_path / "same" / TASK / "test" / f).read_bytes() == reference, f
    assert (tmp_path / "other" / TASK / "test" / "seeds.npy").read_bytes() != (root / TASK / "test" / "seeds.npy").read_bytes()
    assert (tmp_path / "other" / TASK / "test" / "rgb.npy").read_bytes() != (root / TASK / "test" / "rgb.npy").read_bytes()


def test_native_evaluation_is_deterministic(generated):
    """Each call rebuilds the task and its scenes from the seeds (and recompiles the IK: ~4 s)."""
    from envs.evaluation import evaluate_world_method

    root, _ = generated
    runs = [evaluate_world_method(TASK, "expert", 8, root, backend="mujoco") for _ in range(2)]
    for r in runs:
        r.pop("seconds")  # wall time, the one field that may differ
    assert runs[0] == runs[1]
    assert runs[0]["episodes"] == 8 and runs[0]["successes"] == 8


def test_invalid_multi_host_settings_are_one_line_errors(monkeypatch, capsys, tmp_path):
    monkeypatch.setenv("DMO_COORDINATOR", "localhost:1234")
    monkeypatch.setenv("DMO_NUM_PROCESSES", "two")
    monkeypatch.setenv("DMO_PROCESS_ID", "0")
    with pytest.raises(SystemExit) as exit_info:
        train_all.main(["--tasks", TASK, "--preset", "tiny", "--workdir", str(tmp_path)])
    assert exit_info.value.code == 2
    assert "DMO_NUM_PROCESSES must be a positive integer" in capsys.readouterr().err


def test_integer_depth_is_refused_not_read_as_metres():
    from dmo_jax.data import network_image

    rgb = np.zeros((4, 4, 3), np.uint8)
    with pytest.raises(ValueError, match="depth must be floating-point metres, got uint16 .*millimetres"):
        network_image(rgb, np.full((4, 4), 1500, np.uint16))
    assert network_image(rgb, np.full((4, 4), 1.5, np.float32)).shape == (4, 4, 4)


def test_a_damaged_batch_file_of_an_unfinished_split_is_named(tmp_path):
    chunk = tmp_path / "chunk_000000.npz"
    np.savez(chunk, rgb=np.zeros((1, 2, 2, 3), np.uint8), depth=np.zeros((1, 2, 2), np.float32),
             motions=np.zeros((1, 101, 11), np.float32), seeds=np.zeros(1, np.int64), attempts=np.int64(1),
             successes=np.int64(1))
    assert dataset._read_chunk(chunk)["seeds"].shape == (1,)
    chunk.write_bytes(chunk.read_bytes()[:200])  # truncated, as a failing disk would leave it
    with pytest.raises(dataset.DatasetError, match=f"corrupt batch file {chunk} in an unfinished split"):
        dataset._read_chunk(chunk)


def test_load_models_names_a_bad_preset_or_method(tmp_path):
    from dmo_jax.workflow import load_models

    with pytest.raises(ValueError, match="preset must be a dmo_jax.config.Preset"):
        load_models(tmp_path, TASK, "tiny", "dmo")
    with pytest.raises(ValueError, match="unknown method 'dmox'; expected one of sort, dmo"):
        load_models(tmp_path, TASK, TINY, ["sort", "dmox"])


def test_a_second_writer_of_a_split_fails_naming_the_first(tmp_path):
    from envs.tasks import get_task

    task = get_task(TASK, 32)
    with dataset.writer_lock(tmp_path / TASK / ".train.lock"):  # as another bin/generate_data would
        with pytest.raises(dataset.DatasetError, match=f"being written by process {os.getpid()}; wait"):
            dataset.generate_split(task, "train", 2, tmp_path, batch=2, verbose=False)
    assert not (tmp_path / TASK / "train").exists()
    dataset.generate_split(task, "train", 2, tmp_path, batch=2, verbose=False)  # free once the first is done
    assert dataset.load_split(tmp_path, TASK, "train").seeds.shape == (2,)


def test_the_missing_dataset_hint_run_as_printed_makes_the_dataset_needed(tmp_path, capsys):
    data = tmp_path / "data" / "32px"
    with pytest.raises(SystemExit):
        evaluate.main(["--task", TASK, "--method", "sort", "--preset", "tiny", "--data", str(data)])
    hint = capsys.readouterr().err.strip().splitlines()[-1].split("`")[1].split()
    assert hint[0] == "bin/generate_data" and "--image-size" in hint
    generate_data.main(hint[1:] + ["--train", "3", "--test", "2"])  # the printed command, fewer episodes
    split = dataset.load_split(data, TASK, "test")
    assert split.meta["image_size"] == TINY.image_size and len(split.motions) == 2


def test_xla_flags_the_user_set_are_kept(monkeypatch):
    from envs.platform import add_xla_flag, expose_cpu_cores_as_devices

    monkeypatch.setenv("XLA_FLAGS", "--xla_force_host_platform_device_count=3 --xla_cpu_use_fusion_emitters=true")
    assert not add_xla_flag("--xla_cpu_use_fusion_emitters=false")
    expose_cpu_cores_as_devices()
    assert os.environ["XLA_FLAGS"] == "--xla_force_host_platform_device_count=3 --xla_cpu_use_fusion_emitters=true"
    monkeypatch.delenv("XLA_FLAGS")
    assert add_xla_flag("--xla_cpu_use_fusion_emitters=false")
    assert os.environ["XLA_FLAGS"] == "--xla_cpu_use_fusion_emitters=false"
