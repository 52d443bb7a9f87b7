"""The shipped models keep their scores: re-scored here on a fixed slice of their evaluation sets, they match what
results/ records (a refactor of the trainers, the world or evaluate.py that changed a single move would show)."""
import json
from pathlib import Path

import numpy as np
import pytest

import classical_cpp
import evaluate

ROOT = Path(__file__).resolve().parent.parent


def test_the_shipped_single_agent_model_scores_on_the_movingai_maps_as_results_say():
    """models/rainbow_cpp.pt with its fallback on the nine MovingAI maps from their reference starts (27 episodes):
    every episode's overlap as results/rainbow_cpp.json's `external` holds it."""
    recorded = json.loads((ROOT / "results" / "rainbow_cpp.json").read_text())["external"]
    rows = evaluate.run_rainbow(evaluate.Args(policy="rainbow", checkpoint=str(ROOT / "models" / "rainbow_cpp.pt"),
                                              quiet=True), classical_cpp.external_episodes())
    scored: dict[str, list[float]] = {}
    for row in rows:
        scored.setdefault(row["map"], []).append(row["overlap"])
    assert scored.keys() == recorded.keys()
    for name, overlaps in recorded.items():
        assert scored[name] == pytest.approx(overlaps, abs=1e-6), name


def test_the_shipped_team_model_scores_on_marl_eval_as_results_say():
    """models/rainbow_marl.pt with two agents on report.py's first batch of marl_eval layouts (64 episodes, sizes
    10-16): the mean time-save factor of each size it holds whole (10-15) as results/rainbow_marl.json has it."""
    recorded = json.loads((ROOT / "results" / "rainbow_marl.json").read_text())
    scenarios, sizes = classical_cpp.marl_eval_subset(2, recorded["every"])
    episodes = [(f"marl_eval.npz[{z}x{z}]", s) for s, z in zip(scenarios[:64], sizes[:64])]
    rows = evaluate.run_marl(evaluate.Args(policy="marl", checkpoint=str(ROOT / "models" / "rainbow_marl.pt"),
                                           agents=2, quiet=True), episodes)
    for size in range(10, 16):
        time_save = [r["time_save"] for r, z in zip(rows, sizes[:64]) if z == size]
        assert round(float(np.mean(time_save)), 4) == recorded["agents"]["2"]["by_size"][str(size)], size
