"""The far-first heuristic (gridworld.heuristic_actions(core, far_first=True), classical_cpp's greedy-far-first).

Among the nearest points of interest it takes, with dead-ends-first, one with no target neighbour (a hole if left)
first, then the one with the fewest (target neighbours - steps from the start); without dead-ends-first the most
steps from the start; then the first in row-major order. In a team also minus twice the mean steps to the working
teammates, and only targets in the agent's Voronoi region (its far half first when it holds over 1.5 x the team's
mean, with three working agents or more) while it has any, else in the busiest teammate's (by hand). Checked against
a plain breadth-first reference on part-walked maps: the next cell the heuristic covers is the reference's choice.
The rollout's walkers take the same moves (tests/test_walkers.py).
"""
from __future__ import annotations

from collections import deque

import numpy as np
import pytest

import classical_cpp as cc
import gridworld as gw


def steps_from(free: np.ndarray, cells: list[tuple[int, int]]) -> np.ndarray:
    """Breadth-first steps from the nearest of `cells` over `free` (-1 where unreachable), one cell at a time."""
    dist = np.full(free.shape, -1)
    queue = deque(cells)
    for c in cells:
        dist[c] = 0
    while queue:
        y, x = queue.popleft()
        for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1)):
            ny, nx = y + dy, x + dx
            if 0 <= ny < free.shape[0] and 0 <= nx < free.shape[1] and free[ny, nx] and dist[ny, nx] < 0:
                dist[ny, nx] = dist[y, x] + 1
                queue.append((ny, nx))
    return dist


def reference_goal(free, target, agent, start, dead_ends_first: bool) -> tuple[int, int]:
    from_agent, from_start = steps_from(free, [agent]), steps_from(free, [start])
    reach = target & (from_agent >= 0)
    nearest = reach & (from_agent == from_agent[reach].min())
    best = None
    for y, x in zip(*np.nonzero(nearest)):  # row-major
        degree = sum(target[y + dy, x + dx] for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1))
                     if 0 <= y + dy < free.shape[0] and 0 <= x + dx < free.shape[1])
        key = ((degree > 0, degree) if dead_ends_first else (0, 0)) + (-from_start[y, x],)  # holes first
        key = (key[0], key[1] + key[2])
        if best is None or key < best[0]:
            best = (key, (int(y), int(x)))
    return best[1]


@pytest.mark.parametrize("family", ["rooms", "maze", "clutter"])
@pytest.mark.parametrize("dead_ends_first", [True, False])
def test_far_first_covers_the_reference_goal_next(family, dead_ends_first):
    core = gw.GridWorldCore(gw.EnvConfig(size=12, map_family=family, number_obstacles=14, obstacles_random=True,
                                         battery_factor=1e6), 6, seed=3)
    core.reset()
    c, H, W = core.c, core.H, core.W
    start = [tuple(int(v) for v in core.agent_cells()[b, 0]) for b in range(core.B)]
    rng = np.random.default_rng(0)
    for _ in range(15):  # part-walk by random moves so the agents are away from their starts
        core.step(rng.integers(0, 4, (core.B, 1)))
    checked = 0
    for _ in range(40):
        free, covered = ~core.obstacle[:, c:c + H, c:c + W], core.covered[:, c:c + H, c:c + W].copy()
        live = core.remaining > 0
        want = [reference_goal(free[b], free[b] & ~covered[b], tuple(core.agent_cells()[b, 0]), start[b],
                               dead_ends_first) if live[b] else None for b in range(core.B)]
        got = [None] * core.B
        for _ in range(2 * H * W):  # follow the heuristic until each world covers a new cell
            before = core.covered[:, c:c + H, c:c + W].copy()
            core.step(np.where(live, gw.heuristic_actions(core, False, dead_ends_first, far_first=True)[:, 0], gw.WAIT)[:, None])
            new = core.covered[:, c:c + H, c:c + W] & ~before
            for b in np.flatnonzero(new.any((1, 2)) & live):
                got[b] = tuple(int(v) for v in np.argwhere(new[b])[0]) if got[b] is None else got[b]
            if all(g is not None for g, ok in zip(got, live) if ok):
                break
        assert got == want
        checked += int(live.sum())
    assert checked > 100


def test_far_first_sweeps_away_from_the_start_by_hand():
    """A 3x3 room entered at the top-left corner and walked to the middle of the right side ((0, 0) -> (0, 2)
    -> (1, 2)): the nearest points of interest are W (1, 1) and S (2, 2), one step away. (1, 1) comes first
    row-major and has more target neighbours (2 against 1); (2, 2) is farther from the start (4 steps against 2).
    Row-major greedy goes W; far-first goes S, with or without dead-ends."""
    covered = np.zeros((3, 3), bool)
    covered[0, :] = True
    s = gw.Scenario(np.zeros((3, 3), bool), np.array([[0, 0]]), covered)
    moves = {}
    for dead_ends_first, far_first in ((False, False), (False, True), (True, True)):
        core = gw.GridWorldCore(gw.EnvConfig(load_state=True, battery_factor=1e6), 1)
        core.configure(scenarios=[s])
        core.reset()
        for a in (3, 3, 1):  # E, E, S
            core.step(np.array([[a]]))
        assert core.agent_cells()[0, 0].tolist() == [1, 2]
        moves[dead_ends_first, far_first] = int(gw.heuristic_actions(core, False, dead_ends_first, far_first)[0, 0])
    assert moves == {(False, False): 2, (False, True): 1, (True, True): 1}  # W = 2, S = 1


