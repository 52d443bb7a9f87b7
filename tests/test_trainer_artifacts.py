"""Running a Rainbow trainer never touches the committed models: with its default flags a run writes only
under runs/<exp_name>__<seed>__<unix time>/ (checkpoint, export, JSON, TensorBoard), a fresh folder each time.

Each trainer runs as a user would, from a copy of the repository (its scripts, maps/ and models/), for a few
steps; models/ must be byte-identical afterwards.
"""
from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
TINY = ["--total-steps", "64", "--num-envs", "2", "--learning-starts", "32", "--buffer-size", "2000",
        "--eval-every", "0", "--threads", "1"]


@pytest.fixture(scope="module")
def repo(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("repo")
    for script in ROOT.glob("*.py"):
        shutil.copy(script, root)
    shutil.copytree(ROOT / "maps", root / "maps")
    shutil.copytree(ROOT / "models", root / "models")
    return root


def hashes(folder: Path) -> dict:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def train(repo: Path, script: str, *flags: str) -> Path:
    """Run a trainer from the copy; returns the one run folder it made."""
    before = set((repo / "runs").iterdir()) if (repo / "runs").exists() else set()
    result = subprocess.run([sys.executable, f"{script}.py", *TINY, *flags], cwd=repo, capture_output=True, text=True,
                            env={**os.environ, "OMP_NUM_THREADS": "1"}, timeout=300)
    assert result.returncode == 0, result.stderr
    made = set((repo / "runs").iterdir()) - before
    assert len(made) == 1, made
    return made.pop()


def check_run(run: Path, script: str) -> dict:
    assert re.fullmatch(rf"{script}__1__\d+", run.name)
    assert (run / "checkpoint.pt").stat().st_size > 0 and (run / f"{script}.pt").stat().st_size > 0
    assert any(p.name.startswith("events.out.tfevents") for p in run.iterdir())
    info = json.loads((run / f"{script}.json").read_text())
    assert info["args"]["run_name"] == run.name and info["args"]["export"] == f"runs/{run.name}/{script}.pt"
    assert info["global_step"] == 64 and info["provenance"]["env_steps"] == 64
    return info


def test_rainbow_cpp_writes_only_under_a_new_run_folder(repo):
    shipped = hashes(ROOT / "models")
    first = train(repo, "rainbow_cpp", "--hidden", "16")
    second = train(repo, "rainbow_cpp", "--hidden", "16")
    assert first.name != second.name  # unique by default, as CleanRL's run names
    for run in (first, second):
        check_run(run, "rainbow_cpp")
    assert hashes(repo / "models") == shipped


def test_rainbow_marl_with_default_flags_starts_from_the_shipped_model(repo):
    """The default --init-from models/rainbow_cpp.pt sets the width (no --hidden given)."""
    shipped = hashes(ROOT / "models")
    info = check_run(train(repo, "rainbow_marl"), "rainbow_marl")
    parent = json.loads((ROOT / "models" / "rainbow_cpp.json").read_text())
    assert info["args"]["hidden"] == parent["args"]["hidden"] == info["network"]["hidden"]
    assert info["parent"]["path"] == "models/rainbow_cpp.pt"
    assert info["parent"]["sha256"] == shipped["rainbow_cpp.pt"]
    assert info["parent"]["global_step"] == parent["global_step"]
    assert hashes(repo / "models") == shipped
