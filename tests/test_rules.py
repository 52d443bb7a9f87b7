"""Rule tests for the batched grid world (dissertation ch. 4, §5.3.4, §6.3.3, §7.3.3).

Every scenario is hand-made and every expected value is computed by hand in the comments.
Actions: 0 N, 1 S, 2 W, 3 E, 4 WAIT; cells are [row, col] with row 0 North.
"""
from __future__ import annotations

import itertools
from collections import deque

import numpy as np
import pytest

import gridworld as gw

N_, S_, W_, E_, WAIT_ = 0, 1, 2, 3, 4
EVENT_KEYS = ("blocked", "new", "revisit", "waited", "repeated_action", "finished", "timeout")
_counter = itertools.count()


# ----------------------------------------------------------------------------- helpers
def scenario_from_rows(rows: list[str]) -> gw.Scenario:
    """'.' free, '@' obstacle, 'x' pre-covered, digits = agent starts in index order."""
    chars = np.array([list(r) for r in rows])
    digits = np.char.isdigit(chars)
    ids = chars[digits].astype(int)
    starts = np.argwhere(digits)[np.argsort(ids)]
    covered = chars == "x"
    return gw.Scenario(chars == "@", starts, covered if covered.any() else None)


def make_core(tmp_path, rows, num_worlds=1, seed=0, **settings) -> gw.GridWorldCore:
    path = tmp_path / f"map{next(_counter)}.txt"
    scenario = scenario_from_rows(rows)
    gw.save_map(str(path), scenario)
    cfg = gw.EnvConfig(map_configuration=str(path), load_state=True,
                       number_agents=len(scenario.starts), **settings)
    core = gw.GridWorldCore(cfg, num_worlds=num_worlds, seed=seed)
    core.reset()
    return core


def step(core, *actions):
    """One step of world 0 (num_worlds=1) with one action per agent."""
    return core.step(np.array([actions]))


def cells(core, world=0):
    return [tuple(p) for p in core.agent_cells()[world].tolist()]


def world_map(core, b):
    """(obstacle, covered) of world b in map coordinates (h, w)."""
    h, w = core.hw[b]
    c = core.c
    return core.obstacle[b, c:c + h, c:c + w].copy(), core.covered[b, c:c + h, c:c + w].copy()


def bfs(free: np.ndarray, start) -> np.ndarray:
    seen = np.zeros_like(free)
    seen[tuple(start)] = True
    queue = deque([tuple(start)])
    h, w = free.shape
    while queue:
        y, x = queue.popleft()
        for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1)):
            ny, nx = y + dy, x + dx
            if 0 <= ny < h and 0 <= nx < w and free[ny, nx] and not seen[ny, nx]:
                seen[ny, nx] = True
                queue.append((ny, nx))
    return seen


def neighbours_any(m: np.ndarray) -> np.ndarray:
    """Cells with at least one 4-neighbour set in m (outside the map counts as unset)."""
    p = np.pad(m, 1)
    return p[:-2, 1:-1] | p[2:, 1:-1] | p[1:-1, :-2] | p[1:-1, 2:]


def events_of(ev, agent, world=0):
    return {k for k in EVENT_KEYS if ev[k][world, agent]}


# ----------------------------------------------------------------------------- 1. moves
def test_obstacle_and_border_are_blocked(tmp_path):
    core = make_core(tmp_path, ["0@",
                                ".."])
    for action in (E_, N_, W_):  # obstacle, north border, west border
        ev = step(core, action)
        assert cells(core) == [(0, 0)]
        assert ev["blocked"][0, 0] and not ev["new"][0, 0] and not ev["revisit"][0, 0]
        assert not ev["waited"][0, 0]
        assert ev["reward"][0, 0] == pytest.approx(-2.0)  # time step -1, blocked -1
    ev = step(core, S_)
    assert cells(core) == [(1, 0)]
    assert events_of(ev, 0) == {"new"}
    assert ev["reward"][0, 0] == pytest.approx(0.0)  # -1 + 1
    ev = step(core, S_)  # south border, repeated action
    assert cells(core) == [(1, 0)]
    assert events_of(ev, 0) == {"blocked", "repeated_action"}
    ev = step(core, E_)  # the last free cell: (1, 1)
    assert cells(core) == [(1, 1)]
    assert ev["new"][0, 0] and ev["terminated"][0]