def test_in_a_team_far_first_sends_each_agent_away_from_its_teammate_by_hand():
    """A 1x5 corridor, agent 0 at column 3 and agent 1 at column 1 (their starts covered); the points of interest
    0, 2 and 4 are each one step from an agent, none has a target neighbour and each is one step from a start.
    Agent 0's are 2 (one step from agent 1) and 4 (three steps): far-first takes 4 (E), row-major 2 (W). Agent 1's
    are 0 (two steps from agent 0) and 2 (one step): 0 (W) either way. A frozen teammate pulls nobody: agent 0
    alone goes W, row-major, as in a single-agent world."""
    s = gw.Scenario(np.zeros((1, 5), bool), np.array([[0, 3], [0, 1]]))
    moves = {}
    for dead_ends_first, far_first in ((True, False), (False, True), (True, True)):
        core = gw.GridWorldCore(gw.EnvConfig(load_state=True, number_agents=2, battery_factor=1e6), 1)
        core.configure(scenarios=[cc.with_starts(s)])
        core.reset()
        moves[dead_ends_first, far_first] = gw.heuristic_actions(core, False, dead_ends_first, far_first)[0].tolist()
    assert moves == {(True, False): [gw.WEST, gw.WEST], (False, True): [gw.EAST, gw.WEST],
                     (True, True): [gw.EAST, gw.WEST]}
    core.frozen[0, 1] = core.any_frozen = True
    assert gw.heuristic_actions(core, False, True, True)[0, 0] == gw.WEST


def test_in_a_team_far_first_weighs_the_mean_steps_to_every_teammate_by_hand():
    """A 1x9 corridor, agent 0 at column 4, teammates at columns 2, 7 and 8 (starts covered). Agent 0's nearest
    points of interest are 3 and 5, each one step from a start. Steps from 3 to the teammates: 1, 4, 5 (mean 3);
    from 5: 3, 2, 3 (mean 2, though its nearest teammate is the farther one). Without dead-ends-first agent 0
    goes W, to 3 (-2 x 3 < -2 x 2); with it, 3 is a hole (no target neighbour) and comes first anyway. With the
    teammates at 7 and 8 frozen only the one at 2 counts: 3 is one step from it, 5 three, so agent 0 goes E."""
    s = gw.Scenario(np.zeros((1, 9), bool), np.array([[0, 4], [0, 2], [0, 7], [0, 8]]))
    core = gw.GridWorldCore(gw.EnvConfig(load_state=True, number_agents=4, battery_factor=1e6), 1)
    core.configure(scenarios=[cc.with_starts(s)])
    core.reset()
    assert gw.heuristic_actions(core, False, False, True)[0, 0] == gw.WEST
    assert gw.heuristic_actions(core, False, True, True)[0, 0] == gw.WEST
    core.frozen[0, 2:] = core.any_frozen = True
    assert gw.heuristic_actions(core, False, False, True)[0, 0] == gw.EAST


def test_in_a_team_far_first_chases_only_targets_in_the_agents_voronoi_region_by_hand():
    """A 1x9 corridor, agent 0 at column 3, agent 1 at column 6; columns 1-4 and 6 covered, so the points of
    interest are 0, 5, 7 and 8. Without dead-ends-first agent 1 takes 7 (5 is two steps from agent 0, 7 four:
    -1 - 2 x 4 < -1 - 2 x 2) and the claims would leave 5 (two steps) to agent 0, ahead of 0 (three). But 5 is one
    step from agent 1: agent 0's region is columns 0-4, so it goes W, to 0. With column 0 covered too its region
    holds no point of interest, it keeps them all and goes E, to 5."""
    moves = []
    for zero_covered in (False, True):
        covered = np.zeros((1, 9), bool)
        covered[0, [0, 1, 2, 3, 4, 6] if zero_covered else [1, 2, 3, 4, 6]] = True
        s = gw.Scenario(np.zeros((1, 9), bool), np.array([[0, 3], [0, 6]]), covered)
        core = gw.GridWorldCore(gw.EnvConfig(load_state=True, number_agents=2, battery_factor=1e6), 1)
        core.configure(scenarios=[cc.with_starts(s)])
        core.reset()
        moves.append(gw.heuristic_actions(core, False, False, True)[0].tolist())
    assert moves == [[gw.WEST, gw.EAST], [gw.EAST, gw.EAST]]


