"""bin/reproduce: the tables from nothing, written as files, rendered, and resumable."""
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from dmo_jax import reproduce
from dmo_jax.comparison import load_evaluations
from envs import dataset
from envs.tasks import get_task

ROOT = Path(__file__).resolve().parents[1]
TASKS = ("reach_target", "push_button")  # reach_target: the suite's shared tiny networks


def test_tables_are_replaced_between_their_markers_and_appended_where_missing(tmp_path):
    report = tmp_path / "B.md"
    report.write_text("# B\n\nintro\n<!-- table5 -->\nold\n<!-- /table5 -->\nafter\n")
    reproduce.update_report(report, {"5": "new five", "6": "six"})
    text = report.read_text()
    assert "old" not in text and "<!-- table5 -->\nnew five\n<!-- /table5 -->\nafter" in text
    assert text.startswith("# B\n\nintro\n") and text.rstrip().endswith("<!-- table6 -->\nsix\n<!-- /table6 -->")
    reproduce.update_report(report, {"6": "six again"})
    assert report.read_text().count("<!-- table6 -->") == 1 and "six again" in report.read_text()


def test_every_table_has_its_runs_and_the_papers_rows():
    for table in reproduce.TABLES:
        runs = reproduce.table_runs(table, "bank")
        assert runs and len({r.name for r in runs}) == len(runs)
        assert all(len(v) == 9 for v in reproduce.PAPER[table].values())
    assert {r.recipe for r in reproduce.table_runs("1", "bank")} == {None, "paper", "bank"}  # both recipes, the oracle
    with pytest.raises(ValueError, match="unknown table '3'"):
        reproduce.table_runs("3", "bank")


def test_rows_made_with_settings_the_preset_no_longer_has_are_replaced_not_mixed_in(tmp_path, monkeypatch):
    from dmo_jax.config import get_preset

    cpu = get_preset("cpu")
    (run,) = reproduce.table_runs("6", "bank")
    made = lambda successes: {"task": "reach_target", "method": "dmo", "n": 8, "R": 1,  # noqa: E731
                                   "successes": successes, "episodes": 2, "success_rate": successes / 2,
                                   "episode_success": [1] * successes + [0] * (2 - successes)}
    monkeypatch.setattr(reproduce, "evaluate_run", lambda *a, **k: [made(2)])
    path = tmp_path / "table6.json"
    old = {**reproduce._record(made(0), run, cpu), "settings": {**reproduce._settings(run, cpu), "depth_cue": False}}
    path.write_text(json.dumps({"provenance": {"preset": "cpu", "episodes": 2}, "results": [old]}))
    reproduce.reproduce(["6"], ["reach_target"], cpu, 2, results_dir=tmp_path, data=tmp_path, workdir=tmp_path,
                        command=["--tables", "6"], log=lambda m: None)
    payload = json.loads(path.read_text())
    (row,) = payload["results"]
    assert row["successes"] == 2 and row["settings"]["depth_cue"] is True
    # the file says how its new results were made
    assert payload["provenance"]["command"] == "bin/reproduce --tables 6" and "versions" in payload["provenance"]
    # made with today's settings, it is done: nothing is evaluated again
    monkeypatch.setattr(reproduce, "evaluate_run", lambda *a, **k: pytest.fail("evaluated a done row"))
    reproduce.reproduce(["6"], ["reach_target"], cpu, 2, results_dir=tmp_path, data=tmp_path, workdir=tmp_path,
                        log=lambda m: None)


def _run(*args):
    return subprocess.run([sys.executable, str(ROOT / "bin/reproduce"), *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=1800)


def test_reproduce_writes_results_renders_tables_and_a_second_run_does_no_work(trained, tmp_path):
    shared_data, shared_work, _ = trained  # reach_target, trained (in a copy: it is shared)
    data, work = shutil.copytree(shared_data, tmp_path / "data"), shutil.copytree(shared_work, tmp_path / "runs")
    task = get_task(TASKS[1], 32)
    dataset.generate_split(task, "train", 20, data, batch=20, verbose=False)  # the bank of the shared task
    dataset.generate_split(task, "test", 4, data, batch=4, verbose=False)
    report = tmp_path / "REPORT.md"
    report.write_text("# Report\n")
    args = ["--tables", "5", "--tasks", ",".join(TASKS), "--preset", "tiny", "--episodes", "4", "--data",
            str(data), "--workdir", str(work), "--results", str(tmp_path / "results"), "--report", str(report)]
    first = _run(*args)
    assert first.returncode == 0, first.stderr
    # the trained task is loaded, the other one trained
    trained_first, rest = first.stderr.split(f"{TASKS[1]} paper-n: training what is missing")
    assert "train ebm" not in trained_first and "train ebm" in rest
    files = {"5": tmp_path / "results" / "table5.json"}
    for table, path in files.items():
        payload = json.loads(path.read_text())
        made = payload["provenance"]
        assert (made["preset"], made["episodes"]) == ("tiny", 4) and "jax" in made["versions"]
        assert made["command"].startswith("bin/reproduce --tables 5")
        records = payload["results"]
        assert {r["task"] for r in records} == set(TASKS)
        assert all(r["episodes"] == 4 and r["successes"] == sum(r["episode_success"]) for r in records)
        assert all(r["settings"]["recipe"] == "paper" and r["settings"]["dmo_inputs"] == "decoded" for r in records)
        # n = 1, 8 and 1,000, the last the whole bank of 20
        assert {(r["n"], r["R"]) for r in records if r["task"] == TASKS[1]} == {(1, 1), (8, 1), (20, 1)}
        rows = load_evaluations([path])  # bin/compare reads a table file
        assert len(rows) == 3 and all(set(per_task) == set(TASKS) for per_task in rows.values())
    text = report.read_text()
    for table in files:
        section = text.split(f"<!-- table{table} -->")[1].split(f"<!-- /table{table} -->")[0]
        assert "| method | CB | PC | PB |" in section and "paper R=1, n=1000" in section
        assert "dmo n=8 R=1 |" in section and "preset `tiny`" in section
    before = {p: p.read_bytes() for p in files.values()}
    second = _run(*args)
    assert second.returncode == 0, second.stderr
    assert "training" not in second.stderr and second.stderr.count(": done") == 2
    assert {p: p.read_bytes() for p in files.values()} == before
    # results of another preset or scene count are never mixed in
    other = _run(*args[:-10], "--episodes", "3", *args[-8:])
    assert other.returncode == 2 and "on 4 scenes, not 'tiny' on 3" in other.stderr
