"""Tests for the rollout's mirrored and turned copies (gw.rollout_actions(GridWorldCore, symmetries=k)).

The 8 symmetries move boards, cells and moves alike; a move's cost is its mean over the copies, each copy a world
built from the mirrored map; the mean over all 8 does not depend on how the world is turned; bad counts are refused.
"""
from __future__ import annotations

import numpy as np
import pytest

import gridworld as gw


def world(scenarios: list[gw.Scenario]) -> gw.GridWorldCore:
    core = gw.GridWorldCore(gw.EnvConfig(load_state=True, load_random=False, battery_factor=1e6), len(scenarios))
    core.configure(scenarios=scenarios)
    core.reset()
    return core


def states(seed: int, worlds: int = 6, size: int = 9) -> list[gw.Scenario]:
    """Part-covered rooms maps, each with its agent's cell as the start (the far-first reference)."""
    core = gw.GridWorldCore(gw.EnvConfig(size=size, map_family="rooms", number_obstacles=12, obstacles_random=True,
                                         battery_factor=1e6), worlds, seed=seed)
    core.reset()
    for _ in range(size):
        core.step(gw.heuristic_actions(core, random_ties=False, dead_ends_first=True, far_first=True))
    c, H, W = core.c, core.H, core.W
    return [gw.Scenario(core.obstacle[b, c:c + H, c:c + W].copy(), core.agent_cells()[b], core.covered[b, c:c + H,
                                                                                                     c:c + W].copy())
            for b in range(worlds)]


def turned(s: gw.Scenario, k: int) -> gw.Scenario:
    H, W = s.obstacles.shape
    return gw.Scenario(gw._symmetric(s.obstacles, k), gw._symmetric_cells(s.starts, k, H, W),
                       gw._symmetric(s.covered, k))


@pytest.mark.parametrize("k", range(8))
def test_symmetries_move_boards_cells_and_moves_alike(k):
    board = np.arange(20).reshape(4, 5)
    cells = np.array([[0, 0], [1, 3], [3, 4]])
    moved = gw._symmetric_cells(cells, k, 4, 5)
    assert (gw._symmetric(board, k)[moved[:, 0], moved[:, 1]] == board[cells[:, 0], cells[:, 1]]).all()
    assert gw._symmetric(board, k).shape == ((4, 5) if k in (0, 2, 5, 7) else (5, 4))
    for a, delta in enumerate(gw.ACTION_DELTAS[:4]):  # the cell one move away stays one (moved) move away
        there = gw._symmetric_cells(cells[1:2] + delta, k, 4, 5) - moved[1]
        assert (there[0] == gw.ACTION_DELTAS[gw._symmetric_moves(k)[a]]).all()
    assert sorted(gw._symmetric_moves(k)) == [0, 1, 2, 3]


def test_costs_are_the_mean_over_worlds_built_from_the_mirrored_maps():
    scenarios = states(seed=4)
    action, mean = gw.rollout_actions(world(scenarios), far_first=True, costs=True, symmetries=8)
    copies = []
    for k in range(8):
        _, cost = gw.rollout_actions(world([turned(s, k) for s in scenarios]), far_first=True, costs=True)
        copies.append(cost[:, gw._symmetric_moves(k)])
    assert np.allclose(mean, np.mean(copies, 0))
    own = gw.heuristic_actions(world(scenarios), random_ties=False, dead_ends_first=True, far_first=True)[:, 0]
    rows = np.arange(len(action))
    safe = (copies[0] >= 0) & (copies[0] <= copies[0][rows, own][:, None])  # no dearer than its move in the world
    decided = (mean >= 0).sum(1) >= 2
    cheapest = np.where(safe, mean, np.inf).min(1)
    assert (mean[rows, action][decided] == cheapest[decided]).all() and safe[rows, action][decided].all()
    four = gw.rollout_actions(world(scenarios), far_first=True, costs=True, symmetries=4)[1]
    assert np.allclose(four, np.mean(copies[:4], 0))


@pytest.mark.parametrize("family", ["random", "maze"])
def test_walks_by_the_mean_are_never_longer_than_the_heuristics(family):
    """Each step shortens the heuristic's own steps to the end, so every map is covered within them."""
    config = gw.EnvConfig(size=10, min_size=6, random_size=True, map_family=family, number_obstacles=15,
                          obstacles_random=True, battery_factor=1e6)
    steps = []
    for rule in ("heuristic", "mean"):
        core = gw.GridWorldCore(config, 8, seed=21)
        core.reset()
        taken = np.zeros(core.B, np.int64)
        while (core.remaining > 0).any():
            live = core.remaining > 0
            move = (gw.rollout_actions(core, far_first=True, symmetries=4) if rule == "mean" else
                    gw.heuristic_actions(core, random_ties=False, dead_ends_first=True, far_first=True)[:, 0])
            core.step(np.where(live, move, gw.WAIT)[:, None])
            taken += live
            assert taken.max() <= 4 * 100
        steps.append(taken)
    assert (steps[1] <= steps[0]).all()


def test_the_mean_over_all_eight_does_not_depend_on_the_turn():
    scenarios = states(seed=11)
    _, mean = gw.rollout_actions(world(scenarios), far_first=True, costs=True, symmetries=8)
    for k in (1, 4, 6):
        _, other = gw.rollout_actions(world([turned(s, k) for s in scenarios]), far_first=True, costs=True,
                                                                              symmetries=8)
        assert np.allclose(other[:, gw._symmetric_moves(k)], mean)


def test_bad_symmetry_counts():
    core = world(states(seed=2, worlds=2))
    for bad in (0, 3, 16):
        with pytest.raises(ValueError, match="symmetries"):
            gw.rollout_actions(core, symmetries=bad)
    oblong = world([gw.Scenario(np.zeros((2, 3), bool), np.array([[0, 0]]))])  # sits in a square world
    action, cost = gw.rollout_actions(oblong, costs=True, symmetries=8)
    assert cost[0, 0] == cost[0, 2] == -1 and action[0] in (1, 3)  # N and W leave the map
