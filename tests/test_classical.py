"""Tests for classical_cpp: the classical coverage planners, replay, lower_bound and the CLI.

Cells are [row, col], row 0 North; a path is one cell per time step, its first cell the start.
Every plan is checked twice: directly here (4-adjacent or equal steps, never on an obstacle or off
the map, every free cell visited) and by `classical_cpp.replay` (gridworld's own rules and metrics).
Scenarios are prepared as the CLI's `load_scenarios` does: the start cells are covered.
"""
from __future__ import annotations

import hashlib
import json
import math
import re
import subprocess
import sys
from collections import deque
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from conftest import from_rows  # noqa: E402
from conftest import one_line_error as _one_line_error  # noqa: E402

import classical_cpp as cc  # noqa: E402
import gridworld as gw  # noqa: E402

EXTERNAL = ROOT / "maps" / "external"
REFERENCES = json.loads((EXTERNAL / "references.json").read_text())
SINGLE = ("greedy", "greedy-dead-ends", "boustrophedon", "spiral-stc", "wavefront", "lkh")
FAST_SINGLE = ("greedy", "greedy-dead-ends", "boustrophedon", "spiral-stc", "wavefront")  # no LKH


# ----------------------------------------------------------------------------- helpers
def make(obstacles, starts, covered=None) -> gw.Scenario:
    """A scenario with the start cells covered (as load_scenarios prepares them)."""
    obstacles = np.asarray(obstacles, bool)
    starts = np.asarray(starts, np.int64).reshape(-1, 2)
    cov = np.zeros_like(obstacles) if covered is None else np.asarray(covered, bool).copy()
    cov[starts[:, 0], starts[:, 1]] = True
    return gw.Scenario(obstacles, starts, cov)


def load_external(name: str, start) -> gw.Scenario:
    s = gw.load_map(str(EXTERNAL / name))
    return make(s.obstacles, [start])


def free_starts(obstacles: np.ndarray, k: int, seed: int) -> np.ndarray:
    free = np.argwhere(~obstacles)
    return free[np.random.default_rng(seed).choice(len(free), k, replace=False)]


def keep_component(obstacles: np.ndarray, cell) -> np.ndarray:
    """Obstacles with every free cell outside `cell`'s 4-connected component blocked."""
    h, w = obstacles.shape
    seen = np.zeros_like(obstacles)
    seen[tuple(cell)] = True
    queue = deque([tuple(cell)])
    while queue:
        y, x = queue.popleft()
        for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1)):
            ny, nx = y + dy, x + dx
            if 0 <= ny < h and 0 <= nx < w and not obstacles[ny, nx] and not seen[ny, nx]:
                seen[ny, nx] = True
                queue.append((ny, nx))
    return ~seen