def test_wait_is_not_blocked(tmp_path):
    core = make_core(tmp_path, ["0.."])
    ev = step(core, WAIT_)
    assert cells(core) == [(0, 0)]
    assert events_of(ev, 0) == {"waited"}
    assert ev["reward"][0, 0] == pytest.approx(-1.0)
    ev = step(core, WAIT_)  # a repeated WAIT is not a repeated action (it is no move)
    assert events_of(ev, 0) == {"waited"}


def test_move_into_staying_agent_is_blocked(tmp_path):
    core = make_core(tmp_path, ["01.",
                                "..."])
    ev = step(core, E_, WAIT_)
    assert cells(core) == [(0, 0), (0, 1)]
    assert events_of(ev, 0) == {"blocked"}
    assert events_of(ev, 1) == {"waited"}
    # higher index into lower index staying agent (blocked by the border) is blocked too
    ev = step(core, N_, W_)
    assert cells(core) == [(0, 0), (0, 1)]
    assert ev["blocked"][0].tolist() == [True, True]


@pytest.mark.parametrize("rows", [["0.1"], ["1.0"]])
def test_two_agents_one_cell_lower_index_wins(tmp_path, rows):
    core = make_core(tmp_path, rows)
    start = cells(core)
    toward = [E_ if start[i][1] == 0 else W_ for i in range(2)]
    ev = step(core, *toward)
    assert cells(core) == [(0, 1), start[1]]
    assert events_of(ev, 0) == {"new", "finished"}
    assert events_of(ev, 1) == {"blocked", "finished"}
    # size-invariant, K = 0.25, N = 2: r0 = 0.75*1 + 0.25*0 - 1 = -0.25,
    # r1 = 0.75*0 + 0.25*1 - 1 - 1 = -1.75
    np.testing.assert_allclose(ev["reward"][0], [-0.25, -1.75])


def test_following_is_allowed(tmp_path):
    core = make_core(tmp_path, ["01..",
                                "...."])
    ev = step(core, E_, E_)  # 0 enters the cell 1 leaves in the same step
    assert cells(core) == [(0, 1), (0, 2)]
    assert events_of(ev, 0) == {"revisit"}  # (0, 1) was agent 1's start: covered
    assert events_of(ev, 1) == {"new"}
    # and the other way round: agent 1 enters the cell agent 0 leaves
    ev = step(core, S_, W_)
    assert cells(core) == [(1, 1), (0, 1)]
    assert not ev["blocked"].any()


def test_swap_is_blocked_for_both(tmp_path):
    core = make_core(tmp_path, ["01.",
                                "..."])
    ev = step(core, E_, W_)
    assert cells(core) == [(0, 0), (0, 1)]
    assert ev["blocked"][0].tolist() == [True, True]
    # vertical swap
    core = make_core(tmp_path, ["0.",
                                "1."])
    ev = step(core, S_, N_)
    assert cells(core) == [(0, 0), (1, 0)]
    assert ev["blocked"][0].tolist() == [True, True]


def test_chain_behind_blocked_leader_is_blocked(tmp_path):
    core = make_core(tmp_path, ["012@",
                                "...."])
    ev = step(core, E_, E_, E_)  # 2 hits the obstacle, so 1 and then 0 cannot follow
    assert cells(core) == [(0, 0), (0, 1), (0, 2)]
    assert ev["blocked"][0].tolist() == [True, True, True]


def test_chain_behind_leader_that_loses_a_contest_is_blocked(tmp_path):
    # 1 (N) and 0 (E) both aim at (0, 1): 0 wins; 2 follows 1 (W into (1, 1)) so it is blocked
    # too, which needs a second pass of the safety controller.
    core = make_core(tmp_path, ["0...",
                                ".12."])
    ev = step(core, E_, N_, W_)
    assert cells(core) == [(0, 1), (1, 1), (1, 2)]
    assert ev["blocked"][0].tolist() == [False, True, True]
    assert ev["new"][0].tolist() == [True, False, False]


