"""The shape of the repo the design card promises: the world's class holds its state and rules only."""
import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_the_world_class_holds_state_and_rules_only():
    tree = ast.parse((ROOT / "gridworld.py").read_text())
    core = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "GridWorldCore")
    assert core.end_lineno - core.lineno + 1 <= 700
    methods = {n.name for n in core.body if isinstance(n, ast.FunctionDef)}
    assert {"reset", "step", "observe", "_reward"} <= methods
    assert not methods & {"heuristic_actions", "rollout_actions", "team_rollout_actions", "render_rgb", "_draw_maps"}
    functions = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}
    assert {"heuristic_actions", "rollout_actions", "team_rollout_actions", "draw_maps", "render_rgb"} <= functions
