"""bin/compare: one success table from several bin/evaluate --json files, and a row against the
others scene by scene with an exact sign test."""
import json

import numpy as np
import pytest

from dmo_jax.commands import compare
from dmo_jax.comparison import comparison_report, load_evaluations, paired_counts, sign_test


def _evaluation(path, results, dmo_train_steps=None):
    """A file shaped like ``bin/evaluate --json``'s, with per-scene successes."""
    entries = [{"method": method, "n": 8, "R": 1 if method == "dmo" else None, "task": task,
                "episodes": len(s), "successes": sum(s), "success_rate": sum(s) / len(s), "episode_success": s}
               for method, task, s in results]
    path.write_text(json.dumps({"results": entries, "settings": {"dmo_train_steps": dmo_train_steps}}))
    return path


def test_sign_test_is_exact_and_symmetric():
    assert sign_test(0, 0) == 1.0
    assert sign_test(10, 0) == pytest.approx(2 / 2**10)
    assert sign_test(3, 5) == pytest.approx(sign_test(5, 3))
    assert sign_test(30, 4) < 0.05 < sign_test(7, 5)


def test_paired_counts_need_the_same_scenes():
    assert paired_counts(np.array([1, 1, 0, 0]), np.array([1, 0, 1, 1])) == (1, 2)
    with pytest.raises(ValueError, match="cannot pair 3 scenes with 4"):
        paired_counts(np.array([1, 1, 0]), np.array([1, 0, 1, 1]))


def test_report_merges_files_and_counts_paired_scenes(tmp_path):
    ahead = [1] * 30 + [0] * 70          # solves scenes 0-29
    behind = [0] * 26 + [1] * 4 + [0] * 70  # solves 26-29: the DMO wins 26, loses none
    files = [_evaluation(tmp_path / "a.json", [("dmo", "close_box", ahead), ("sort", "close_box", behind),
                                               ("dmo", "reach_target", behind), ("sort", "reach_target", behind)]),
             _evaluation(tmp_path / "b.json", [("dmo", "close_box", behind)], dmo_train_steps=5)]
    rows = load_evaluations(files)
    assert list(rows) == ["dmo n=8 R=1", "sort n=8", "dmo n=8 R=1 (trained R=5)"]
    report = comparison_report(rows, "dmo n=8 R=1")
    assert "| dmo n=8 R=1 | 30 | – |" in report and "| 4 |" in report
    assert "| sort n=8 | +26 / −0* | +0 / −0 |" in report
    assert "| dmo n=8 R=1 (trained R=5) | +26 / −0* | – |" in report
    assert "more scenes than every other row on 1 of 2 tasks (CB), as many as the best of them on 1 (RT)" in report
    assert "significantly fewer than some row on 0." in report

    reversed_report = comparison_report(rows, "sort n=8")
    assert "significantly fewer than some row on 1; CB: dmo n=8 R=1." in reversed_report


def test_mixing_two_files_of_the_same_row_and_task_is_refused(tmp_path):
    a = _evaluation(tmp_path / "a.json", [("dmo", "close_box", [1, 0])])
    b = _evaluation(tmp_path / "b.json", [("dmo", "close_box", [0, 1])])
    with pytest.raises(ValueError, match="'dmo n=8 R=1' on close_box is also in .*a.json, with other"):
        load_evaluations([a, b])
    # the same outcomes (one network evaluated in two runs) are one row
    again = _evaluation(tmp_path / "again.json", [("dmo", "close_box", [1, 0])])
    assert {k: v.tolist() for k, v in load_evaluations([a, again])["dmo n=8 R=1"].items()} == {"close_box": [1, 0]}
    (tmp_path / "other.json").write_text(json.dumps({"results": [{"method": "dmo"}]}))
    with pytest.raises(ValueError, match="not a `bin/evaluate --json` file"):
        load_evaluations([tmp_path / "other.json"])


def test_command_prints_the_report_and_rejects_an_unknown_row(tmp_path, capsys):
    a = _evaluation(tmp_path / "a.json", [("dmo", "close_box", [1, 1, 0]), ("gd", "close_box", [0, 1, 0])])
    compare.main([str(a)])
    out = capsys.readouterr().out
    assert "| gd n=8 | +1 / −0 |" in out and "on 1 of 1 tasks (CB)" in out
    with pytest.raises(SystemExit) as exit_info:
        compare.main([str(a), "--against", "langevin n=8"])
    assert exit_info.value.code == 2
    assert "no row 'langevin n=8' to compare against; rows: dmo n=8 R=1, gd n=8" in capsys.readouterr().err

    compare.main([str(a), "--rows", "gd n=8, dmo n=8 R=1"])
    out = capsys.readouterr().out
    assert out.index("| gd n=8 | 33 |") < out.index("| dmo n=8 R=1 | 67 |")
    with pytest.raises(SystemExit):
        compare.main([str(a), "--rows", "dmo n=8 R=1,dfo n=8"])
    assert "no row 'dfo n=8' in these files; rows: dmo n=8 R=1, gd n=8" in capsys.readouterr().err