def test_rotation_of_four_agents_is_allowed(tmp_path):
    # Documented behaviour: a cycle of 4 agents around a 2x2 block is allowed (only 2-cycles,
    # i.e. swaps, are blocked): every agent enters the cell the next one leaves.
    core = make_core(tmp_path, ["01.",
                                "32."])
    ev = step(core, E_, S_, W_, N_)
    assert cells(core) == [(0, 1), (1, 1), (1, 0), (0, 0)]
    assert not ev["blocked"].any()
    assert ev["revisit"][0].all()  # all four cells were start cells


def test_bad_actions_raise(tmp_path):
    core = make_core(tmp_path, ["0.."])
    for bad in (5, -1, 99):
        with pytest.raises(ValueError):
            step(core, bad)
    assert core.steps[0] == 0 and core.battery[0] == core.budget[0]
    assert cells(core) == [(0, 0)]
    step(core, E_)  # still usable
    assert cells(core) == [(0, 1)]


# ----------------------------------------------------------------------------- 2. events
def test_new_revisit_repeated_and_finished(tmp_path):
    core = make_core(tmp_path, ["0..."])
    expected = [  # action, cell, events, reward (defaults: -1 step, +1 new, -1 blocked)
        (E_, (0, 1), {"new"}, 0.0),
        (E_, (0, 2), {"new", "repeated_action"}, 0.0),
        (W_, (0, 1), {"revisit"}, -1.0),
        (E_, (0, 2), {"revisit"}, -1.0),
        (E_, (0, 3), {"new", "repeated_action", "finished"}, 0.0),
    ]
    for i, (a, cell, evs, r) in enumerate(expected):
        ev = step(core, a)
        assert cells(core) == [cell], i
        assert events_of(ev, 0) == evs, i
        assert ev["reward"][0, 0] == pytest.approx(r), i
        last = i == len(expected) - 1
        assert ev["terminated"][0] == last and not ev["truncated"][0]


def test_battery_and_truncation(tmp_path):
    core = make_core(tmp_path, ["0..",
                                "..."])
    assert core.budget[0] == 5 * 2 * 3 == core.battery[0]
    for t in range(29):
        ev = step(core, WAIT_)
        assert not ev["truncated"][0] and not ev["terminated"][0] and not ev["timeout"].any()
        assert core.battery[0] == 29 - t
    ev = step(core, WAIT_)  # the 30th step empties the battery
    assert core.battery[0] == 0
    assert ev["truncated"][0] and not ev["terminated"][0]
    assert ev["timeout"][0, 0]


@pytest.mark.parametrize("factor, budget", [(2.0, 6), (1.5, 5), (0.1, 1)])
def test_battery_factor(tmp_path, factor, budget):
    core = make_core(tmp_path, ["0.."], battery_factor=factor)  # h*w = 3, ceil(factor*3)
    assert core.budget[0] == budget == core.battery[0]
    for _ in range(budget - 1):
        assert not step(core, WAIT_)["truncated"][0]
    assert step(core, WAIT_)["truncated"][0]


def test_finishing_on_last_battery_step_is_termination_only(tmp_path):
    core = make_core(tmp_path, ["0.."], battery_factor=0.6)  # ceil(1.8) = 2 steps
    assert core.budget[0] == 2
    ev = step(core, E_)
    assert not ev["terminated"][0] and not ev["truncated"][0]
    ev = step(core, E_)  # covers the last cell with the last battery step
    assert ev["terminated"][0] and not ev["truncated"][0]
    assert ev["finished"][0, 0] and not ev["timeout"][0, 0]


def test_terminated_and_truncated_never_both(tmp_path):
    cfg = gw.EnvConfig(size=4, number_obstacles=3, number_agents=2, battery_factor=1.0)
    core = gw.GridWorldCore(cfg, num_worlds=64, seed=3)
    core.reset()
    rng = np.random.default_rng(0)
    seen_term = seen_trunc = False
    for _ in range(core.budget.max()):
        ev = core.step(rng.integers(0, 5, (64, 2)))
        assert not (ev["terminated"] & ev["truncated"]).any()
        assert (ev["finished"] == ev["terminated"][:, None]).all()
        assert (ev["timeout"] == ev["truncated"][:, None]).all()
        seen_term |= ev["terminated"].any()
        seen_trunc |= ev["truncated"].any()
    assert seen_trunc  # 16 steps of random walk on a 4x4 map rarely covers everything