def maze(k: int, seed: int, loops: int = 0) -> np.ndarray:
    """A (2k+1)x(2k+1) perfect maze carved depth-first on the odd cells, plus `loops` extra
    openings in inner walls (so that the free graph has cycles)."""
    rng = np.random.default_rng(seed)
    n = 2 * k + 1
    obst = np.ones((n, n), bool)
    obst[1, 1] = False
    stack = [(1, 1)]
    while stack:
        y, x = stack[-1]
        nbs = [(y + dy, x + dx) for dy, dx in ((-2, 0), (2, 0), (0, -2), (0, 2))
               if 0 < y + dy < n and 0 < x + dx < n and obst[y + dy, x + dx]]
        if not nbs:
            stack.pop()
            continue
        ny, nx = nbs[rng.integers(len(nbs))]
        obst[ny, nx] = obst[(y + ny) // 2, (x + nx) // 2] = False
        stack.append((ny, nx))
    walls = [(y, x) for y in range(1, n - 1) for x in range(1, n - 1)
             if obst[y, x] and (y + x) % 2 == 1]
    for i in rng.choice(len(walls), min(loops, len(walls)), replace=False):
        obst[walls[i]] = False
    return obst


def rooms(h: int, w: int, room: int, seed: int) -> np.ndarray:
    """Rooms of side `room` separated by one-cell walls; every wall segment between two rooms
    has one door at a random place."""
    rng = np.random.default_rng(seed)
    obst = np.zeros((h, w), bool)
    rows = list(range(room, h - 1, room + 1))
    cols = list(range(room, w - 1, room + 1))
    for r in rows:
        obst[r, :] = True
    for c in cols:
        obst[:, c] = True
    ybounds = [-1] + rows + [h]
    xbounds = [-1] + cols + [w]
    for r in rows:  # a door in each horizontal wall segment
        for x0, x1 in zip(xbounds, xbounds[1:]):
            obst[r, rng.integers(x0 + 1, x1)] = False
    for c in cols:  # and in each vertical one
        for y0, y1 in zip(ybounds, ybounds[1:]):
            obst[rng.integers(y0 + 1, y1), c] = False
    return obst


def partly_blocked(h: int, w: int, seed: int) -> np.ndarray:
    """Most 2x2 blocks get 1-3 obstacle cells (never all 4): cells are blocked in random order
    whenever their block keeps a free cell and the free cells stay one 4-connected component."""
    rng = np.random.default_rng(seed)
    obst = np.zeros((h, w), bool)
    for i in rng.permutation(h * w):
        y, x = divmod(int(i), w)
        by, bx = y - y % 2, x - x % 2
        block = obst[by:by + 2, bx:bx + 2]
        if rng.random() < 0.4 or block.sum() + 1 >= block.size:
            continue
        obst[y, x] = True
        free = np.argwhere(~obst)
        if (keep_component(obst, free[0]) != obst).any():  # disconnected: undo
            obst[y, x] = False
    return obst


def random_scenario(size: int, pct: float, seed: int, agents: int = 1) -> gw.Scenario:
    s = gw.generate_scenarios(1, seed=seed, size=size, number_obstacles=int(pct * size * size),
                              obstacles_random=True, number_agents=agents)[0]
    gw.check_scenario(s)  # one 4-connected component, starts on free cells
    return s


def check_legal(scenario: gw.Scenario, paths) -> dict:
    """Check the plan directly, then through replay; return replay's metrics."""
    obst = scenario.obstacles
    h, w = obst.shape
    assert len(paths) == len(scenario.starts)
    visited = np.zeros_like(obst)
    for i, p in enumerate(paths):
        p = np.asarray(p)
        assert p.ndim == 2 and p.shape[1] == 2 and len(p) >= 1, f"path {i} has shape {p.shape}"
        assert np.issubdtype(p.dtype, np.integer), f"path {i} dtype {p.dtype}"
        assert (p[0] == scenario.starts[i]).all(), f"path {i} starts at {p[0]} not {scenario.starts[i]}"
        assert ((p >= 0) & (p < [h, w])).all(), f"path {i} leaves the {h}x{w} map"
        assert not obst[p[:, 0], p[:, 1]].any(), f"path {i} enters an obstacle"
        steps = np.abs(np.diff(p, axis=0)).sum(1)
        assert (steps <= 1).all(), f"path {i} jumps at step {int(np.argmax(steps > 1)) + 1}"
        visited[p[:, 0], p[:, 1]] = True
    missing = ~obst & ~visited
    if scenario.covered is not None:
        missing &= ~scenario.covered
    assert not missing.any(), f"free cells never visited: {np.argwhere(missing)[:5].tolist()}"
    m = cc.replay(scenario, paths)
    assert m["completed"] is True or m["completed"] == 1
    assert m["steps"] >= m["lower_bound"]
    return m


def run_planner(name: str, scenario: gw.Scenario):
    return cc.PLANNERS[name](scenario)


# ----------------------------------------------------------------------------- 1. legality
RANDOM_CASES = [(5, 0.0, 1), (5, 0.1, 2), (6, 0.05, 3), (7, 0.1, 4), (8, 0.0, 5), (9, 0.08, 6),
                (10, 0.1, 7), (11, 0.03, 8), (12, 0.1, 9), (13, 0.06, 10), (15, 0.1, 11),
                (16, 0.0, 12), (17, 0.1, 13), (20, 0.05, 14), (24, 0.1, 15), (27, 0.02, 16),
                (30, 0.1, 17), (30, 0.0, 18)]


@pytest.mark.parametrize("size,pct,seed", RANDOM_CASES)
def test_every_planner_legal_and_complete_on_random_maps(size, pct, seed):
    s = random_scenario(size, pct, seed)
    names = SINGLE if size <= 16 else FAST_SINGLE
    for name in names + ("partition",):
        m = check_legal(s, run_planner(name, s))
        assert m["steps"] >= (~s.obstacles).sum() - 1, name


STRUCTURED = {
    "rooms-19x19": lambda: rooms(19, 19, 5, seed=0),
    "rooms-17x26": lambda: rooms(17, 26, 3, seed=1),
    "rooms-12x12-odd": lambda: rooms(12, 12, 4, seed=2),
    "maze-7": lambda: maze(3, seed=0),
    "maze-15": lambda: maze(7, seed=1),
    "maze-21-loops": lambda: maze(10, seed=2, loops=15),
    "maze-25": lambda: maze(12, seed=3),
    "partly-blocked-16x16": lambda: partly_blocked(16, 16, seed=0),
    "partly-blocked-15x21": lambda: partly_blocked(15, 21, seed=1),
    "partly-blocked-9x9": lambda: partly_blocked(9, 9, seed=2),
}


@pytest.mark.parametrize("kind", list(STRUCTURED))
def test_every_planner_legal_and_complete_on_rooms_mazes_and_partly_blocked_blocks(kind):
    obst = STRUCTURED[kind]()
    for seed in range(2):  # two starts per map (lkh from the first only: it is the slow one)
        start = free_starts(obst, 1, seed)[0]
        s = make(obst, [start])
        gw.check_scenario(s)
        for name in (SINGLE if seed == 0 else FAST_SINGLE) + ("partition",):
            check_legal(s, run_planner(name, s))


def test_partly_blocked_map_really_has_partly_blocked_blocks():
    """The spiral-STC stress maps above must contain many blocks with 1-3 obstacle cells, and
    spiral-stc must cover every free cell of them (from many starts)."""
    for seed, (h, w) in enumerate([(16, 16), (15, 21), (9, 9), (20, 13)]):
        obst = partly_blocked(h, w, seed)
        hh, ww = h - h % 2, w - w % 2
        blocks = obst[:hh, :ww].reshape(hh // 2, 2, ww // 2, 2).sum((1, 3))
        assert ((blocks >= 1) & (blocks <= 3)).sum() >= blocks.size // 2
        for start in free_starts(obst, 6, seed):
            check_legal(make(obst, [start]), cc.spiral_stc(make(obst, [start])))


@pytest.mark.parametrize("mapname", sorted(REFERENCES))
def test_fast_planners_legal_and_complete_on_external_maps(mapname):
    start = REFERENCES[mapname][0]["start"]
    s = load_external(mapname, start)
    for name in FAST_SINGLE:
        check_legal(s, run_planner(name, s))
    multi = make(s.obstacles, free_starts(s.obstacles, 3, seed=3))
    check_legal(multi, cc.greedy(multi))
    check_legal(multi, cc.partition(multi))


def test_lkh_legal_on_one_32x32_external_map():
    ref = REFERENCES["maze-32-32-2.map"][0]
    s = load_external("maze-32-32-2.map", ref["start"])
    m = check_legal(s, cc.lkh(s))
    assert ref["n_free"] - 1 <= m["steps"] <= math.ceil(1.02 * ref["lkh_steps"])
    assert m["steps"] < ref["greedy_steps"]


def test_spiral_stc_is_hamiltonian_on_empty_even_rectangles():
    """On an empty 2k x 2m grid the STC circumnavigation is a Hamiltonian cycle: from any start
    spiral-stc needs exactly n - 1 steps and never revisits."""
    for h, w in [(2, 2), (4, 4), (6, 8), (8, 4)]:
        for y in range(h):
            for x in range(w):
                s = make(np.zeros((h, w)), [[y, x]])
                m = check_legal(s, cc.spiral_stc(s))
                assert m["steps"] == h * w - 1 and m["overlap"] == 0, (h, w, y, x)


# ----------------------------------------------------------------------------- 2. hand-computed
@pytest.mark.parametrize("n", [2, 3, 6, 9])
@pytest.mark.parametrize("name", SINGLE + ("partition",))
def test_corridor_from_an_end_takes_n_minus_1_steps(name, n):
    for start in ([0, 0], [0, n - 1]):  # 1 x n, both ends
        s = make(np.zeros((1, n)), [start])
        m = check_legal(s, run_planner(name, s))
        assert m["steps"] == n - 1 and m["overlap"] == 0, (start, m)
    for start in ([0, 0], [n - 1, 0]):  # n x 1, both ends
        s = make(np.zeros((n, 1)), [start])
        m = check_legal(s, run_planner(name, s))
        assert m["steps"] == n - 1 and m["overlap"] == 0, (start, m)


def test_lkh_middle_of_1x7_corridor_is_optimal():
    # from col 3: 3 steps to one end, then 6 to the other = 9; 6 new cells, 3 revisits
    s = make(np.zeros((1, 7)), [[0, 3]])
    m = check_legal(s, cc.lkh(s))
    assert m["steps"] == 9
    assert m["new_cells"] == 6 and m["revisits"] == 3
    assert m["overlap"] == pytest.approx(0.5) and m["time_save"] == pytest.approx(1.5)
    assert m["lower_bound"] == 7  # parity: 4 cells of the other colour than col 3's take 7 steps


@pytest.mark.parametrize("corner", [[0, 0], [0, 3], [3, 0], [3, 3]])
def test_lkh_empty_4x4_from_a_corner_is_hamiltonian(corner):
    s = make(np.zeros((4, 4)), [corner])
    m = check_legal(s, cc.lkh(s))
    assert m["steps"] == 15 and m["overlap"] == 0


def test_boustrophedon_hand_path_on_3x3():
    # from the SW corner: N, N, then E (N/S blocked), S, S, E, N, N - a column-wise snake
    s = make(np.zeros((3, 3)), [[2, 0]])
    (p,) = cc.boustrophedon(s)
    assert p.tolist() == [[2, 0], [1, 0], [0, 0], [0, 1], [1, 1], [2, 1], [2, 2], [1, 2], [0, 2]]


@pytest.mark.parametrize("h,w", [(4, 4), (5, 7), (6, 3)])
def test_boustrophedon_snakes_empty_rectangles_from_corners(h, w):
    for corner in ([0, 0], [0, w - 1], [h - 1, 0], [h - 1, w - 1]):
        s = make(np.zeros((h, w)), [corner])
        m = check_legal(s, cc.boustrophedon(s))
        assert m["steps"] == h * w - 1, corner


def test_every_planner_around_a_pillar():
    # 3x3 ring around a central obstacle from a corner: 8 free cells in a cycle, 7 steps.
    # (spiral-stc is exempt: on partly blocked 2x2 blocks its circumnavigation is not optimal,
    # here it takes 8; it must still be legal)
    s = from_rows(["0..", ".@.", "..."])
    for name in SINGLE:
        m = check_legal(s, run_planner(name, s))
        assert m["steps"] == 7 or (name == "spiral-stc" and m["steps"] <= 9), (name, m["steps"])


def test_lkh_dead_end_branch():
    # a T from the junction (0,2): west arm 2 cells, stem 2 cells, east arm 3 cells. Two arms
    # are walked there and back, the last one way: best is to end in the longest (east) arm,
    # 2*2 + 2*2 + 3 = 11 (ending in the stem or the west arm costs 12)
    s = from_rows(["..0...", "@@.@@@", "@@.@@@"])
    m = check_legal(s, cc.lkh(s))
    assert m["steps"] == 11
    assert cc.replay(s, cc.greedy(s))["steps"] >= 11


def test_start_cells_of_paths_and_trivial_maps():
    for rows in (["0."], [".0"], ["0", "."], [".", "0"]):
        s = from_rows(rows)
        for name in SINGLE + ("partition",):
            m = check_legal(s, run_planner(name, s))
            assert m["steps"] == 1, (rows, name)


def test_precovered_cells_need_not_be_visited():
    # only (0,4) is uncovered: every planner walks straight there
    s = from_rows(["0xxx."])
    for name in SINGLE + ("partition",):
        m = check_legal(s, run_planner(name, s))
        assert m["steps"] == 4 and m["n_poi_start"] == 1, name


def test_dead_ends_first_covers_the_lone_cell_before_the_row():
    # row 0 uncovered, and the lone cell below the start: greedy takes row 0 first (row-major) and
    # walks back, 7 steps; dead-ends-first takes the lone cell (no uncovered neighbour) first, 6
    s = from_rows(["...", "x0x", "x.x"])
    assert check_legal(s, cc.greedy(s))["steps"] == 7
    assert check_legal(s, cc.greedy_dead_ends(s))["steps"] == 6


def test_dead_ends_first_overlaps_less_than_greedy_on_random_maps():
    scenarios = [random_scenario(size, 0.1, seed=700 + 10 * size + k) for size in range(6, 21, 2) for k in range(3)]
    greedy = np.mean([cc.replay(s, p)["overlap"] for s, p in zip(scenarios, cc.plan("greedy", scenarios))])
    dead_ends = np.mean([cc.replay(s, p)["overlap"]
                         for s, p in zip(scenarios, cc.plan("greedy-dead-ends", scenarios))])
    assert dead_ends < 0.75 * greedy, (dead_ends, greedy)


# ----------------------------------------------------------------------------- 3. lkh quality
def test_lkh_bound_and_never_much_worse_than_greedy():
    worse = []
    for i in range(14):
        size = 5 + i % 10
        s = random_scenario(size, 0.05 * (i % 3), seed=200 + i)
        n_free = int((~s.obstacles).sum())
        lk = check_legal(s, cc.lkh(s))["steps"]
        gr = cc.replay(s, cc.greedy(s))["steps"]
        assert lk >= n_free - 1
        worse.append(lk - gr)
        assert lk <= gr + max(1, math.ceil(0.01 * gr)), (size, lk, gr)
    assert max(worse) <= 0 or np.mean(worse) < 0


@pytest.mark.parametrize("mapname", ["random-8-8-20.map", "empty-8-8.map"])
def test_lkh_reproduces_references_on_8x8(mapname):
    for ref in REFERENCES[mapname]:
        s = load_external(mapname, ref["start"])
        assert int((~s.obstacles).sum()) == ref["n_free"]
        m = check_legal(s, cc.lkh(s))
        assert m["steps"] == ref["lkh_steps"], ref["start"]
        assert round(m["overlap"], 4) == ref["lkh_overlap"]


def test_lkh_reproduces_reference_on_16x16():
    ref = REFERENCES["empty-16-16.map"][0]
    s = load_external("empty-16-16.map", ref["start"])
    assert check_legal(s, cc.lkh(s))["steps"] == ref["lkh_steps"] == 255


# ----------------------------------------------------------------------------- 4. greedy references
def test_greedy_reproduces_every_reference_entry():
    entries = [(name, ref) for name in sorted(REFERENCES) for ref in REFERENCES[name]]
    scenarios = [load_external(name, ref["start"]) for name, ref in entries]
    plans = cc.greedy_many(scenarios)  # batched over maps of 8x8, 16x16 and 32x32
    for (name, ref), s, paths in zip(entries, scenarios, plans):
        assert len(paths[0]) - 1 == ref["greedy_steps"], (name, ref["start"])
        if s.obstacles.shape[0] <= 16:  # full replay for the small maps
            m = check_legal(s, paths)
            assert m["steps"] == ref["greedy_steps"]
            assert round(m["overlap"], 4) == ref["greedy_overlap"]


def test_greedy_single_equals_batched_with_mixed_agent_counts():
    scenarios = [random_scenario(6 + i, 0.05, seed=300 + i, agents=1 + i % 3) for i in range(7)]
    batched = cc.greedy_many(scenarios)
    assert cc.greedy_many([]) == []
    for s, b in zip(scenarios, batched):
        single = cc.greedy(s)
        assert len(single) == len(b) == len(s.starts)
        for p, q in zip(single, b):
            np.testing.assert_array_equal(p, q)
    via_plan = cc.plan("greedy", scenarios)
    for b, q in zip(batched, via_plan):
        for p1, p2 in zip(b, q):
            np.testing.assert_array_equal(p1, p2)


# ----------------------------------------------------------------------------- 5. several agents
@pytest.mark.parametrize("dead_ends_first", [False, True])
@pytest.mark.parametrize("agents", [2, 3, 4, 5])
def test_multi_agent_greedy_completes_without_blocked_moves(agents, dead_ends_first):
    scenarios = gw.generate_scenarios(6, seed=agents, size=8 + 2 * agents, number_obstacles=agents * 4,
                                      obstacles_random=True, number_agents=agents)
    for s, paths in zip(scenarios, cc.greedy_many(scenarios, dead_ends_first)):
        assert len(paths) == agents
        assert len({len(p) for p in paths}) == 1  # all agents share the clock
        m = check_legal(s, paths)  # replay raises on any blocked move
        assert m["steps"] == len(paths[0]) - 1
        # no two agents ever share a cell, nor swap cells in one step
        cells = np.stack(paths, 1)  # (T, N, 2)
        flat = cells[..., 0] * 100 + cells[..., 1]
        for t in range(len(flat)):
            assert len(set(flat[t].tolist())) == agents, t
            if t:
                for a in range(agents):
                    for b in range(agents):
                        assert not (a != b and flat[t, a] == flat[t - 1, b] and flat[t, b] == flat[t - 1, a])


def _check_partition(s: gw.Scenario) -> dict:
    paths = cc.partition(s)
    m = check_legal(s, paths)
    owners = {}
    for i, p in enumerate(paths):
        cells = {tuple(c) for c in np.asarray(p).tolist()}
        for c in cells:
            assert c not in owners, f"cell {c} visited by agents {owners.get(c)} and {i}"
            owners[c] = i
        # each agent's region is 4-connected (it is walked without leaving it)
        region = np.ones_like(s.obstacles)
        for c in cells:
            region[c] = False
        assert not (keep_component(region, p[0]) != region).any()
    assert set(owners) == {tuple(c) for c in np.argwhere(~s.obstacles).tolist()}
    assert m["steps"] >= cc.lower_bound(s)
    assert m["steps"] == max(len(p) for p in paths) - 1
    return m


@pytest.mark.parametrize("agents", [2, 3, 4, 5])
def test_partition_regions_disjoint_and_cover_everything(agents):
    for seed in range(4):
        size = 7 + 3 * seed
        _check_partition(random_scenario(size, 0.08, seed=400 + 10 * agents + seed, agents=agents))
    for obst in (rooms(17, 17, 3, seed=agents), maze(6, seed=agents, loops=5)):
        _check_partition(make(obst, free_starts(obst, agents, seed=agents)))


def test_partition_balanced_on_empty_maps():
    s = make(np.zeros((8, 8)), [[0, 0], [0, 7], [7, 0], [7, 7]])
    paths = cc.partition(s)
    assert [len({tuple(c) for c in p.tolist()}) for p in paths] == [16, 16, 16, 16]
    assert _check_partition(s)["steps"] == 15 == cc.lower_bound(s)
    s = make(np.zeros((10, 10)), [[0, 0], [0, 1], [0, 2]])
    sizes = sorted(len({tuple(c) for c in p.tolist()}) for p in cc.partition(s))
    assert sizes == [33, 33, 34]


def test_partition_agent_with_nothing_to_cover_stays_put():
    # 1x3 corridor, agents at both ends: agent 0 claims the middle cell (ties go to the lower
    # index), so agent 1 has nothing to cover and its path is just its start
    s = from_rows(["0.1"])
    paths = cc.partition(s)
    assert paths[0].tolist() == [[0, 0], [0, 1]]
    assert np.asarray(paths[1]).tolist() == [[0, 2]]
    assert _check_partition(s)["steps"] == 1


def test_lower_bound_hand_values():
    # 10 free cells, 3 agents: ceil(7 / 3) = 3
    s = make(np.array([[0] * 5, [0] * 5, [1] * 5], bool), [[0, 0], [0, 1], [1, 4]])
    assert cc.lower_bound(s) == 3
    assert cc.lower_bound(make(np.zeros((1, 7)), [[0, 3]])) == 7  # cols 0, 2, 4, 6: 4 of the other colour
    assert cc.lower_bound(make(np.zeros((4, 4)), [[0, 0], [3, 3]])) == 7  # ceil(14 / 2)
    assert cc.lower_bound(make(np.zeros((3, 3)), [[0, 0], [0, 1], [0, 2], [1, 1]])) == 2  # ceil(5/4)
    assert cc.lower_bound(make(np.zeros((1, 2)), [[0, 0]])) == 1


def test_lower_bound_checkerboard_hand_values():
    # 3x3 from an edge cell: 5 cells of the other colour (corners, centre) need 9 steps; no Hamiltonian path exists
    assert cc.lower_bound(make(np.zeros((3, 3)), [[0, 1]])) == 9
    assert cc.lower_bound(make(np.zeros((3, 3)), [[1, 1]])) == 8  # from the centre: round the ring, no revisit
    assert cc.lower_bound(make(np.zeros((1, 3)), [[0, 1]])) == 3  # both ends are the other colour
    assert cc.lower_bound(make(np.zeros((1, 3)), [[0, 1], [0, 0]])) == 1  # agent 0 takes col 2 in one step
    # 5x5 from (0, 1): 13 cells of the other colour need 2 * 13 - 1 = 25 steps, one more than n_poi
    assert cc.lower_bound(make(np.zeros((5, 5)), [[0, 1]])) == 25
    assert cc.lower_bound(make(np.zeros((5, 5)), [[0, 0]])) == 24


@pytest.mark.parametrize("agents", [1, 2, 5])
def test_lower_bound_never_above_a_walk(agents):
    for seed in range(6):
        s = random_scenario(5 + seed, 0.1, seed=700 + seed, agents=agents)
        for name in ("greedy", "greedy-dead-ends", "rollout"):
            if agents == 1 or name != "rollout":
                assert cc.replay(s, cc.PLANNERS[name](s))["steps"] >= cc.lower_bound(s)
    s = make(np.zeros((5, 5)), [[0, 1]])
    assert cc.replay(s, cc.lkh(s))["steps"] == cc.lower_bound(s) == 25  # the bound is tight there


def test_lower_bound_respects_precovered_cells():
    # only (0,1) is left to cover: 1 step suffices, so the bound must be <= 1 (it is 5 = 6 - 1)
    s = from_rows(["0.", "xx", "xx"])
    m = cc.replay(s, cc.greedy(s))
    assert m["steps"] == 1
    assert cc.lower_bound(s) <= m["steps"]


# ----------------------------------------------------------------------------- 6. bad input
def _one_line_value_error(fn, *args, match=None):
    with pytest.raises(ValueError) as info:
        fn(*args)
    msg = str(info.value)
    assert msg and "\n" not in msg.strip(), msg
    if match is not None:
        assert match in msg.lower(), msg
    return msg


@pytest.mark.parametrize("name", SINGLE + ("partition",))
def test_start_on_an_obstacle_is_a_value_error(name):
    s = gw.Scenario(np.array([[0, 0, 0], [0, 1, 0], [0, 0, 0]], bool), np.array([[1, 1]]),
                    np.array([[0, 0, 0], [0, 1, 0], [0, 0, 0]], bool))
    _one_line_value_error(cc.PLANNERS[name], s, match="obstacle")


@pytest.mark.parametrize("name", SINGLE + ("partition",))
def test_disconnected_map_is_a_value_error(name):
    s = from_rows(["0.@..", "..@.."])
    _one_line_value_error(cc.PLANNERS[name], s)


def test_lkh_disconnected_single_target_is_a_value_error():
    _one_line_value_error(cc.lkh, from_rows(["0@."]))


@pytest.mark.parametrize("name", ["boustrophedon", "spiral-stc", "wavefront", "lkh"])
def test_single_agent_planner_with_two_starts(name):
    s = from_rows(["0..", "...", "..1"])
    _one_line_value_error(cc.PLANNERS[name], s, match="one start")
    _one_line_value_error(cc.plan, name, [s], match="single-agent")


def test_plan_unknown_name():
    msg = _one_line_value_error(cc.plan, "nope", [from_rows(["0.."])], match="unknown planner")
    for name in cc.PLANNERS:
        assert name in msg


def test_plan_matches_planners():
    s = from_rows(["0...", ".@..", "...."])
    for name in cc.PLANNERS:
        (got,) = cc.plan(name, [s])
        want = cc.PLANNERS[name](s)
        assert len(got) == len(want)
        for p, q in zip(got, want):
            np.testing.assert_array_equal(p, q)


def test_replay_rejects_bad_paths():
    s = from_rows(["0..", ".@.", "..."])
    good = [np.array([[0, 0], [0, 1], [0, 2], [1, 2], [2, 2], [2, 1], [2, 0], [1, 0]])]
    m = cc.replay(s, good)
    assert m["completed"] and m["steps"] == 7 and m["overlap"] == 0 and m["lower_bound"] == 7
    jump = [np.array([[0, 0], [0, 2], [1, 2], [2, 2], [2, 1], [2, 0], [1, 0], [0, 1]])]
    _one_line_value_error(cc.replay, s, jump, match="jump")
    diagonal = [np.array([[0, 0], [1, 0], [2, 1], [2, 2], [1, 2], [0, 2], [0, 1]])]
    _one_line_value_error(cc.replay, s, diagonal, match="jump")
    into_obstacle = [np.array([[0, 0], [0, 1], [1, 1], [1, 2], [2, 2], [2, 1], [2, 0], [1, 0]])]
    _one_line_value_error(cc.replay, s, into_obstacle, match="blocked")
    off_map = [np.array([[0, 0], [-1, 0]])]
    _one_line_value_error(cc.replay, s, off_map, match="blocked")
    elsewhere = [good[0][1:]]
    _one_line_value_error(cc.replay, s, elsewhere, match="start")
    incomplete = [good[0][:5]]
    _one_line_value_error(cc.replay, s, incomplete, match="uncovered")
    _one_line_value_error(cc.replay, s, [], match="paths")
    _one_line_value_error(cc.replay, s, good + good, match="paths")
    _one_line_value_error(cc.replay, s, [np.zeros((0, 2), int)])
    _one_line_value_error(cc.replay, s, [np.array([0, 0, 0])])


def test_replay_rejects_agent_collisions():
    s = from_rows(["0..1"])
    # both agents step into (0,1)/(0,2) and then swap through each other
    swap = [np.array([[0, 0], [0, 1], [0, 2], [0, 3]]), np.array([[0, 3], [0, 2], [0, 1], [0, 0]])]
    _one_line_value_error(cc.replay, s, swap, match="blocked")
    same = [np.array([[0, 0], [0, 1], [0, 2]]), np.array([[0, 3], [0, 2], [0, 2]])]
    _one_line_value_error(cc.replay, s, same)
    ok = [np.array([[0, 0], [0, 1]]), np.array([[0, 3], [0, 2]])]
    m = cc.replay(s, ok)
    assert m["completed"] and m["steps"] == 1 and m["lower_bound"] == 1


# ----------------------------------------------------------------------------- 7. many maps
def test_greedy_many_on_50_random_30x30_maps_finishes():
    scenarios = gw.generate_scenarios(50, seed=7, size=30, number_obstacles=60, obstacles_random=True)
    plans = cc.greedy_many(scenarios)
    assert len(plans) == 50
    for s, (p,) in zip(scenarios, plans):
        visited = np.zeros_like(s.obstacles)
        visited[p[:, 0], p[:, 1]] = True
        assert (visited | s.obstacles).all()
        assert (np.abs(np.diff(p, axis=0)).sum(1) <= 1).all()
    for s, paths in zip(scenarios[:3], plans[:3]):
        check_legal(s, paths)


# ----------------------------------------------------------------------------- 8. the CLI
def _cli(*args, timeout=120):
    return subprocess.run([sys.executable, "classical_cpp.py", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=timeout)


def test_cli_boustrophedon_on_an_external_map(tmp_path):
    out = tmp_path / "rows.jsonl"
    r = _cli("--planner", "boustrophedon", "--maps", "maps/external/random-8-8-20.map", "--out", str(out))
    assert r.returncode == 0, r.stderr
    (row,) = [json.loads(ln) for ln in out.read_text().splitlines()]
    assert row["size"] == [8, 8] and row["completed"] is True
    assert row["n_poi_start"] == 50 and row["steps"] >= 53 and row["lower_bound"] == 53  # parity: 50 cells, 3 revisits
    (line,) = [ln for ln in r.stdout.splitlines() if ln.strip()]  # one readable line, no progress bar (not a tty)
    assert line.startswith("boustrophedon: 1 scenario(s), 1 agent(s) each, ") and line.endswith(f"-> {out}")
    assert f"mean overlap {row['overlap']:.4f}" in line and f"mean time-save factor {row['time_save']:.4f}" in line
    assert "planning " in line and "{" not in line


def test_cli_bad_planner_is_a_one_line_error():
    r = _cli("--planner", "nope", "--maps", "maps/external/random-8-8-20.map")
    assert r.returncode != 0
    err = r.stderr.strip()
    assert "Traceback" not in r.stderr
    assert err.startswith("error: ") and "\n" not in err, err
    assert "nope" in err


def test_cli_single_agent_planner_with_several_agents_is_a_one_line_error():
    r = _cli("--planner", "lkh", "--maps", "maps/external/empty-8-8.map", "--agents", "2")
    assert r.returncode != 0
    err = r.stderr.strip()
    assert "Traceback" not in r.stderr
    assert err.startswith("error: ") and "\n" not in err and "single-agent" in err, err


def _args(**kw) -> cc.Args:
    return cc.Args(**{"maps": (str(EXTERNAL / "random-8-8-20.map"),), "quiet": True, **kw})


@pytest.fixture
def bad_maps(tmp_path):
    """Map files a user could pass by mistake: empty, binary, ragged rows, a bad MovingAI header."""
    files = {"empty.map": b"", "binary.txt": bytes(range(256)), "ragged.txt": b"...\n..\n",
             "header.map": b"type octile\nheight 2\nwidth 9\nmap\n..\n..\n", "blank.txt": b"\n\n"}
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    return {name: str(tmp_path / name) for name in files}


@pytest.mark.parametrize("kw, message", [
    (dict(planner="nope"), "unknown planner 'nope'"),
    (dict(agents=0), "--agents must be >= 1"),
    (dict(agents=-2), "--agents must be >= 1"),
    (dict(agents=52), "51 free cells for 52 agents"),
    (dict(limit=-1), "--limit must be >= 0"),
    (dict(maps=()), "give --maps FILE... or --dataset FILE"),
    (dict(maps=(), dataset="no/such.npz"), "no/such.npz"),
    (dict(maps=(str(EXTERNAL / "references.json"),)), "references.json"),
    (dict(planner="spiral-stc", agents=2), "single-agent"),
    (dict(out="no/such/folder/rows.jsonl"), "no such folder"),
])
def test_bad_requests_are_value_errors_naming_the_flag_or_file(tmp_path, kw, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        cc.main(_args(**kw))
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("name", ["empty.map", "binary.txt", "ragged.txt", "header.map", "blank.txt"])
def test_bad_map_files_are_value_errors_naming_the_file(bad_maps, name):
    with pytest.raises(ValueError, match=re.escape(bad_maps[name])):
        cc.main(_args(maps=(bad_maps[name],)))


def test_bad_dataset_files_are_value_errors_naming_the_file(tmp_path, bad_maps):
    for path in (bad_maps["binary.txt"], bad_maps["empty.map"], str(tmp_path / "missing.npz")):
        with pytest.raises(ValueError, match=re.escape(path)):
            cc.main(_args(maps=(), dataset=path))


def test_report_flags_are_checked_before_anything_runs(tmp_path):
    with pytest.raises(ValueError, match="--per-size must be >= 1"):
        cc.main(cc.Args(report=True, per_size=0, out=str(tmp_path)))
    with pytest.raises(ValueError, match="--structured-per-band must be >= 1"):
        cc.main(cc.Args(report=True, structured_per_band=0, out=str(tmp_path)))
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match="not a folder"):
        cc.main(cc.Args(report=True, out=str(tmp_path / "file")))
    assert [p.name for p in tmp_path.iterdir()] == ["file"]


def test_cli_bad_inputs_are_one_line_errors_and_write_nothing(tmp_path, bad_maps):
    out = tmp_path / "rows.jsonl"
    _one_line_error(_cli("--maps", bad_maps["binary.txt"], "--out", str(out)), bad_maps["binary.txt"])
    _one_line_error(_cli("--dataset", str(tmp_path / "missing.npz"), "--out", str(out)), "missing.npz")
    _one_line_error(_cli("--maps", "maps/external/empty-8-8.map", "--agents", "65", "--out", str(out)), "64 free cells")
    _one_line_error(_cli("--maps", "maps/external/empty-8-8.map", "--limit", "-3", "--out", str(out)), "--limit")
    _one_line_error(_cli("--report", "--per-size", "0", "--out", str(tmp_path)), "--per-size")
    assert not out.exists()


def _hashes(folder: Path) -> dict:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def test_report_writes_into_out_only(tmp_path, capsys, small_report_maps):
    small_report_maps(8, 3)
    committed = _hashes(ROOT / "results")
    cc.main(cc.Args(report=True, per_size=1, out=str(tmp_path / "new" / "folder"), quiet=True))
    assert _hashes(ROOT / "results") == committed  # the committed results are left alone
    assert [p.name for p in (tmp_path / "new" / "folder").iterdir()] == ["classical_cpp.json"]
    saved = json.loads((tmp_path / "new" / "folder" / "classical_cpp.json").read_text())
    assert saved["per_size"] == 1 and list(saved["cpp_eval"]) == list(cc.REPORT_PLANNERS)
    assert list(saved["cpp_eval"]["lkh"]) == ["plan_ms_per_map", "all", "5-6", "7-8"]
    (per,) = saved["external"].values()
    assert list(saved["external"]) == ["empty-8-8.map"] and list(per) == list(cc.REPORT_PLANNERS)
    refs = REFERENCES["empty-8-8.map"][:2]
    assert per["greedy"] == [r["greedy_overlap"] for r in refs] and per["lkh"] == [r["lkh_overlap"] for r in refs]
    assert list(saved["marl_eval"]) == ["2", "5", "10"] and saved["marl_eval"]["5"]["maps"] == 3
    assert saved["marl_every"] == cc.MARL_EVERY and saved["marl_sizes"][0] >= cc.MARL_MIN_SIZE
    for entry in saved["marl_eval"].values():
        assert entry["lower_bound_time_save"] <= min(entry["greedy"], entry["partition"])
    printed = capsys.readouterr().out
    assert cc.tables(saved) in printed and "| lkh |" in printed and "| empty-8-8.map | 0.000 |" in printed
    st = saved["structured_eval"]  # the fixture: one size-10 map per family
    assert st["per_band"] == cc.STRUCTURED_PER_BAND and st["bands"] == [[10, 10]]
    assert st["maps"] == dict.fromkeys(gw.STRUCTURED_FAMILIES, 1) and list(st["planners"]) == list(cc.STRUCTURED_PLANNERS)
    assert "| rollout |" in cc.structured_table(st) and cc.structured_table(st) in printed


# ----------------------------------------------------------------------------- structured_eval in the report
def test_structured_subset_picks_per_family_and_band():
    data = np.load(ROOT / "maps" / "structured_eval.npz")
    scenarios, families, sizes = cc.structured_eval_subset(3)
    assert len(scenarios) == 3 * len(gw.STRUCTURED_FAMILIES) * len(cc.STRUCTURED_BANDS) == 48
    for f in gw.STRUCTURED_FAMILIES:
        picked = [sorted(sizes[(families == f) & (sizes >= a) & (sizes <= b)].tolist()) for a, b in cc.STRUCTURED_BANDS]
        assert picked == [[11, 13, 15], [16, 18, 20], [21, 23, 25], [26, 28, 30]]  # spread over the band's sizes
    first = np.flatnonzero((data["family"] == "maze") & (data["size"] == 13))[0]  # the first map of that size
    s = scenarios[int(np.flatnonzero((families == "maze") & (sizes == 13))[0])]
    assert s.obstacles.shape == (13, 13) and (s.obstacles == data["obstacles"][first][:13, :13]).all()
    assert (s.starts[0] == data["starts"][first][0]).all()
    for s in scenarios:  # the single-agent scenario: the first stored start, covered
        assert s.starts.shape == (1, 2) and s.covered.sum() == 1 and s.covered[tuple(s.starts[0])]
    many, fam, size = cc.structured_eval_subset(12)  # more than the band's sizes: the next maps of each size
    keep = (fam == "rooms") & (size <= 15)
    assert keep.sum() == 12 and sorted(np.unique(size[keep], return_counts=True)[1].tolist()) == [2] * 6
    assert len({m.obstacles.tobytes() + m.starts.tobytes() for m, k in zip(many, keep) if k}) == 12


def test_compare_structured_by_family_and_band(small_report_maps):
    small_report_maps(7, 1, structured=2)
    st = cc.compare_structured(3, quiet=True)
    assert st["maps"] == dict.fromkeys(gw.STRUCTURED_FAMILIES, 2) and st["bands"] == [[10, 10]]
    assert list(st["planners"]) == list(cc.STRUCTURED_PLANNERS)
    for r in st["planners"].values():
        assert list(r) == [*gw.STRUCTURED_FAMILIES, "all"]
        for v in r.values():
            assert v["completion"] == 1.0 and v["by_band"] == {"10-10": v["overlap"]} and v["plan_ms_per_map"] >= 0
        assert r["all"]["overlap"] == pytest.approx(np.mean([r[f]["overlap"] for f in gw.STRUCTURED_FAMILIES]), abs=1e-3)
    lkh, rollout = st["planners"]["lkh"], st["planners"]["rollout"]
    assert lkh["all"]["overlap"] <= rollout["all"]["overlap"] <= st["planners"]["greedy-dead-ends"]["all"]["overlap"]
    for bad in (0, -1):
        with pytest.raises(ValueError, match="--structured-per-band must be >= 1"):
            cc.compare_structured(bad)
        with pytest.raises(ValueError, match="--structured-per-band must be >= 1"):
            cc.compare(1, structured_per_band=bad)


def test_compare_rollout_is_compare_for_rollout_alone(small_report_maps):
    small_report_maps(7, 1)
    ro = cc.compare_rollout(1, quiet=True)
    assert ro["planners"] == ["rollout"] and ro["per_size"] == 1 and list(ro["cpp_eval"]) == ["rollout"]
    scenarios, sizes = cc.cpp_eval_subset(1)
    rows, _ = cc.evaluate("rollout", scenarios)
    assert ro["cpp_eval"]["rollout"]["5-6"] == round(float(np.mean([r["overlap"] for r, z in zip(rows, sizes) if z <= 6])), 4)
    assert list(ro["cpp_eval"]["rollout"]) == ["plan_ms_per_map", "all", "5-6", "7-7"]
    assert ro["external"] == {"empty-8-8.map": {"rollout": [0.0, 0.0]}}
    with pytest.raises(ValueError, match="--per-size must be >= 1"):
        cc.compare_rollout(0)


def test_replay_can_report_an_incomplete_path():
    s = make(np.zeros((1, 3)), [[0, 0]])
    short = [np.array([[0, 0], [0, 1]])]
    with pytest.raises(ValueError, match="1 free cells uncovered"):
        cc.replay(s, short)
    assert cc.replay(s, short, complete=False)["completed"] is False
    assert cc.replay(s, [np.array([[0, 0], [0, 1], [0, 2]])], complete=False)["completed"] is True


def test_evaluate_moves_the_bar_and_times_the_planning():
    scenarios = [load_external("empty-8-8.map", [0, 0]), load_external("random-8-8-20.map", [0, 0])]

    class Bar:
        n = 0

        def update(self, k):
            self.n += k

    for name in ("greedy", "boustrophedon"):
        bar = Bar()
        rows, ms = cc.evaluate(name, scenarios, bar)
        assert bar.n == 2 and len(rows) == 2 and ms >= 0
        assert rows[0]["overlap"] == 0.0 and rows[0]["steps"] == 63