def test_networks_trained_with_other_settings_get_rows_of_their_own(tmp_path):
    scenes = [1, 0, 1, 0]
    plain = _evaluation(tmp_path / "plain.json", [("sort", "reach_target", scenes)])
    other = tmp_path / "other.json"
    payload = json.loads(_evaluation(other, [("sort", "reach_target", scenes)]).read_text())
    payload["settings"].update({"recipe": "paper", "set": ["lr=0.001", "depth_cue=true"]})
    other.write_text(json.dumps(payload))
    assert list(load_evaluations([plain, other])) == ["sort n=8", "sort n=8 (depth cue) {lr=0.001}"]
    # a result's own settings name its row (bin/reproduce's tables hold several networks per file)
    mixed = tmp_path / "mixed.json"
    payload = json.loads(_evaluation(mixed, [("dmo", "reach_target", scenes)] * 3).read_text())
    for result, own in zip(payload["results"], ({}, {"variant": "wo_concat"}, {"negatives": "only-vae"})):
        result["settings"] = own
    mixed.write_text(json.dumps(payload))
    assert list(load_evaluations([mixed])) == ["dmo n=8 R=1", "dmo n=8 R=1 (wo_concat)",
                                               "dmo n=8 R=1 (only-vae negatives)"]
    # a DMO is named by its inputs, a head by its depth cue, an EBM by its mined negatives, only
    # where they are not the recipe's own (both recipes: decoded inputs; bank: the cue with the
    # concat variant, and mined negatives)
    from dmo_jax.comparison import row_label

    dmo = {"method": "dmo", "n": 8, "R": 1}
    bank = {"recipe": "bank", "depth_cue": True, "ebm_mined_steps": 200}
    assert row_label(dmo, bank) == row_label(dmo, {**bank, "dmo_inputs": "decoded"}) == "dmo n=8 R=1 [bank]"
    assert row_label(dmo, {**bank, "dmo_inputs": "offset"}) == "dmo n=8 R=1 (inputs offset) [bank]"
    assert row_label(dmo, {"dmo_inputs": "offset"}) == "dmo n=8 R=1 (inputs offset)"
    assert row_label(dmo, {**bank, "depth_cue": False}) == "dmo n=8 R=1 (no depth cue) [bank]"
    assert row_label(dmo, {**bank, "variant": "gap", "depth_cue": False}) == "dmo n=8 R=1 (gap) [bank]"
    assert row_label(dmo, {**bank, "ebm_mined_steps": 0}) == "dmo n=8 R=1 (no mined negatives) [bank]"
    assert row_label(dmo, {"ebm_mined_steps": 80}) == "dmo n=8 R=1 (mined negatives)"
    # files older than the fields: the cue was on only where set, and no EBM was mined
    assert row_label(dmo, {"recipe": "bank", "ebm_mined_steps": 200}) == "dmo n=8 R=1 (no depth cue) [bank]"
    assert row_label(dmo, {"recipe": "bank", "set": ["head.depth_cue=true"], "ebm_mined_steps": 200}) == \
        "dmo n=8 R=1 [bank]"
    assert row_label(dmo, {"recipe": "bank", "depth_cue": True}) == "dmo n=8 R=1 (no mined negatives) [bank]"
    # a DMO ranked by a selection head is named by the head's training scenes (recorded, or the
    # --set item in files older than the field) and the parts of the motion it reads (files older
    # than that field: the mean over the whole motion); sort is not ranked by it, so it shares the energy's row
    sort = {"method": "sort", "n": 8, "R": None}
    assert row_label(dmo, {**bank, "selection_scenes": 300, "selection_phases": 8}) == \
        "dmo n=8 R=1 (selection head 300, 8 phases) [bank]"
    assert row_label(dmo, {**bank, "selection_scenes": 300}) == "dmo n=8 R=1 (selection head 300) [bank]"
    assert row_label(dmo, {**bank, "set": ["selection_scenes=100"]}) == "dmo n=8 R=1 (selection head 100) [bank]"
    assert row_label(dmo, {**bank, "selection_scenes": 0}) == "dmo n=8 R=1 [bank]"
    assert row_label(sort, {**bank, "selection_scenes": 300}) == row_label(sort, bank) == "sort n=8 [bank]"
    # two-stage scorings measured to choose what the full one chooses share its row; others do not
    assert row_label({**dmo, "coarse": [6, 32]}, bank) == row_label({**dmo, "coarse": [6, 64]}, bank) == \
        row_label({**dmo, "coarse": [4, 64]}, bank) == row_label({**dmo, "coarse": None}, bank) == "dmo n=8 R=1 [bank]"
    assert row_label({**dmo, "coarse": [8, 64]}, bank) == "dmo n=8 R=1 (coarse 8/64) [bank]"
    # networks of two image sizes never share a row: the size is recorded, set, or (files older
    # than the field) the one the file's preset had then
    sized = row_label(dmo, {**bank, "preset": "cpu", "image_size": 96, "set": ["dmo_batch=12"]})
    assert sized == "dmo n=8 R=1 [bank] {dmo_batch=12, image_size=96}"
    assert row_label(dmo, {**bank, "preset": "cpu", "set": ["dmo_batch=12", "preset.image_size=96"]}) == sized
    assert row_label(dmo, {**bank, "preset": "cpu", "set": ["dmo_batch=12"]}) == \
        "dmo n=8 R=1 [bank] {dmo_batch=12, image_size=64}"