# ----------------------------------------------------------------------------- 3. rewards
THREE = ["0..",
         "1..",
         "2x."]  # all move E: 0 and 1 cover new cells, 2 revisits (2, 1)


@pytest.mark.parametrize("structure, gain, expected", [
    # competitive (7.3): r_i = -1 + new_i - blocked_i
    ("competitive", 0.25, [0.0, 0.0, -1.0]),
    ("competitive", 0.9, [0.0, 0.0, -1.0]),
    # cooperative (7.4): + K/(N-1) * sum_{j != i} new_j;  K/(N-1) = 0.125 | 0.25
    ("cooperative", 0.25, [0.125, 0.125, -0.75]),
    ("cooperative", 0.5, [0.25, 0.25, -0.5]),
    # size invariant (7.5): (1-K) new_i + K/(N-1) sum_{j != i} new_j - 1
    ("size_invariant", 0.25, [-0.125, -0.125, -0.75]),
    ("size_invariant", 0.5, [-0.25, -0.25, -0.5]),
    ("size_invariant", 1.0, [-0.5, -0.5, 0.0]),
    ("size_invariant", 0.0, [0.0, 0.0, -1.0]),
])
def test_multi_agent_reward_structures(tmp_path, structure, gain, expected):
    core = make_core(tmp_path, THREE, reward=gw.RewardParams(structure=structure, gain=gain))
    ev = step(core, E_, E_, E_)
    assert ev["new"][0].tolist() == [True, True, False]
    assert ev["revisit"][0].tolist() == [False, False, True]
    np.testing.assert_allclose(ev["reward"][0], expected, atol=1e-6)


@pytest.mark.parametrize("structure, expected2", [
    ("competitive", -2.0),  # -1 - 1
    ("cooperative", -1.75),  # -2 + 0.125 * 2
    ("size_invariant", -1.75),  # -2 + 0.125 * 2
])
def test_multi_agent_reward_with_blocked_agent(tmp_path, structure, expected2):
    core = make_core(tmp_path, THREE, reward=gw.RewardParams(structure=structure, gain=0.25))
    ev = step(core, E_, E_, W_)  # 2 runs into the west border
    assert ev["blocked"][0].tolist() == [False, False, True]
    assert ev["reward"][0, 2] == pytest.approx(expected2)


@pytest.mark.parametrize("structure", gw.STRUCTURES)
@pytest.mark.parametrize("gain", [0.25, 0.7])
def test_single_agent_reward_same_for_all_structures(tmp_path, structure, gain):
    core = make_core(tmp_path, ["0.."], reward=gw.RewardParams(structure=structure, gain=gain))
    rewards = [step(core, a)["reward"][0, 0] for a in (E_, W_, W_, WAIT_)]
    np.testing.assert_allclose(rewards, [0.0, -1.0, -2.0, -1.0])  # new, revisit, blocked, wait


def test_chapter5_reward(tmp_path):
    core = make_core(tmp_path, ["....",
                                ".0..",
                                "....",
                                "...."], reward=gw.RewardParams.chapter5())
    area = 16.0  # every term divided by h*w
    expected = [
        (E_, (1, 2), 1),  # new only
        (E_, (1, 3), 3),  # new + repeated + wall (east border)
        (W_, (1, 2), -5),  # revisit
        (W_, (1, 1), -5),  # revisit; the repeated action gives nothing without a new cell
        (W_, (1, 0), 4),  # new + repeated + wall + finished row 1
        (W_, (1, 0), -10),  # collision with the border; repeated gives nothing
        (N_, (0, 0), 2),  # new + wall; row 0 and column 0 still have open cells
        (S_, (1, 0), -5),  # revisit
        (S_, (2, 0), 3),  # new + repeated + wall; (3, 0) still open
        (S_, (3, 0), 4),  # new + repeated + wall + finished column 0
    ]
    for i, (a, cell, r) in enumerate(expected):
        ev = step(core, a)
        assert cells(core) == [cell], i
        assert ev["reward"][0, 0] == pytest.approx(r / area), i


