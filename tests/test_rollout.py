"""Tests for the rollout planner (classical_cpp.rollout_many) and its world-copy primitive
(GridWorldCore.copy_worlds).

copy_worlds: a copied world steps exactly as its original (observations, events, metrics) for every
sensor and several agents, other worlds are left alone, and every per-world array is copied.
rollout: never longer than its base, strictly shorter where the base must walk back to a hole,
legal and complete (classical_cpp.replay), deterministic and independent of the batch.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from conftest import from_rows  # noqa: E402

import classical_cpp as cc  # noqa: E402
import gridworld as gw  # noqa: E402


def random_maps(n: int, agents: int = 1, seed: int = 0) -> list[gw.Scenario]:
    """n connected random maps of 4x4 to 8x8 with 0-12 obstacles."""
    rng = np.random.default_rng(seed)
    maps = []
    while len(maps) < n:
        size = int(rng.integers(4, 9))
        (s,) = gw.generate_scenarios(1, seed=int(rng.integers(1 << 30)), size=size, number_agents=agents,
                                     number_obstacles=int(rng.integers(0, 13)), obstacles_random=True)
        maps.append(cc.with_starts(gw.Scenario(s.obstacles, s.starts)))
    return maps


def steps(scenarios, paths) -> np.ndarray:
    return np.array([cc.replay(s, p)["steps"] for s, p in zip(scenarios, paths)])


# ----------------------------------------------------------------------------- copy_worlds
def _state(core: gw.GridWorldCore, w: int) -> dict:
    """Everything observable about world w: both observations, the agents' cells and the metrics."""
    obs = core.observe()
    out = {k: v[w].copy() for k, v in obs.items()}
    out["tabular"] = core.observe_tabular()[w]
    out["cells"] = core.agent_cells()[w]
    out.update({f"metric_{k}": v[w] for k, v in core.metrics().items()})
    return out