def test_in_a_team_an_agent_with_an_empty_region_helps_the_one_with_the_most_left_by_hand():
    """A 1x13 corridor, agent 0 at column 5, agent 1 at 1, agent 2 at 10; columns 3-8 covered, so the points of
    interest are 0 and 2 (agent 1's region: 2 of them) and 9, 11 and 12 (agent 2's: 3). Agent 0's region (columns
    3-7) holds none, so it helps agent 2, the busiest: E, to 9 (four steps), though 2 (three steps) is nearer and
    agent 1 claims 0, not 2 (farther from its teammates). With or without dead-ends-first."""
    covered = np.zeros((1, 13), bool)
    covered[0, 3:9] = True
    s = gw.Scenario(np.zeros((1, 13), bool), np.array([[0, 5], [0, 1], [0, 10]]), covered)
    core = gw.GridWorldCore(gw.EnvConfig(load_state=True, number_agents=3, battery_factor=1e6), 1)
    core.configure(scenarios=[cc.with_starts(s)])
    core.reset()
    assert gw.heuristic_actions(core, False, False, True)[0].tolist() == [gw.EAST, gw.WEST, gw.EAST]
    assert gw.heuristic_actions(core, False, True, True)[0, 0] == gw.EAST


@pytest.mark.parametrize("agent_0, covered_columns", [(7, [0, 1, 7, 8]), (9, [0, 1, 9, 10, 11, 12])],
                         ids=["over twice the mean", "over 1.5 x the mean"])
def test_in_a_team_an_overloaded_agent_takes_the_far_half_of_its_region_first_by_hand(agent_0, covered_columns):
    """A 1x17 corridor, agent 1 at column 1 and agent 2 at 0, so agent 2's region holds no point of interest.
    Agent 0 at 7, columns 0-1, 7 and 8 covered: agent 1's region holds 2, 3 and 4 (4 is as near to agent 0), agent
    0's 4-6 and 9-16: 11, over 1.5 x the mean (14 / 3). Steps from agent 0's targets to its nearest teammate
    (agent 1): 3-5 for 4-6, 8-15 for 9-16, so its far half is 9-16 (at least 15 / 2 steps) and it goes E, though
    6 (one step) is nearer than 9 (two). Agent 0 at 9, columns 0-1 and 9-12 covered: agent 1's region holds 2-5
    (5 is as near to agent 0): 4; agent 0's 5-8 and 13-16: 8, over 1.5 x the mean (12 / 3) though not over twice
    it. Its targets lie 4-7 and 12-15 steps from agent 1, so its far half is 13-16 and it goes E, though 8 (one
    step) is nearer than 13 (four). With agent 2 frozen two agents work, the far half is for three or more, and
    agent 0 goes W, to the nearest target."""
    covered = np.zeros((1, 17), bool)
    covered[0, covered_columns] = True
    s = gw.Scenario(np.zeros((1, 17), bool), np.array([[0, agent_0], [0, 1], [0, 0]]), covered)
    core = gw.GridWorldCore(gw.EnvConfig(load_state=True, number_agents=3, battery_factor=1e6), 1)
    core.configure(scenarios=[cc.with_starts(s)])
    core.reset()
    assert gw.heuristic_actions(core, False, False, True)[0, 0] == gw.EAST
    assert gw.heuristic_actions(core, False, True, True)[0, 0] == gw.EAST
    core.freeze([0], 2)
    assert gw.heuristic_actions(core, False, True, True)[0, 0] == gw.WEST


def test_in_a_team_the_teammate_term_is_twice_the_mean_steps_rounded_once_by_hand():
    """A 2x5 room, `o` covered, agents 0-3 where their digits are:
        o3..2
        o0o1.
    The points of interest: (0,2) in agent 3's region, (0,3) and (1,4) in agents 1 and 2's (one step from each);
    agent 0's region is empty. For agent 1 both are one step away and one step from the nearest start; their
    Manhattan steps to its teammates 0, 2 and 3 sum to 3 + 1 + 2 = 6 and 3 + 1 + 4 = 8. Twice the mean,
    2 x 6 // 3 = 4 and 2 x 8 // 3 = 5, puts (1,4) first: E (flooring the mean before doubling would tie them at 4,
    and row-major order would take (0,3): N). Agent 2's sums are the same, so it prefers (1,4) too; agent 1 claims
    it first (the lower index) and agent 2 takes (0,3): W. Agent 3 goes E, to (0,2); agent 0 (helping agent 1)
    finds every target claimed and waits. Without dead-ends-first: with it (1,4), a hole, comes first anyway."""
    covered = np.array([[1, 1, 0, 0, 1], [1, 1, 1, 1, 0]], bool)
    s = gw.Scenario(np.zeros((2, 5), bool), np.array([[1, 1], [1, 3], [0, 4], [0, 1]]), covered)
    core = gw.GridWorldCore(gw.EnvConfig(load_state=True, number_agents=4, battery_factor=1e6), 1)
    core.configure(scenarios=[cc.with_starts(s)])
    core.reset()
    assert gw.heuristic_actions(core, False, False, True)[0].tolist() == [gw.WAIT, gw.EAST, gw.WEST, gw.EAST]


def test_greedy_far_first_planner_covers_every_map():
    scenarios = gw.generate_scenarios(8, seed=5, size=10, map_family="rooms")
    for s, paths in zip(scenarios, cc.plan("greedy-far-first", scenarios)):
        assert cc.replay(s, paths)["completed"]