# ----------------------------------------------------------------------------- 4. maps
def check_generated_map(core, b, n_req):
    """Algorithm 9/10 invariants of world b; returns (obstacle, free, starts)."""
    obstacle, covered = world_map(core, b)
    free = ~obstacle
    starts = core.agent_cells()[b][core.active[b]]
    s = [tuple(p) for p in starts.tolist()]
    assert len(set(s)) == len(s)
    assert all(free[p] for p in s)
    start_mask = np.zeros_like(free)
    start_mask[tuple(starts.T)] = True
    assert (covered == start_mask).all()  # no task settings: only the starts are covered
    # the fix only adds obstacles, so there are at least the requested ones; a cell filled by
    # the fix never touches the free region, so the obstacles touching it were all placed by
    # Algorithm 9 (at most the requested count)
    assert (obstacle & neighbours_any(free)).sum() <= n_req
    return obstacle, free, s


@pytest.mark.parametrize("seed", range(4))
def test_random_maps_single_agent_are_connected(seed):
    n_req = 20
    core = gw.GridWorldCore(gw.EnvConfig(size=8, number_obstacles=n_req), num_worlds=100,
                            seed=seed)
    core.reset()
    fixed = 0
    for b in range(core.B):
        assert core.hw[b].tolist() == [8, 8]
        obstacle, free, s = check_generated_map(core, b, n_req)
        assert obstacle.sum() >= n_req
        assert (bfs(free, s[0]) == free).all()  # Algorithm 10: every free cell reachable
        fixed += obstacle.sum() - n_req
    assert fixed > 0  # 20 obstacles in 8x8 do cut off pockets now and then: the fix is exercised


def test_random_maps_multi_agent_are_connected():
    n_req = 20
    core = gw.GridWorldCore(gw.EnvConfig(size=8, number_obstacles=n_req, number_agents=2),
                            num_worlds=100, seed=0)
    core.reset()
    split = 0
    for b in range(core.B):
        obstacle, free, s = check_generated_map(core, b, n_req)
        assert obstacle.sum() >= n_req
        split += (bfs(free, s[0]) != free).any()
    assert split == 0


def test_obstacles_random_and_zero_obstacles():
    core = gw.GridWorldCore(gw.EnvConfig(size=7, number_obstacles=15, obstacles_random=True),
                            num_worlds=300, seed=1)
    core.reset()
    counts = []
    for b in range(core.B):
        obstacle, _ = world_map(core, b)
        free = ~obstacle
        assert (bfs(free, core.agent_cells()[b, 0]) == free).all()
        assert (obstacle & neighbours_any(free)).sum() <= 15
        counts.append(obstacle.sum())
    assert min(counts) <= 3 and max(counts) >= 12  # uniform in [0, 15] plus fixed cells
    core = gw.GridWorldCore(gw.EnvConfig(size=7), num_worlds=20, seed=1)
    core.reset()
    assert all(world_map(core, b)[0].sum() == 0 for b in range(20))


def test_random_size_within_bounds():
    cfg = gw.EnvConfig(size=9, min_size=4, random_size=True, number_obstacles=3)
    core = gw.GridWorldCore(cfg, num_worlds=300, seed=2)
    core.reset()
    h, w = core.hw[:, 0], core.hw[:, 1]
    assert (h == w).all() and h.min() == 4 and h.max() == 9
    assert set(h.tolist()) == set(range(4, 10))
    assert (core.budget == 5 * h * w).all()
    cellsyx = core.agent_cells()[:, 0]
    assert (cellsyx >= 0).all() and (cellsyx[:, 0] < h).all() and (cellsyx[:, 1] < w).all()
    rng = np.random.default_rng(0)
    for _ in range(30):  # agents never leave their (smaller) map
        core.step(rng.integers(0, 5, (300, 1)))
        yx = core.agent_cells()[:, 0]
        assert (yx >= 0).all() and (yx[:, 0] < h).all() and (yx[:, 1] < w).all()


def test_many_agents_distinct_starts():
    core = gw.GridWorldCore(gw.EnvConfig(size=4, number_agents=6, number_obstacles=5),
                            num_worlds=200, seed=4)
    core.reset()
    for b in range(core.B):
        s = [tuple(p) for p in core.agent_cells()[b].tolist()]
        obstacle, covered = world_map(core, b)
        assert len(set(s)) == 6
        assert all(not obstacle[p] and covered[p] for p in s)
        assert core.n_poi_start[b] == (~obstacle).sum() - 6 >= 1