def _assert_same(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


@pytest.mark.parametrize("sensor", gw.SENSORS)
@pytest.mark.parametrize("agents", [1, 3])
def test_copied_worlds_step_as_their_originals(sensor, agents):
    B, src, dst = 7, np.array([0, 1, 2]), np.array([4, 6, 1])  # 1 is copied from and into at once
    cfg = gw.EnvConfig(size=12, random_size=True, min_size=6, number_obstacles=15, obstacles_random=True,
                       number_agents=agents, sensor=sensor, view_size=9, random_coverage=True,
                       reward=gw.RewardParams(finished_line=1.0, wall_adjacent=1.0, repeated_action=-0.5))
    core = gw.GridWorldCore(cfg, B, seed=3)
    core.reset()
    rng = np.random.default_rng(0)
    for _ in range(6):  # some history: coverage, sensed cells, last actions, battery
        core.step(rng.integers(0, 5, (B, agents)))
    before = {w: _state(core, w) for w in range(B)}
    core.copy_worlds(src, dst)
    for w in set(range(B)) - set(dst):  # the other worlds are left alone
        _assert_same(_state(core, w), before[w])
    for s, d in zip(src, dst):  # world 6 gets world 1's state from before world 1 was overwritten
        _assert_same(_state(core, d), before[s])
    pairs = [(0, 4), (2, 1)]  # originals still alive and their copies
    for _ in range(25):
        a = rng.integers(0, 5, (B, agents))
        for s, d in pairs:
            a[d] = a[s]
        events = core.step(a)
        for s, d in pairs:
            for k, v in events.items():
                np.testing.assert_array_equal(v[s], v[d], err_msg=k)
            _assert_same(_state(core, s), _state(core, d))


def test_copy_from_another_core_and_bad_input():
    cfg = gw.EnvConfig(size=8, number_obstacles=6, obstacles_random=True, number_agents=2)
    a, b = gw.GridWorldCore(cfg, 3, seed=1), gw.GridWorldCore(cfg, 2, seed=2)
    a.reset()
    b.reset()
    a.step(np.ones((3, 2), np.int64))
    b.copy_worlds([2, 0], [0, 1], source=a)
    for w_a, w_b in ((2, 0), (0, 1)):
        _assert_same(_state(a, w_a), _state(b, w_b))
    actions = np.random.default_rng(0).integers(0, 5, (3, 2))
    ea, eb = a.step(actions), b.step(actions[[2, 0]])
    for k in ea:
        np.testing.assert_array_equal(ea[k][[2, 0]], eb[k], err_msg=k)
    _assert_same(_state(a, 2), _state(b, 0))
    with pytest.raises(ValueError, match="distinct destination"):
        a.copy_worlds([0, 1], [2, 2])
    with pytest.raises(ValueError, match="distinct destination"):
        a.copy_worlds([0, 1], [2])
    other = gw.GridWorldCore(cfg.replace(size=9), 2)
    with pytest.raises(ValueError, match="geometry"):
        other.copy_worlds([0], [1], source=a)


def test_copy_worlds_knows_every_per_world_array():
    """A new per-world array (leading axis B) must be added to WORLD_ARRAYS, or copies would share it."""
    B = 7
    core = gw.GridWorldCore(gw.EnvConfig(size=6, number_agents=2, sensor="camera"), B)
    core.reset()
    core.step(np.zeros((B, 2), np.int64))
    per_world = {k for k, v in vars(core).items()
                 if isinstance(v, np.ndarray) and v.ndim and v.shape[0] == B and k not in ("canvas32",)}
    assert per_world <= set(gw.GridWorldCore.WORLD_ARRAYS), per_world - set(gw.GridWorldCore.WORLD_ARRAYS)


# ----------------------------------------------------------------------------- rollout
def test_rollout_never_worse_than_its_base_and_replays():
    maps = random_maps(30)
    base = steps(maps, cc.plan("greedy-dead-ends", maps))
    paths = cc.plan("rollout", maps)
    got = steps(maps, paths)  # replay raises unless every path is legal and covers the map
    assert (got <= base).all(), np.flatnonzero(got > base)
    assert got.sum() < base.sum()
    # each map alone plans the same path: maps do not interact in the batch; and plans are repeatable
    for i in (0, 7, 29):
        (alone,) = cc.plan("rollout", [maps[i]])
        np.testing.assert_array_equal(alone[0], paths[i][0])
    again = cc.plan("rollout", maps)
    assert all((p[0] == q[0]).all() for p, q in zip(paths, again))


# The start 0 splits the map into a dead-end branch West, (0,1) (0,0) (1,0), and a loop East,
# (0,3) (1,3) (1,2). Greedy-dead-ends sees three nearest cells with one uncovered neighbour each,
# takes the first in row-major order, (0,1), runs down the branch to (1,0) and leaves the loop
# behind: it walks back through (0,0) (0,1) (0,2) (4 steps, 3 wasted) to (0,3), then (1,3) (1,2):
# 9 steps for 6 cells. The loop first costs 3 steps round it, 1 back to the start, 3 down the branch:
# 7, the optimum (whichever side comes first is walked back through the start, the loop for 1 step).
HOLE = ["..0.",
        ".@.."]


def test_rollout_fills_the_hole_greedy_leaves():
    s = from_rows(HOLE)
    (greedy,) = cc.plan("greedy-dead-ends", [s])
    np.testing.assert_array_equal(greedy[0], [[0, 2], [0, 1], [0, 0], [1, 0], [0, 0], [0, 1], [0, 2],
                                              [0, 3], [1, 3], [1, 2]])
    (paths,) = cc.plan("rollout", [s])
    np.testing.assert_array_equal(paths[0], [[0, 2], [1, 2], [1, 3], [0, 3], [0, 2], [0, 1], [0, 0], [1, 0]])
    g, r = cc.replay(s, greedy), cc.replay(s, paths)
    assert (g["steps"], g["revisits"], r["steps"], r["revisits"]) == (9, 3, 7, 1)
    assert r["overlap"] == pytest.approx(1 / 6) and g["overlap"] == pytest.approx(0.5)


def test_rollout_bases_and_merging_do_not_change_the_plan():
    """A base without the `markov` mark (no state merging) plans the same paths, only slower; the
    plain greedy base works too and is never beaten by its own rollout's absence."""
    maps = random_maps(12, seed=5)
    merged = cc.rollout_many(maps)
    plain = cc.rollout_many(maps, base=lambda core: gw.heuristic_actions(core, random_ties=False, dead_ends_first=True))
    assert all((p[0] == q[0]).all() for p, q in zip(merged, plain))
    greedy = steps(maps, cc.plan("greedy", maps))
    on_greedy = steps(maps, cc.plan("rollout", maps, rollout_base="greedy"))
    assert (on_greedy <= greedy).all()
    far_first = steps(maps, cc.plan("greedy-far-first", maps))
    assert (steps(maps, cc.plan("rollout", maps, rollout_base="greedy-far-first")) <= far_first).all()


def test_the_planner_and_rollout_many_find_the_same_costs():
    """plan("rollout") walks with the teacher's rollout_actions, rollout_many with copies of the core: both take a
    cheapest move, so they differ at most where two moves cost the same; on these maps they never do."""
    maps = random_maps(12, seed=2)
    assert steps(maps, cc.plan("rollout", maps)).tolist() == steps(maps, cc.rollout_many(maps)).tolist()


def test_multiagent_rollout_never_worse():
    maps = random_maps(8, agents=2, seed=2) + random_maps(4, agents=3, seed=3)
    base = steps(maps, cc.plan("greedy-dead-ends", maps))
    got = steps(maps, cc.plan("rollout", maps))
    assert (got <= base).all(), (got, base)


def test_rollout_edge_cases():
    tiny = from_rows(["0."])
    (paths,) = cc.plan("rollout", [tiny])
    np.testing.assert_array_equal(paths[0], [[0, 0], [0, 1]])
    assert cc.plan("rollout", []) == []
    with pytest.raises(ValueError, match="rollout base"):
        cc.plan("rollout", [tiny], rollout_base="lkh")
    with pytest.raises(ValueError):  # gridworld's checks: a start on an obstacle
        cc.plan("rollout", [gw.Scenario(np.array([[True, False]]), np.array([[0, 0]]))])


def test_cli_rollout(tmp_path):
    out = tmp_path / "rows.jsonl"
    result = subprocess.run([sys.executable, "classical_cpp.py", "--planner", "rollout", "--rollout-base", "greedy",
                             "--maps", "maps/external/empty-8-8.map", "--out", str(out), "--quiet"],
                            cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "rollout: 1 scenario(s)" in result.stdout and out.read_text().count("\n") == 1
    bad = subprocess.run([sys.executable, "classical_cpp.py", "--planner", "rollout", "--rollout-base", "nope",
                          "--maps", "maps/external/empty-8-8.map"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert bad.returncode != 0 and "rollout base" in bad.stderr and "Traceback" not in bad.stderr
