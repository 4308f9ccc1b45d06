"""bin/reproduce: the tables from nothing, written as files, rendered, and resumable."""
import json
import shutil
from pathlib import Path

import pytest

from dmo_jax import reproduce
from dmo_jax.comparison import load_evaluations

TASK = "reach_target"  # the task of the suite's shared tiny networks (conftest.py, `trained`)


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
    assert [r.variant for r in reproduce.table_runs("2", "bank", ("concat", "gap"))] == ["concat", "gap"]
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
    # made without the depth cue, at a size it did not record (files older than the field: 64²)
    settings = {k: v for k, v in reproduce._settings(run, cpu).items() if k != "image_size"}
    old = {**reproduce._record(made(0), run, cpu), "settings": {**settings, "depth_cue": False}}
    path.write_text(json.dumps({"provenance": {"preset": "cpu", "episodes": 2}, "results": [old]}))
    reproduce.reproduce(["6"], ["reach_target"], cpu, 2, results_dir=tmp_path, data=tmp_path, workdir=tmp_path,
                        command=["--tables", "6"], log=lambda m: None)
    payload = json.loads(path.read_text())
    (row,) = payload["results"]
    assert row["successes"] == 2 and row["settings"]["depth_cue"] is True and row["settings"]["image_size"] == 96
    # the file says how its new results were made
    assert payload["provenance"]["commands"] == ["bin/reproduce --tables 6"] and "versions" in payload["provenance"]
    # made with today's settings, it is done: nothing is evaluated again
    before = path.read_bytes()
    monkeypatch.setattr(reproduce, "evaluate_run", lambda *a, **k: pytest.fail("evaluated a done row"))
    reproduce.reproduce(["6"], ["reach_target"], cpu, 2, results_dir=tmp_path, data=tmp_path, workdir=tmp_path,
                        command=["--tables", "6", "--tasks", "reach_target"], log=lambda m: None)
    assert path.read_bytes() == before
    # a command that adds results is named after those that made the rest
    monkeypatch.setattr(reproduce, "evaluate_run", lambda *a, **k: [{**made(1), "task": "stack_wine"}])
    reproduce.reproduce(["6"], ["reach_target", "stack_wine"], cpu, 2, results_dir=tmp_path, data=tmp_path,
                        workdir=tmp_path, command=["--tables", "6", "--tasks", "stack_wine"], log=lambda m: None)
    payload = json.loads(path.read_text())
    assert [r["task"] for r in payload["results"]] == ["reach_target", "stack_wine"]
    assert payload["provenance"]["commands"] == ["bin/reproduce --tables 6",
                                                 "bin/reproduce --tables 6 --tasks stack_wine"]
    assert reproduce.render(path, "6").startswith(
        "`bin/reproduce --tables 6`, then `bin/reproduce --tables 6 --tasks stack_wine`: preset `cpu`")


def _run(capsys, *args) -> tuple[int, str]:
    """``bin/reproduce args`` in this process (its compiled programs are the suite's): exit code, stderr."""
    from dmo_jax.commands.reproduce import main

    capsys.readouterr()
    try:
        main(list(args))
        code = 0
    except SystemExit as exit_:
        code = exit_.code
    return code, capsys.readouterr().err


def test_reproduce_writes_results_renders_tables_and_a_second_run_does_no_work(trained, tmp_path, capsys):
    shared_data, shared_work, _ = trained  # reach_target's data and networks (in a copy: they are shared)
    data, work = shutil.copytree(shared_data, tmp_path / "data"), shutil.copytree(shared_work, tmp_path / "runs")
    (dmo,) = work.glob(f"{TASK}/tiny/concat/dmo-*")
    shutil.rmtree(dmo)  # the command trains what is missing and loads the rest
    report = tmp_path / "REPORT.md"
    report.write_text("# Report\n")
    args = ["--tables", "5", "--tasks", TASK, "--preset", "tiny", "--episodes", "4", "--data", str(data),
            "--workdir", str(work), "--results", str(tmp_path / "results"), "--report", str(report)]
    code, err = _run(capsys, *args)
    assert code == 0, err
    assert "train dmo" in err and "train ebm" not in err and dmo.is_dir()
    path = tmp_path / "results" / "table5.json"
    payload = json.loads(path.read_text())
    made = payload["provenance"]
    assert (made["preset"], made["episodes"]) == ("tiny", 4) and "jax" in made["versions"]
    assert len(made["commands"]) == 1 and made["commands"][0].startswith("bin/reproduce --tables 5")
    records = payload["results"]
    assert {r["task"] for r in records} == {TASK}
    assert all(r["episodes"] == 4 and r["successes"] == sum(r["episode_success"]) for r in records)
    assert all(r["settings"]["recipe"] == "paper" and r["settings"]["dmo_inputs"] == "decoded" for r in records)
    # n = 1, 8 and 1,000, the last the whole bank of 20
    assert {(r["n"], r["R"]) for r in records} == {(1, 1), (8, 1), (20, 1)}
    rows = load_evaluations([path])  # bin/compare reads a table file
    assert len(rows) == 3 and all(set(per_task) == {TASK} for per_task in rows.values())
    section = report.read_text().split("<!-- table5 -->")[1].split("<!-- /table5 -->")[0]
    assert "| method | CB | PC | PB |" in section and "paper R=1, n=1000" in section
    assert "dmo n=8 R=1 {image_size=32} |" in section and "preset `tiny`" in section
    before = path.read_bytes()
    code, err = _run(capsys, *args)
    assert code == 0, err
    assert "training" not in err and err.count(": done") == 1
    assert path.read_bytes() == before
    # results of another preset or scene count are never mixed in
    code, err = _run(capsys, *args[:-10], "--episodes", "3", *args[-8:])
    assert code == 2 and "on 4 scenes, not 'tiny' on 3" in err
