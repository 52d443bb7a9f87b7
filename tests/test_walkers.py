"""Tests for the rollouts' lean walkers (gridworld._Walkers, _path_tables, gridworld._path_tables_of).

The walkers must take exactly the deterministic heuristic's moves (gridworld.heuristic_actions with
random_ties=False, one agent, full view), by neighbour, by breadth-first search and by the shortest-path tables; a
hand-made map checks the tables' distances and first cells; the cache keeps one table per map and respects its byte
budget.
"""
from __future__ import annotations

import numpy as np
import pytest

import gridworld as gw


def mid_episode(family: str, size: int, seed: int, worlds: int = 12) -> gw.GridWorldCore:
    """Worlds part-walked by a mix of random moves and the heuristic's (states a learner visits)."""
    rng = np.random.default_rng(seed)
    core = gw.GridWorldCore(gw.EnvConfig(size=size, min_size=5, random_size=True, map_family=family,
                                         number_obstacles=size * size // 8, obstacles_random=True,
                                         random_coverage=True, battery_factor=1e6), worlds, seed=seed)
    core.reset()
    for t in range(int(rng.integers(1, size * size // 2))):
        act = rng.integers(0, 4, worlds) if t % 3 == 0 else gw.heuristic_actions(core, False, True)[:, 0]
        core.step(act[:, None])
    return core


def walkers_of(core: gw.GridWorldCore, dead_ends_first: bool, tables: bool, far_first: bool = False) -> gw._Walkers:
    c, H, W = core.c, core.H, core.W
    free = ~core.obstacle[:, c:c + H, c:c + W]
    walkers = gw._Walkers(free, free & ~core.covered[:, c:c + H, c:c + W], core.agent_cells()[:, 0],
                          dead_ends_first, start=core.start[:, c:c + H, c:c + W] if far_first else None)
    if tables:
        walkers.tables = [gw._path_tables(m, walkers.Wp) for m in walkers.free]
    return walkers


@pytest.mark.parametrize("family", gw.MAP_FAMILIES[:-1])
@pytest.mark.parametrize("dead_ends_first", [True, False])
@pytest.mark.parametrize("far_first", [False, True])
def test_walkers_move_as_the_heuristic(family, dead_ends_first, far_first):
    for seed in range(3):
        core = mid_episode(family, 16, seed)
        want = gw.heuristic_actions(core, False, dead_ends_first, far_first)[:, 0]
        unfinished = core.remaining > 0
        for tables in (False, True):
            got = walkers_of(core, dead_ends_first, tables, far_first).moves()
            assert got[unfinished].tolist() == want[unfinished].tolist()


@pytest.mark.parametrize("far_first", [False, True])
def test_walkers_follow_the_heuristic_to_the_end(far_first):
    """Stepped together, walkers and the environment cover the same cells in the same steps."""
    core = mid_episode("rooms", 14, 7, worlds=6)
    walkers = walkers_of(core, True, True, far_first)
    for _ in range(4 * 14 * 14):
        live = core.remaining > 0
        if not live.any():
            break
        move = gw.heuristic_actions(core, False, True, far_first)[:, 0]
        assert walkers.moves()[live].tolist() == move[live].tolist()
        core.step(move[:, None])
        step = walkers.take(np.flatnonzero(live))
        step.step(move[live])
        walkers.pos[live], walkers.remaining[live], walkers.poi[live] = step.pos, step.remaining, step.poi
        assert walkers.remaining.tolist() == core.remaining.tolist()
    assert (core.remaining == 0).all()


@pytest.mark.parametrize("far_first", [False, True])
def test_walkers_forget_their_target_when_they_step_off_its_path(far_first):
    """A walker keeps the target it looked up while it walks toward it, and a step elsewhere (a rollout's tried
    move, a learner's move) makes it look again: with random steps mixed in, its moves stay the heuristic's."""
    rng = np.random.default_rng(5)
    core = mid_episode("maze", 16, 3, worlds=8)
    walkers = walkers_of(core, True, True, far_first)
    for _ in range(300):
        live = core.remaining > 0
        if not live.any():
            break
        move = gw.heuristic_actions(core, False, True, far_first)[:, 0]
        assert walkers.moves()[live].tolist() == move[live].tolist()
        legal = walkers.free[np.arange(len(move))[:, None], walkers.pos[:, None] + walkers.delta]
        random_move = np.array([rng.choice(np.flatnonzero(row)) for row in legal])
        move = np.where(live & (rng.random(len(move)) < 0.3), random_move, move)
        move = np.where(live, move, gw.WAIT)
        core.step(move[:, None])
        rows = np.flatnonzero(live)
        step = walkers.take(rows)
        step.step(move[rows])
        walkers.pos[rows], walkers.remaining[rows], walkers.poi[rows], walkers.goal[rows] = (
            step.pos, step.remaining, step.poi, step.goal)
    assert (core.remaining == 0).all()


def test_path_tables_by_hand():
    """A 3x3 map with its centre blocked: a ring of 8 cells. From the top-left corner (0, 0) the bottom-right
    (2, 2) is 4 steps either way round; the walk back from it takes the first closer cell in N, S, W, E order:
    N of (2, 2) is (1, 2) (distance 3), then N again (0, 2), then W (0, 1): the first cell is East of the start."""
    free = np.ones((1, 3, 3), bool)
    free[0, 1, 1] = False
    walkers = gw._Walkers(free, free, np.array([[0, 0]]), True)
    row, dist, first = gw._path_tables(walkers.free[0], walkers.Wp)
    Wp = walkers.Wp
    cell = lambda y, x: (y + 1) * Wp + x + 1  # noqa: E731
    assert row[cell(1, 1)] == -1 and (row[[cell(y, x) for y, x in np.argwhere(free[0])]] >= 0).all()
    r = row[cell(0, 0)]
    assert [dist[r, cell(y, x)] for y, x in [(0, 0), (0, 2), (2, 2), (2, 0), (1, 0)]] == [0, 2, 4, 2, 1]
    assert dist[r, cell(1, 1)] == np.iinfo(np.int16).max
    assert first[r, cell(2, 2)] == cell(0, 1) and first[r, cell(2, 0)] == cell(1, 0) and first[r, cell(0, 1)] == cell(0, 1)


def test_path_table_cache_keeps_one_table_a_map_within_its_budget(monkeypatch):
    core = mid_episode("clutter", 12, 3, worlds=4)
    gw.rollout_actions(core)
    assert len(core.path_cache) == len({m.tobytes() for m in ~core.obstacle})
    first = {k: e[0] for k, e in core.path_cache.items()}
    gw.rollout_actions(core)
    assert all(core.path_cache[k][0] is t for k, t in first.items())  # reused, not rebuilt
    small = gw.GridWorldCore(gw.EnvConfig(size=12), 1)
    monkeypatch.setattr(gw.GridWorldCore, "PATH_TABLE_BYTES", 1)
    small.reset()
    small.step(np.array([[gw.NORTH]]))
    before = gw.rollout_actions(small)
    assert small.path_cache == {}  # over the budget: the walkers searched instead
    monkeypatch.setattr(gw.GridWorldCore, "PATH_TABLE_BYTES", 512 * 2**20)
    small.path_cache.clear()
    assert gw.rollout_actions(small).tolist() == before.tolist()