# ----------------------------------------------------------------------------- 5. tasks
def test_random_coverage_fraction():
    kmax, B = 0.7, 1000
    cfg = gw.EnvConfig(size=10, random_coverage=True, random_coverage_max=kmax)
    core = gw.GridWorldCore(cfg, num_worlds=B, seed=5)
    core.reset()
    c = core.c
    covered = core.covered[:, c:c + 10, c:c + 10].reshape(B, -1).copy()
    assert not core.obstacle[:, c:c + 10, c:c + 10].any()
    yx = core.agent_cells()[:, 0]
    covered[np.arange(B), yx[:, 0] * 10 + yx[:, 1]] = False  # the start is always covered
    fractions = covered.sum(1) / 99
    # "up to 70 %": per world a fraction drawn in [0, 0.7], mean 0.35; single worlds may only
    # overshoot 0.7 by binomial noise (sd ~0.05 for 99 cells)
    assert abs(fractions.mean() - kmax / 2) < 0.03
    assert fractions.max() < kmax + 0.2
    assert (fractions > kmax).mean() < 0.06
    assert fractions.min() < 0.05 and fractions.max() > 0.6
    assert (core.n_poi_start == 99 - covered.sum(1)).all()
    assert not core.metrics()["completed"].any()


def test_random_coverage_never_finished_at_reset():
    cfg = gw.EnvConfig(size=2, number_agents=1, random_coverage=True, random_coverage_max=0.99)
    core = gw.GridWorldCore(cfg, num_worlds=400, seed=6)
    core.reset()
    assert (core.n_poi_start >= 1).all()
    assert (core.remaining >= 1).all()
    ev = core.step(np.full((400, 1), WAIT_))
    assert not ev["terminated"].any()


@pytest.mark.parametrize("k", [1, 5])
def test_points_of_interest(k):
    core = gw.GridWorldCore(gw.EnvConfig(size=6, number_obstacles=4, number_agents=2,
                                         number_points_of_interest=k), num_worlds=100, seed=7)
    core.reset()
    for b in range(core.B):
        obstacle, covered = world_map(core, b)
        assert (~obstacle & ~covered).sum() == k
        for y, x in core.agent_cells()[b]:
            assert covered[y, x]
    assert (core.n_poi_start == k).all()


def test_point_to_point_terminates_at_the_point(tmp_path):
    core = make_core(tmp_path, ["0....."], seed=3, number_points_of_interest=1)
    _, covered = world_map(core, 0)
    assert (~covered).sum() == 1
    target = int(np.flatnonzero(~covered[0])[0])
    assert target >= 1
    for t in range(1, 6):
        ev = step(core, E_)
        assert ev["new"][0, 0] == (t == target)
        assert ev["terminated"][0] == (t == target)
        if t == target:
            break


# ----------------------------------------------------------------------------- 6. failures
def test_faulty_agent_freezes(tmp_path):
    core = make_core(tmp_path, ["0.....",
                                "1....."], faulty_agent_step=2)
    for _ in range(2):  # steps 0 and 1: both agents move
        ev = step(core, E_, E_)
        assert not ev["waited"].any()
    assert cells(core) == [(0, 2), (1, 2)]
    for t in range(3):  # from step 2 on the last agent is frozen whatever it is told
        ev = step(core, E_, E_)
        assert cells(core) == [(0, 3 + t), (1, 2)]
        assert events_of(ev, 1) == {"waited"}
        assert not ev["blocked"][0, 1]


def test_faulty_agent_index(tmp_path):
    core = make_core(tmp_path, ["0.....",
                                "1....."], faulty_agent_step=0, faulty_agent=0)
    ev = step(core, E_, E_)
    assert cells(core) == [(0, 0), (1, 1)]
    assert ev["waited"][0].tolist() == [True, False]


