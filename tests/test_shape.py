"""The shape of the repo the design card promises: the world's class holds its state and rules only, and each
trainer reads in one sitting."""
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


def test_each_trainer_is_read_in_one_sitting():
    """Issue 45: a trainer is at most 1,000 lines, its run files, logging and evaluation loop in gridworld."""
    for script in ("rainbow_cpp.py", "rainbow_marl.py"):
        source = (ROOT / script).read_text()
        assert len(source.splitlines()) <= 1000, script
        names = {n.name for n in ast.parse(source).body if isinstance(n, (ast.FunctionDef, ast.ClassDef))}
        assert {"Args", "QNetwork", "Replay", "learn", "evaluate_policy", "main"} <= names, script
