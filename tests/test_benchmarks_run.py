"""Every benchmark runs: each script of benchmarks/ for a few steps through its own small flags, as a subprocess in
a temporary folder, so that a broken benchmark fails the build (issue 44). cpu.py is the pinning helper the others
import.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
TESTED_ELSEWHERE = {"cpu.py"}
TINY = {  # each ~2-15 s on one core; --cpu -1: the first CPU this process may use (CPU 0 may not be one)
    "learning_rate.py": ["--rates", "5e-4", "--stage-steps-scale", "0.0001", "--eval-every", "64", "--eval-maps", "2",
                         "--out", "lr.json"],
    "recipe_speed.py": ["--steps", "32", "--learning-starts", "32", "--buffer-size", "1024"],
    "rainbow_sps.py": ["--steps", "16", "--learning-starts", "32", "--hidden", "16", "--size", "6", "--num-envs", "2"],
    "rollout_planner.py": ["--per-size", "1", "--sizes", "5", "--external-maps", "empty-8-8.map", "--cpu", "-1"],
    "team_rollout.py": ["--agents", "2", "--marl-every", "5000", "--structured-every", "0", "--cpu", "-1"],
    "train_speed.py": ["--quick", "--threads", "1", "--no-cuda", "--no-sb3", "--batch-sizes", "32",
                       "--replay-ratios", "4", "--learning-starts", "32", "--size", "6", "--steps", "16", "--repeats",
                       "1", "--json", "rows.json"],
}


def git_status() -> str:
    return subprocess.run(["git", "status", "--porcelain", "--untracked-files=all"], cwd=ROOT, capture_output=True,
                          text=True, check=True).stdout


def test_every_benchmark_is_run_here():
    scripts = {p.name for p in (ROOT / "benchmarks").glob("*.py")}
    assert scripts - TESTED_ELSEWHERE == set(TINY), "a new benchmark needs its small flags in TINY"


@pytest.mark.parametrize("script", sorted(TINY))
def test_benchmark_runs(tmp_path, script):
    before = git_status()
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONDONTWRITEBYTECODE": "1"}
    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / script), *TINY[script]], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=180)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "Traceback" not in done.stderr and done.stdout.strip(), done.stderr[-3000:]
    assert git_status() == before  # nothing under the repository: the outputs went to the temporary folder


def test_the_learning_rate_sweep_of_the_team_trainer_records_its_time_save(tmp_path):
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONDONTWRITEBYTECODE": "1"}
    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "learning_rate.py"), "--trainer", "rainbow_marl",
                           *TINY["learning_rate.py"]], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=180)
    assert done.returncode == 0, done.stderr[-3000:]
    sweep = json.loads((tmp_path / "lr.json").read_text())
    rate = sweep["rates"]["0.0005"]
    assert sweep["trainer"] == "rainbow_marl" and "--init-from" in sweep["flags"]  # from scratch
    assert rate["time_save"] and len(rate["time_save"]) == len(rate["heuristic_time_save"])