def known_cells(core):
    """Cells of the 1-row map that agent 0's observation shows as known (any map channel)."""
    m = core.observe()["map"][0, 0]  # (4, V, V), centred on the agent
    c = core.V // 2
    ay, ax = core.agent_cells()[0, 0]
    h, w = core.hw[0]
    known = (m[gw.POI] | m[gw.COVERED] | m[gw.OBSTACLE]) > 0
    return [x for x in range(w) if known[c - ay, c + x - ax]]


@pytest.mark.parametrize("failure, expected", [(1.0, [0, 1, 2, 3, 4, 5]),
                                               (0.0, [0, 1, 2, 3, 4, 5, 6])])
def test_sensor_failure(tmp_path, failure, expected):
    core = make_core(tmp_path, ["0......."], sensor="camera", sensor_range=1,
                     sensor_failure=failure)
    assert known_cells(core) == [0, 1]  # the 3x3 footprint at reset
    for _ in range(5):
        step(core, E_)
    # failed sensor: only the reset footprint plus the cells the agent itself stood on
    assert known_cells(core) == expected


def test_cells_walked_with_failed_sensor_stay_known_after_configure(tmp_path):
    core = make_core(tmp_path, ["0......."], sensor="camera", sensor_range=1,
                     sensor_failure=1.0)
    for _ in range(5):
        step(core, E_)
    assert known_cells(core) == [0, 1, 2, 3, 4, 5]
    core.configure(view_size=43)  # keeps the world in progress, repaints the canvas
    assert known_cells(core) == [0, 1, 2, 3, 4, 5]


# ----------------------------------------------------------------------------- 7. metrics
def test_metrics_on_corridor_walk(tmp_path):
    core = make_core(tmp_path, ["0..."])
    for a in (E_, E_, W_, E_, E_):  # one backtrack: 5 moves, 3 new cells
        ev = step(core, a)
    assert ev["terminated"][0]
    m = core.metrics()
    assert m["steps"][0] == 5 and m["new_cells"][0] == 3 and m["n_poi_start"][0] == 3
    assert m["overlap"][0] == pytest.approx((5 - 3) / 3)
    assert m["time_save"][0] == pytest.approx(5 / 3)
    assert m["rho"][0] == pytest.approx(5 / 4)
    assert m["completed"][0]


def test_metrics_wait_and_blocked(tmp_path):
    core = make_core(tmp_path, ["0...",
                                "@@@@"])
    # WAIT is a step but not a move; a blocked move is a (wasted) move
    for a in (WAIT_, W_, E_, E_, E_):
        step(core, a)
    m = core.metrics()
    assert m["steps"][0] == 5 and m["new_cells"][0] == 3
    assert m["overlap"][0] == pytest.approx((4 - 3) / 3)
    assert m["time_save"][0] == pytest.approx(5 / 3)
    assert m["rho"][0] == pytest.approx(5 / 4)


# ----------------------------------------------------------------------------- 8. agents
def test_number_agent_random_and_inactive_agents():
    K = 0.25
    cfg = gw.EnvConfig(size=6, number_agents=3, number_agent_random=True, number_obstacles=4)
    core = gw.GridWorldCore(cfg, num_worlds=200, seed=8)
    core.reset()
    active = core.active.copy()
    n = active.sum(1)
    assert n.min() == 1 and n.max() == 3 and set(n.tolist()) == {1, 2, 3}
    assert (active == (np.arange(3) < n[:, None])).all()  # the first n agents are active
    parked = core.agent_cells()[~active]
    rng = np.random.default_rng(1)
    for _ in range(25):
        ev = core.step(rng.integers(0, 5, (200, 3)))
        assert (core.agent_cells()[~active] == parked).all()
        assert (ev["reward"][~active] == 0).all()
        for k in EVENT_KEYS:
            assert not ev[k][~active].any()
        new, blocked = ev["new"].astype(float), ev["blocked"].astype(float)
        others = (new.sum(1, keepdims=True) - new) / np.maximum(n[:, None] - 1, 1)
        own = np.where(n[:, None] > 1, 1 - K, 1.0)
        expected = np.where(active, own * new + K * others - 1 - blocked, 0.0)
        np.testing.assert_allclose(ev["reward"], expected, atol=1e-6)
        yx = core.agent_cells()[active]
        assert len({(b, y, x) for b, (y, x) in zip(np.nonzero(active)[0], yx.tolist())}) == len(yx)