def test_distances_of_the_first_ranked_motions_are_tabled_per_row(tmp_path, capsys):
    path = _evaluation(tmp_path / "a.json", [("dmo", "reach_target", [1, 0]), ("sort", "reach_target", [0, 0])])
    payload = json.loads(path.read_text())
    payload["results"][0].update(first_error_m=0.0123, first_depth_error_m=0.004)
    path.write_text(json.dumps(payload))
    compare.main([str(path)])
    table = capsys.readouterr().out.split("first-ranked motion's distance")[1]
    assert "| dmo n=8 R=1 | 1.2 (0.4) |" in table and "sort" not in table  # sort has no distances here


def test_what_the_choice_among_candidates_costs_is_tabled_per_row(tmp_path, capsys):
    path = _evaluation(tmp_path / "a.json", [("dmo", "reach_target", [1, 0]), ("sort", "reach_target", [0, 0])])
    payload = json.loads(path.read_text())  # bin/evaluate --each-candidate
    payload["results"][0].update(some_candidate_solves=1.0, some_start_solves=0.5, start_success_rate=0.25,
                                 optimised_success_rate=0.5)
    path.write_text(json.dumps(payload))
    compare.main([str(path)])
    out = capsys.readouterr().out
    chosen, alone = out.split("| chosen / best start / best candidate, % | RT |")[1].split("succeeds alone")
    assert "| dmo n=8 R=1 | 50 / 50 / 100 |" in chosen and "| dmo n=8 R=1 | 25 / 50 |" in alone
    assert "sort" not in chosen + alone  # sort's candidates were not executed alone here
    assert "by its distance from the demonstration" not in out  # recorded by newer files only


def test_candidate_success_by_distance_from_the_demonstration_is_counted_and_tabled(tmp_path, capsys):
    from dmo_jax.evaluation import candidate_outcomes

    # two scenes x three candidates: 0.4, 0.7, 2.5 cm and 0.9, 1.2, 40 cm from the demonstration
    errors = np.array([[0.004, 0.007, 0.025], [0.009, 0.012, 0.4]])
    success = np.array([[1, 0, 0], [0, 1, 1]], bool)
    out = candidate_outcomes(success, np.ones_like(success), np.zeros(errors.shape), errors)
    assert out["nearest_candidate_solves"] == 0.5  # the 0.4 cm one solves, the 0.9 cm one does not
    assert [(b["from_m"], b["to_m"], b["candidates"], b["success_rate"]) for b in out["success_by_error"]] == [
        (0.0, 0.005, 1, 1.0), (0.005, 0.01, 2, 0.0), (0.01, 0.015, 1, 1.0), (0.015, 0.02, 0, None),
        (0.02, 0.03, 1, 0.0), (0.03, None, 1, 1.0)]
    assert out["candidate_error_m"] == errors.tolist()
    path = _evaluation(tmp_path / "a.json", [("dmo", "reach_target", [1, 1])])
    payload = json.loads(path.read_text())
    payload["results"][0].update({k: v for k, v in out.items() if not k.startswith("candidate_")})
    path.write_text(json.dumps(payload))
    compare.main([str(path)])
    table = capsys.readouterr().out.split("by its distance from the demonstration | RT |")[1]
    assert "| 0–0.5 cm | 100 (1) |" in table and "| 0.5–1 cm | 0 (2) |" in table and "| 1.5–2 cm | – |" in table
    assert "| ≥ 3 cm | 100 (1) |" in table and "| the candidate nearest the demonstration solves its scene | 50 |" in table
