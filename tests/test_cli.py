"""The world's commands, run as a user runs them."""
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _run(*args):
    proc = subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    return proc


def test_render_writes_rgb_beside_depth(tmp_path):
    out = tmp_path / "front.png"
    proc = _run("bin/render", "--out", str(out), "--size", "64")
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    assert width >= 2 * 256 and height >= 256  # legible at any --size: two 256-px panels and a colour bar
    assert re.search(r"colour bar \d+\.\d\d-\d+\.\d\d m", proc.stdout)


def test_execute_runs_a_motion_file(tmp_path):
    motion, out = tmp_path / "m.npy", tmp_path / "r.json"
    _run("bin/execute", "--backend", "mujoco", "--save-motion", str(motion))
    assert np.load(motion).shape == (101, 11)
    proc = _run("bin/execute", "--backend", "mujoco", "--motion", str(motion), "--json", str(out))
    assert json.loads(out.read_text()) == {"success": True, "failed_waypoints": 0, "abandoned": False}
    assert len([line for line in proc.stdout.splitlines() if line.strip()[:1].isdigit()]) == 101


def test_commands_started_by_another_python_run_in_the_project_environment():
    import os

    base = Path(sys.base_prefix) / "bin" / "python3"  # the interpreter the environment was made from
    env = {**os.environ, "DMO_VENV": sys.prefix}
    proc = subprocess.run([str(base), "bin/compare", "--help"], cwd=ROOT, capture_output=True, text=True, env=env,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("usage: compare")
    for script in ("bin/demo", "bin/setup"):  # --help prints help and does nothing else
        proc = subprocess.run([script, "--help"], cwd=ROOT, capture_output=True, text=True, timeout=60)
        assert proc.returncode == 0 and proc.stdout.strip() and not proc.stderr


def test_every_command_help_describes_every_option_and_writes_nothing(tmp_path, monkeypatch, capsys):
    import argparse

    from dmo_jax.commands import benchmark, compare, cost, ebm_misses, evaluate, reproduce, train_all
    from envs.commands import execute, generate_data, render, task_report

    commands = {module.__name__.rsplit(".", 1)[1]: module.main
                for module in (benchmark, compare, cost, ebm_misses, evaluate, reproduce, train_all, execute,
                               generate_data, render, task_report)}
    assert set(commands) | {"demo", "setup", "test"} == {p.name for p in (ROOT / "bin").iterdir()
                                                        if p.is_file() and not p.name.startswith("_")}
    monkeypatch.chdir(tmp_path)
    real = argparse.ArgumentParser.parse_args
    for name, main in commands.items():
        parsers = []
        monkeypatch.setattr(argparse.ArgumentParser, "parse_args",
                            lambda self, *a, **k: (parsers.append(self), real(self, *a, **k))[1])
        with pytest.raises(SystemExit) as exit_info:
            main(["--help"])
        assert exit_info.value.code == 0 and capsys.readouterr().out.startswith("usage: "), name
        undescribed = [a.option_strings for a in parsers[0]._actions if a.option_strings and not a.help]
        assert not undescribed, f"{name}: options without help: {undescribed}"
    assert not list(tmp_path.iterdir())


def test_progress_off_a_terminal_prints_a_line_per_quarter_of_the_work(capsys):
    from envs.progress import Progress

    progress = Progress("train ebm", 500, initial=100)
    for done in range(101, 501):
        progress.update(done, f"loss {1 / done:.4f}")
    progress.close()
    lines = capsys.readouterr().err.splitlines()
    assert [line.split(" (")[0] for line in lines] == [f"train ebm: {n}/500" for n in (125, 250, 375, 500)]
    assert lines[-1].endswith("loss 0.0020")