# ----------------------------------------------------------------------------- 9. settings
def test_configure_larger_size():
    core = gw.GridWorldCore(gw.EnvConfig(size=5, number_obstacles=3), num_worlds=3, seed=9)
    core.reset()
    rng = np.random.default_rng(2)
    for _ in range(4):
        core.step(rng.integers(0, 4, (3, 1)))
    before = core.agent_cells().copy()
    maps = [world_map(core, b) for b in range(3)]
    steps = core.steps.copy()
    core.configure(size=12)
    # worlds in progress keep going unchanged until their next reset
    assert (core.agent_cells() == before).all() and (core.hw == 5).all()
    for b in range(3):
        for old, new in zip(maps[b], world_map(core, b)):
            assert (old == new).all()
    core.step(np.full((3, 1), WAIT_))
    assert (core.steps == steps + 1).all()
    core.reset()
    assert (core.hw == 12).all() and (core.budget == 5 * 144).all()
    for _ in range(50):
        core.step(rng.integers(0, 5, (3, 1)))
        yx = core.agent_cells()[:, 0]
        assert (yx >= 0).all() and (yx < 12).all()
    assert (core.new_cells > 0).all()


def test_partial_reset_leaves_other_worlds_untouched():
    core = gw.GridWorldCore(gw.EnvConfig(size=6, number_obstacles=5, number_agents=2),
                            num_worlds=4, seed=10)
    core.reset()
    rng = np.random.default_rng(3)
    for _ in range(6):
        core.step(rng.integers(0, 5, (4, 2)))
    keep = [1, 3]
    snap = dict(cells=core.agent_cells().copy(), battery=core.battery.copy(),
                steps=core.steps.copy(), new=core.new_cells.copy(),
                maps=[world_map(core, b) for b in range(4)],
                obs=core.observe()["map"].copy())
    core.reset(np.array([True, False, True, False]))
    assert (core.agent_cells()[keep] == snap["cells"][keep]).all()
    assert (core.battery[keep] == snap["battery"][keep]).all()
    assert (core.steps[keep] == snap["steps"][keep]).all()
    assert (core.new_cells[keep] == snap["new"][keep]).all()
    for b in keep:
        for old, new in zip(snap["maps"][b], world_map(core, b)):
            assert (old == new).all()
    assert (core.observe()["map"][keep] == snap["obs"][keep]).all()
    assert (core.steps[[0, 2]] == 0).all() and (core.battery[[0, 2]] == core.budget[[0, 2]]).all()
    # reset by indices works too
    core.reset([3])
    assert core.steps[3] == 0 and core.steps[1] == snap["steps"][1]


def test_reset_into_given_scenarios_restores_a_snapshot():
    core = gw.GridWorldCore(gw.EnvConfig(size=9, number_obstacles=8), num_worlds=3, seed=2)
    core.reset()
    rng = np.random.default_rng(0)
    for _ in range(6):
        core.step(rng.integers(0, 4, (3, 1)))
    kept = core.snapshot([1])  # world 1 as it is now: map, agent cell, coverage
    other = core.snapshot([0, 2])
    core.reset([2], scenarios=kept)
    assert (core.agent_cells()[2] == kept[0].starts).all()
    obstacle, covered = world_map(core, 2)
    assert (obstacle == kept[0].obstacles).all() and (covered == kept[0].covered).all()
    assert core.steps[2] == 0 and core.battery[2] == core.budget[2]
    again = core.snapshot([0])[0]  # world 0 untouched
    assert (again.covered == other[0].covered).all()
    with pytest.raises(ValueError, match="2 scenarios for 1 worlds"):
        core.reset([0], scenarios=kept * 2)


def test_random_coverage_probability():
    cfg = gw.EnvConfig(size=10, random_coverage=True, random_coverage_max=0.66, random_coverage_prob=0.5)
    core = gw.GridWorldCore(cfg, num_worlds=400, seed=3)
    core.reset()
    pre = core.n_free - core.n_poi_start - 1  # pre-covered cells besides the start
    assert 0.35 < (pre == 0).mean() < 0.65  # about half the episodes start uncovered
    with pytest.raises(ValueError, match="random_coverage_prob"):
        gw.EnvConfig(random_coverage_prob=1.5).validate()
