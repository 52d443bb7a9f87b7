"""Classical coverage planners, multi-agent baselines and a near-optimal reference.

Every planner takes a map with its start(s) (a gridworld.Scenario) and returns one path per
agent: an array of [row, col] cells, one per time step, consecutive cells 4-adjacent (or equal:
the agent waits). `replay` runs the paths through gridworld's own environment, so every metric
(steps, overlap, time-save factor) is counted by the same code that scores the learned agents,
and it rejects illegal or incomplete paths.

    python classical_cpp.py --planner boustrophedon --maps maps/external/room-32-32-4.map
    python classical_cpp.py --planner greedy --dataset maps/cpp_eval.npz --limit 200
    python classical_cpp.py --planner partition --dataset maps/marl_eval.npz --agents 5
    python classical_cpp.py --report --out DIR     # every planner on the report's maps -> DIR/classical_cpp.json
    python classical_cpp.py --report --overwrite   # ... -> results/classical_cpp.json, replacing the committed one
    python classical_cpp.py --report --structured-per-band 1 --per-size 2 --out DIR   # a quicker one

Single agent: greedy (the navigation heuristic run to completion), greedy-dead-ends (the same
with Warnsdorff's tie-break: of the nearest uncovered cells, the one with the fewest uncovered
neighbours first; also for several agents), boustrophedon (BA*-style
back-and-forth with shortest-path repositioning), spiral-stc (Spiral-STC on 2x2 blocks, partly
blocked blocks kept), wavefront (Zelinsky's distance transform), lkh (the TSP over the
shortest-path metric closure solved by LKH-3 through elkai: the near-optimal reference), rollout
(one-step lookahead: each move finished by a base, greedy-dead-ends by default, the best taken; also
for several agents, one agent after the other).
Several agents: greedy (with claims), partition (balanced connected regions, then greedy in
each), and `lower_bound`: no schedule is shorter than ceil(n_poi / N) steps or than the checkerboard
parity of the cells allows.
"""
from __future__ import annotations

import heapq
import json
import math
import os
import sys
import time
from collections import deque
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

import gridworld
from gridworld import EnvConfig, GridWorldCore, Scenario

MOVES = ((-1, 0), (1, 0), (0, -1), (0, 1))  # N, S, W, E: the gridworld action order
LKH_TIME_LIMIT = 10.0  # seconds of LKH search per map (plus reading the problem)
ROOT = os.path.dirname(os.path.abspath(__file__))
REPORT_PLANNERS = ("greedy", "rollout", "boustrophedon", "spiral-stc", "wavefront", "lkh")
REPORT_BANDS = ((5, 10), (11, 15), (16, 20), (21, 25), (26, 30))  # the map-size bands --report averages the overlap over
REPORT_AGENTS = (2, 5, 10)
STRUCTURED_PLANNERS = ("greedy", "greedy-dead-ends", "boustrophedon", "spiral-stc", "wavefront", "rollout", "lkh")
STRUCTURED_BANDS = ((10, 15), (16, 20), (21, 25), (26, 30))  # structured_eval's sizes, in bands
STRUCTURED_PER_BAND = 3  # maps per family and band: 48 maps, ~15 min of planners on one core (LKH, rollout)
MARL_MIN_SIZE, MARL_EVERY = 10, 5  # the multi-agent baselines: every 5th marl_eval layout of sizes 10-30
TEAM_PLANNERS = ("greedy", "greedy-dead-ends", "rollout")  # the multiagent rollout beside its base and greedy
TEAM_AGENTS, TEAM_MARL_EVERY, TEAM_STRUCTURED_EVERY = (2, 5, 10), 100, 21  # 21 marl_eval maps, 80 structured_eval maps


# ----------------------------------------------------------------------------- the grid graph
class Grid:
    """The free cells of a map as a graph over flat indices y * w + x."""

    def __init__(self, obstacles: np.ndarray):
        self.h, self.w = obstacles.shape
        self.free = ~obstacles.ravel()
        self.neighbours = [[] for _ in range(self.h * self.w)]
        for y in range(self.h):
            for x in range(self.w):
                if self.free[y * self.w + x]:
                    self.neighbours[y * self.w + x] = [
                        (y + dy) * self.w + x + dx for dy, dx in MOVES
                        if 0 <= y + dy < self.h and 0 <= x + dx < self.w
                        and self.free[(y + dy) * self.w + x + dx]]

    def bfs(self, source: int) -> np.ndarray:
        """Shortest-path distances from `source` to every cell (-1 where unreachable)."""
        dist = np.full(self.h * self.w, -1, np.int64)
        dist[source] = 0
        queue = deque([source])
        while queue:
            u = queue.popleft()
            for v in self.neighbours[u]:
                if dist[v] < 0:
                    dist[v] = dist[u] + 1
                    queue.append(v)
        return dist

    def walk(self, a: int, b: int, dist_to_b: np.ndarray) -> list[int]:
        """The cells of a shortest path a -> b (a excluded, b included), each move the first
        in N, S, W, E order that gets closer, given the distances to b."""
        path = []
        while a != b:
            a = next(v for v in self.neighbours[a] if dist_to_b[v] == dist_to_b[a] - 1)
            path.append(a)
        return path

    def nearest(self, source: int, wanted: np.ndarray, rank: np.ndarray | None = None) -> list[int]:
        """Shortest path from `source` to the nearest `wanted` cell (ties: the lowest `rank`,
        else the first in row-major order), source excluded; [] if none is reachable."""
        dist = np.full(self.h * self.w, -1, np.int64)
        dist[source] = 0
        layer, parent = [source], {source: source}
        while layer:
            hits = [u for u in layer if wanted[u] and u != source]
            if hits:
                goal = min(hits, key=lambda u: (rank[u], u) if rank is not None else u)
                path = [goal]
                while parent[path[-1]] != source:
                    path.append(parent[path[-1]])
                return path[::-1]
            nxt = []
            for u in layer:
                for v in self.neighbours[u]:
                    if dist[v] < 0:
                        dist[v] = dist[u] + 1
                        parent[v] = u
                        nxt.append(v)
            layer = nxt
        return []


def _cells(grid: Grid, path: list[int]) -> np.ndarray:
    return np.stack(np.divmod(np.asarray(path, np.int64), grid.w), 1)


def _grid(scenario: Scenario) -> Grid:
    """The scenario's free-cell graph, after gridworld's checks (starts, connectivity)."""
    gridworld.check_scenario(scenario, "scenario")
    return Grid(scenario.obstacles)


def _start(scenario: Scenario, grid: Grid) -> int:
    if scenario.starts is None or len(scenario.starts) != 1:
        raise ValueError("a single-agent planner needs exactly one start")
    y, x = scenario.starts[0]
    return int(y) * grid.w + int(x)


def _uncovered(scenario: Scenario, grid: Grid) -> np.ndarray:
    covered = np.zeros_like(grid.free) if scenario.covered is None else scenario.covered.ravel().copy()
    return grid.free & ~covered


def _cover(grid: Grid, path: list[int], todo: np.ndarray, step=lambda pos, todo: None,
           rank: np.ndarray | None = None) -> list[int]:
    """Extend `path` until no `todo` cell is left: take `step(pos, todo)` (an uncovered
    neighbour, or None) and at a dead end walk a shortest path to the nearest todo cell (ties:
    lowest `rank`, then row-major order)."""
    while todo.any():
        nxt = step(path[-1], todo)
        leg = [nxt] if nxt is not None else grid.nearest(path[-1], todo, rank)
        if not leg:
            raise ValueError("some free cells are unreachable from the start")
        path += leg
        todo[leg] = False
    return path


# ----------------------------------------------------------------------------- single agent
def boustrophedon(scenario: Scenario) -> list[np.ndarray]:
    """BA*-style coverage: move N, else S, else E, else W into an uncovered cell (column-wise
    back-and-forth sweeps); at a dead end, walk a shortest path to the nearest uncovered cell
    (ties: first in row-major order) and sweep on."""
    grid = _grid(scenario)
    pos = _start(scenario, grid)
    todo = _uncovered(scenario, grid)
    todo[pos] = False

    def sweep(pos, todo):
        y, x = divmod(pos, grid.w)
        for dy, dx in (MOVES[0], MOVES[1], MOVES[3], MOVES[2]):  # N, S, E, W
            ny, nx = y + dy, x + dx
            if 0 <= ny < grid.h and 0 <= nx < grid.w and todo[ny * grid.w + nx]:
                return ny * grid.w + nx
        return None

    return [_cells(grid, _cover(grid, [pos], todo, sweep))]


def wavefront(scenario: Scenario) -> list[np.ndarray]:
    """Zelinsky's distance-transform coverage (§3.4.1): the distance transform grows from the
    goal (the free cell farthest from the start); the robot steps to the uncovered neighbour
    with the highest value, else walks a shortest path (no jumps) to the nearest uncovered
    cell, ties going to the highest value."""
    grid = _grid(scenario)
    pos = _start(scenario, grid)
    goal = int(np.argmax(grid.bfs(pos)))
    transform = grid.bfs(goal)
    todo = _uncovered(scenario, grid)
    todo[pos] = False

    def descend(pos, todo):
        options = [v for v in grid.neighbours[pos] if todo[v]]
        return max(options, key=lambda v: transform[v]) if options else None

    return [_cells(grid, _cover(grid, [pos], todo, descend, rank=-transform))]


def spiral_stc(scenario: Scenario) -> list[np.ndarray]:
    """Spiral-STC (Gabriely & Rimon) on 2x2 blocks. A block is usable if ANY of its cells is
    free, so partly blocked blocks are covered too: the spanning tree of usable blocks (joined
    where two facing cells are free) is grown depth-first with a spiral (counter-clockwise)
    preference, its circumnavigation visits the cells of every tree block in order, blocked
    cells are skipped and consecutive free cells are joined by shortest paths; cells of blocks
    the tree misses are finished greedily."""
    grid = _grid(scenario)
    h, w = grid.h, grid.w
    H, W = -(-h // 2), -(-w // 2)
    free = np.zeros((2 * H, 2 * W), bool)
    free[:h, :w] = ~scenario.obstacles
    usable = free.reshape(H, 2, W, 2).any((1, 3))
    # blocks are neighbours only where two facing cells are both free (a real passage)
    east = (free[0::2, 1::2][:, :-1] & free[0::2, 2::2]) | (free[1::2, 1::2][:, :-1] & free[1::2, 2::2])
    south = (free[1::2, 0::2][:-1] & free[2::2, 0::2]) | (free[1::2, 1::2][:-1] & free[2::2, 1::2])

    def joined(a, b):
        if a[0] == b[0]:
            return east[a[0], min(a[1], b[1])]
        return south[min(a[0], b[0]), a[1]]
    pos = _start(scenario, grid)
    root = (pos // w // 2, pos % w // 2)
    # the spanning tree: depth-first, turning counter-clockwise from where we came from
    ccw = [(-1, 0), (0, -1), (1, 0), (0, 1)]  # N, W, S, E
    tree = {root: []}
    stack = [(root, 0)]
    while stack:
        block, heading = stack[-1]
        for turn in range(4):
            k = (heading + 1 + turn) % 4  # start left of the heading: a spiral
            nb = (block[0] + ccw[k][0], block[1] + ccw[k][1])
            if 0 <= nb[0] < H and 0 <= nb[1] < W and usable[nb] and nb not in tree and joined(block, nb):
                tree[nb] = []
                tree[block].append(nb)
                stack.append((nb, (k + 2) % 4))
                break
        else:
            stack.pop()
    # the circumnavigation: within a block the cells form the cycle TL-TR-BR-BL; a tree edge
    # opens the two facing sides and links the blocks' cells in their place
    link: dict[tuple, set] = {}

    def cell(by, bx, dy, dx):
        return (2 * by + dy, 2 * bx + dx)

    for (by, bx) in tree:
        ring = [cell(by, bx, 0, 0), cell(by, bx, 0, 1), cell(by, bx, 1, 1), cell(by, bx, 1, 0)]
        for a, b in zip(ring, ring[1:] + ring[:1]):
            link.setdefault(a, set()).add(b)
            link.setdefault(b, set()).add(a)
    for (by, bx), children in tree.items():
        for (cy, cx) in children:
            if cy == by:  # east-west edge
                left, right = ((by, bx), (cy, cx)) if cx > bx else ((cy, cx), (by, bx))
                pairs = [(cell(*left, 0, 1), cell(*left, 1, 1)), (cell(*right, 0, 0), cell(*right, 1, 0))]
                joins = [(cell(*left, 0, 1), cell(*right, 0, 0)), (cell(*left, 1, 1), cell(*right, 1, 0))]
            else:  # north-south edge
                top, bottom = ((by, bx), (cy, cx)) if cy > by else ((cy, cx), (by, bx))
                pairs = [(cell(*top, 1, 0), cell(*top, 1, 1)), (cell(*bottom, 0, 0), cell(*bottom, 0, 1))]
                joins = [(cell(*top, 1, 0), cell(*bottom, 0, 0)), (cell(*top, 1, 1), cell(*bottom, 0, 1))]
            for a, b in pairs:
                link[a].discard(b)
                link[b].discard(a)
            for a, b in joins:
                link[a].add(b)
                link[b].add(a)
    start = (pos // w, pos % w)
    order, prev, here = [start], None, start
    while True:  # follow the single cycle once round
        nxt = min(link[here] - {prev}) if prev is not None else min(link[here])
        if nxt == start:
            break
        order.append(nxt)
        prev, here = here, nxt
    todo = _uncovered(scenario, grid)
    todo[pos] = False
    path = [pos]
    for y, x in order[1:]:
        if y < h and x < w and todo[y * w + x]:
            target = y * w + x
            leg = [target] if target in grid.neighbours[path[-1]] else \
                grid.walk(path[-1], target, grid.bfs(target))
            path += leg
            todo[leg] = False
    return [_cells(grid, _cover(grid, path, todo))]


def lkh(scenario: Scenario, time_limit: float = LKH_TIME_LIMIT, runs: int = 1) -> list[np.ndarray]:
    """Near-optimal reference: an open tour from the start through every uncovered cell, over
    the shortest-path metric closure, solved by LKH-3 (elkai), then expanded into moves. A
    dummy city joined to the start at cost 0 and to every other city at a large cost turns
    LKH's closed tour into a path with a fixed start and a free end."""
    import elkai._elkai as lkh3  # the solver's own entry point, so a time limit can be set

    grid = _grid(scenario)
    pos = _start(scenario, grid)
    cities = [pos] + [int(c) for c in np.flatnonzero(_uncovered(scenario, grid)) if c != pos]
    if len(cities) <= 2:
        path = [pos] + [c for t in cities[1:] for c in grid.walk(pos, t, grid.bfs(t))]
        return [_cells(grid, path)]
    dist = np.stack([grid.bfs(c)[cities] for c in cities])
    if (dist < 0).any():
        raise ValueError("some free cells are unreachable from the start")
    n = len(cities)
    big = int(dist.max()) * n + 1
    matrix = np.zeros((n + 1, n + 1), np.int64)
    matrix[:n, :n] = dist
    matrix[n, 1:n] = matrix[1:n, n] = big
    problem = (f"TYPE : TSP\nDIMENSION : {n + 1}\nEDGE_WEIGHT_TYPE : EXPLICIT\n"
               "EDGE_WEIGHT_FORMAT : FULL_MATRIX\nEDGE_WEIGHT_SECTION\n"
               + "\n".join(" ".join(map(str, row)) for row in matrix.tolist()) + "\n")
    params = f"RUNS = {runs}\nPROBLEM_FILE = :stdin:\nTIME_LIMIT = {time_limit}\nSEED = 1\n"
    tour = [c - 1 for c in lkh3.solve_problem(params, problem)]
    k = tour.index(n)
    tour = tour[k + 1:] + tour[:k]  # the dummy's neighbours are the start and the free end
    if tour[0] != 0:
        tour = tour[::-1]
    path = [pos]
    for c in tour[1:]:
        path += grid.walk(path[-1], cities[c], grid.bfs(cities[c]))
    return [_cells(grid, path)]


# ----------------------------------------------------------------------------- greedy (batched)
def greedy_many(scenarios: list[Scenario], dead_ends_first: bool = False,
                far_first: bool = False) -> list[list[np.ndarray]]:
    """The navigation heuristic run to completion in gridworld itself, for many maps at once:
    nearest known point of interest, first in row-major order on ties (with dead_ends_first,
    the one with the fewest uncovered neighbours first; with far_first, the one farthest from
    the start first); several agents claim distinct targets (the nearest agent-target pair first)."""
    return _run_many(scenarios, lambda core, live: gridworld.heuristic_actions(core, False, dead_ends_first, far_first)[live])


def _run_many(scenarios: list[Scenario], act) -> list[list[np.ndarray]]:
    """Every agent's path when `act(core, live) -> (len(live), N)` actions steps the unfinished worlds `live` of a
    GridWorldCore (one batched core per number of agents) until every map is covered."""
    if not scenarios:
        return []
    by_agents: dict[int, list[int]] = {}
    for i, s in enumerate(scenarios):
        by_agents.setdefault(len(s.starts), []).append(i)
    out: list[list[np.ndarray]] = [[] for _ in scenarios]
    for n, rows in by_agents.items():  # one batched core per number of agents
        group = [scenarios[i] for i in rows]
        core = GridWorldCore(EnvConfig(load_state=True, load_random=False, number_agents=n,
                                       battery_factor=1e6), len(group))
        core.configure(scenarios=group)
        core.reset()
        trace = [core.agent_cells()]
        done = core.remaining == 0
        end = np.where(done, 0, -1)
        while not done.all():
            live = np.flatnonzero(~done)
            actions = np.full((core.B, n), gridworld.WAIT)
            actions[live] = act(core, live)
            core.step(actions)
            trace.append(core.agent_cells())
            finished = ~done & (core.remaining == 0)
            end[finished] = len(trace) - 1
            done |= finished
        trace = np.stack(trace, 1)  # (B, T, N, 2)
        for j, i in enumerate(rows):
            out[i] = [trace[j, :end[j] + 1, a].copy() for a in range(n)]
    return out


def greedy(scenario: Scenario) -> list[np.ndarray]:
    return greedy_many([scenario])[0]


def greedy_dead_ends(scenario: Scenario) -> list[np.ndarray]:
    return greedy_many([scenario], dead_ends_first=True)[0]


def greedy_far_first(scenario: Scenario) -> list[np.ndarray]:
    return greedy_many([scenario], dead_ends_first=True, far_first=True)[0]


# ----------------------------------------------------------------------------- rollout (one-step lookahead)
def heuristic_base(dead_ends_first: bool = True, far_first: bool = False):
    """The navigation heuristic with deterministic ties as a rollout base: base(core) -> (B, N) actions."""
    def base(core: GridWorldCore) -> np.ndarray:
        return gridworld.heuristic_actions(core, random_ties=False, dead_ends_first=dead_ends_first, far_first=far_first)

    base.markov = True  # its moves depend on the agents' cells and the coverage only
    return base


ROLLOUT_BASES = {"greedy": heuristic_base(False), "greedy-dead-ends": heuristic_base(True),
                 "greedy-far-first": heuristic_base(True, True)}  # --rollout-base
_SPAWN, _RUN, _APPLY, _DONE = range(4)  # the phase of a map in rollout_many


def _step_some(core: GridWorldCore, actions: np.ndarray, stepping: np.ndarray) -> dict:
    """core.step for the worlds in `stepping` only: the others WAIT and get their step count, battery and
    last action back, which is all a WAIT changes (same cells, same coverage, the same sensor footprint)."""
    keep = ~stepping
    saved = core.steps[keep], core.battery[keep], core.last_action[keep]
    events = core.step(np.where(stepping[:, None], actions, gridworld.WAIT))
    core.steps[keep], core.battery[keep], core.last_action[keep] = saved
    return events


def rollout_many(scenarios: list[Scenario], base=None, config: EnvConfig | None = None,
                 stats: dict | None = None) -> list[list[np.ndarray]]:
    """Rollout (Bertsekas): at every step try each move, finish each try with the base policy and take
    the move with the fewest total steps (the base's own move on ties), for many maps at once. For a
    deterministic base the result is never longer than the base's own path (cost improvement).

    `base(core) -> (B, N)` gives the base's actions for every world of a GridWorldCore (default
    greedy-dead-ends); any deterministic policy that reads only the core's state fits, e.g. a learned
    one acting on core.observe(). A base marked `base.markov = True` (its moves depend only on the
    agents' cells and the coverage, as the heuristic's do) also lets states met twice share their cost
    to go. `config` sets the worlds (default: gridworld's, with a battery that never runs out). Several
    agents decide one after the other (multiagent rollout): agent i tries its moves (WAIT too) with
    agents < i on their chosen moves and agents > i on the base's, N lookaheads a step instead of 5^N
    (plan("rollout") plans several agents with team_rollout_many instead, whose ties go to fewer agent moves).

    One core holds, per map, its real world and K candidate worlds (K = 3 moves besides the
    incumbent's for one agent, 4 with WAIT for several). Every iteration is one batched base call and
    one step of the busy worlds: maps run asynchronously (one spawns candidates while another's still
    run), idle worlds are frozen so the heuristic skips them, and finished maps leave the core (it is
    rebuilt at half occupancy). The incumbent's cost is never simulated: it is the previous winner's
    cost minus the step taken (the winner's completion is the base's completion from the new state).
    Candidates run in lockstep and stop once steps + ceil(remaining / agents) reaches the best cost
    known (a lower bound: an agent covers at most a cell a step), so a decision ends when the first
    candidate finishes or all have wasted as many steps as the incumbent; a markov base's candidates
    also stop on reaching a state of known cost to go (one on a finished candidate's path: its cost is
    then exact) or a state another candidate reached no later (theirs is no worse). Moves into
    obstacles are skipped. `stats`, if given, gets the iterations, decisions and candidate steps."""
    base = base or ROLLOUT_BASES["greedy-dead-ends"]
    config = config or EnvConfig(battery_factor=1e6)
    out: list[list[np.ndarray]] = [[] for _ in scenarios]
    by_agents: dict[int, list[int]] = {}
    for i, s in enumerate(scenarios):
        by_agents.setdefault(len(s.starts), []).append(i)
    for n, rows in by_agents.items():  # one core per number of agents
        solver = _Rollout([scenarios[i] for i in rows], n, base, config)
        paths = solver.solve()
        if stats is not None:
            for k, v in solver.stats.items():
                stats[k] = stats.get(k, 0) + v
        for i, p in zip(rows, paths):
            out[i] = p
    return out


class _Rollout:
    """The state of rollout_many for maps with N agents each; see rollout_many. World m * (K + 1) of
    the core is map m's real world, the next K its candidate slots."""

    def __init__(self, group: list[Scenario], N: int, base, config: EnvConfig):
        self.N, self.base, self.group = N, base, group
        self.moves = np.arange(4 if N == 1 else 5)  # a single agent never gains by waiting
        self.K = K = len(self.moves) - 1
        self.cfg = config.replace(load_state=True, load_random=False, number_agents=N)
        self.markov = bool(getattr(base, "markov", False))  # its actions depend on agent cells and coverage only
        M = len(group)
        self.core = self._core(M)
        self.core.reset(scenarios=[s for s in group for _ in range(K + 1)])
        self.maps = np.arange(M)  # the group index of each map in the core
        real = self.real
        self.traces = [[c] for c in self.core.agent_cells()[real]]
        self.phase = np.where(self.core.remaining[real] == 0, _DONE, _SPAWN)
        self.cost = np.full(M, np.inf)  # steps the incumbent joint move needs to finish (inf: unknown)
        self.known = np.zeros(M, bool)
        self.agent = np.zeros(M, np.int64)  # the agent deciding
        self.fresh = np.ones(M, bool)  # a new step: the incumbent is the base's joint move
        self.chosen = np.zeros((M, N), np.int64)  # incumbent: agents < agent chosen, the others the base's
        self.best = np.full(M, np.inf)
        self.best_slot = np.full(M, -1)
        self.probe = np.zeros(M, bool)
        self.cand = np.zeros((M, K, N), np.int64)  # the candidates' first joint moves
        self.run = np.zeros((M, K), bool)
        self.first = np.zeros((M, K), bool)
        self.start = np.zeros((M, K), np.int64)
        self.final = np.full((M, K), np.inf)  # the candidates' costs, where known
        # Zobrist keys of (coverage, agent cells): a state met again has the same cost to go
        P = self.core.Ph * self.core.Pw
        rng = np.random.default_rng(0)
        self.zcell = np.frombuffer(rng.bytes(8 * P), np.uint64)
        self.zpos = np.frombuffer(rng.bytes(8 * N * P), np.uint64).reshape(N, P)
        cov = self.core.covered.reshape(-1, P)
        self.hash = np.bitwise_xor.reduce(np.where(cov, self.zcell, np.uint64(0)), 1)
        self.togo = [{} for _ in range(M)]  # state key -> the base's steps to finish from it
        self.seen = [{} for _ in range(M)]  # this decision's candidate states -> (steps, slot)
        self.hist = [[[] for _ in range(K)] for _ in range(M)]  # candidate state keys, step by step
        self.stats = dict(iterations=0, decisions=0, candidate_steps=0)

    def _core(self, m: int) -> GridWorldCore:
        core = GridWorldCore(self.cfg, m * (self.K + 1))
        core.configure(scenarios=self.group)
        return core

    @property
    def real(self) -> np.ndarray:
        return np.arange(len(self.maps)) * (self.K + 1)

    def keys(self, worlds: np.ndarray) -> np.ndarray:
        local = self.core.pos[worlds] - (worlds * self.core.Ph * self.core.Pw)[:, None]
        return self.hash[worlds] ^ np.bitwise_xor.reduce(self.zpos[np.arange(self.N), local], 1)

    def copy(self, src: np.ndarray, dst: np.ndarray) -> None:
        self.core.copy_worlds(src, dst)
        self.hash[dst] = self.hash[src]

    def compact(self) -> None:
        """Rebuild the core without the finished maps."""
        keep = np.flatnonzero(self.phase != _DONE)
        worlds = (keep[:, None] * (self.K + 1) + np.arange(self.K + 1)).ravel()
        small = self._core(len(keep))
        small.copy_worlds(worlds, np.arange(len(worlds)), source=self.core)
        self.core, self.hash, self.maps = small, self.hash[worlds], self.maps[keep]
        for k in ("phase", "cost", "known", "agent", "fresh", "chosen", "best", "best_slot", "probe", "cand",
                  "run", "first", "start", "final"):
            setattr(self, k, getattr(self, k)[keep])
        for k in ("togo", "seen", "hist"):
            setattr(self, k, [getattr(self, k)[i] for i in keep])

    def solve(self) -> list[list[np.ndarray]]:
        while (self.phase != _DONE).any():
            if (self.phase != _DONE).sum() * 2 <= len(self.maps) and len(self.maps) > 4:
                self.compact()
            self.iterate()
        return [[np.stack(t)[:, a].copy() for a in range(self.N)] for t in self.traces]

    def iterate(self) -> None:
        core, K, N = self.core, self.K, self.N
        Mc, real = len(self.maps), self.real
        phase = self.phase
        # the base's moves; idle worlds are frozen for the call, so a heuristic base skips them
        frozen = core.frozen[real].copy()
        core.frozen[real[phase != _SPAWN]] = True
        slots = core.frozen.reshape(Mc, K + 1, N)[:, 1:]
        slots[~self.run] = True
        core.any_frozen = True
        acts = np.asarray(self.base(core), np.int64).reshape(Mc, K + 1, N)
        core.frozen[real] = frozen
        spawn = phase == _SPAWN
        self.chosen[spawn & self.fresh] = acts[spawn & self.fresh, 0]
        self.fresh[spawn] = False
        p = np.flatnonzero(spawn & ~self.known)  # a map's first incumbent cost is simulated once
        if len(p):
            self.copy(real[p], real[p] + 1)
            self.cand[p, 0], self.run[p, 0], self.first[p, 0] = self.chosen[p], True, True
            self.final[p] = np.inf
            self.start[p, 0] = core.steps[real[p]]
            self.probe[p], self.known[p], phase[p], self.best[p], self.best_slot[p] = True, True, _RUN, np.inf, -1
            for m in p:
                self.seen[m], self.hist[m][0] = {}, []
            spawn[p] = False
        for _ in range(N):  # candidates of the deciding agent; an agent without any passes at once
            s = np.flatnonzero(spawn)
            if len(s) == 0:
                break
            spawn[:] = False
            spawn[self._spawn(s)] = True
        # the step: the candidates' first moves, else the base's; decisions on the real worlds
        step_acts = acts.copy()
        step_acts[:, 1:] = np.where(self.first[..., None], self.cand, acts[:, 1:])
        apply = np.flatnonzero(phase == _APPLY)
        step_acts[apply, 0] = self.chosen[apply]
        stepping = np.zeros((Mc, K + 1), bool)
        stepping[:, 1:] = self.run
        stepping[apply, 0] = True
        events = _step_some(core, step_acts.reshape(-1, N), stepping.ravel())
        local = core.pos - (np.arange(core.B) * core.Ph * core.Pw)[:, None]
        self.hash ^= np.bitwise_xor.reduce(np.where(events["new"], self.zcell[local], np.uint64(0)), 1)
        self.stats["iterations"] += 1
        self.stats["candidate_steps"] += int(self.run.sum())
        if len(apply):
            y, x = np.divmod(core.pos[real[apply]] % (core.Ph * core.Pw), core.Pw)
            cells = np.stack([y - core.c, x - core.c], -1)
            for j, m in enumerate(apply):
                self.traces[self.maps[m]].append(cells[j])
            self.stats["decisions"] += len(apply)
            self.cost[apply] -= 1
            self.agent[apply], self.fresh[apply] = 0, True
            over = (core.remaining[real[apply]] == 0) | (core.battery[real[apply]] <= 0)  # (a truncated map fails replay)
            phase[apply] = np.where(over, _DONE, _SPAWN)
        r = np.flatnonzero(phase == _RUN)
        if len(r):
            self._judge(r, events)

    def _spawn(self, s: np.ndarray) -> np.ndarray:
        """Candidates for the deciding agent of maps s: the moves but the incumbent's, skipping moves
        into obstacles and those that cannot beat the incumbent even covering a cell per agent and
        step. Maps with none keep the incumbent's move; returns those that decide their next agent."""
        core, K, N = self.core, self.K, self.N
        real, i = self.real[s], self.agent[s]
        rows = np.arange(len(s))
        inc = self.chosen[s, i]
        u = np.argsort(self.moves[None] == inc[:, None], 1, kind="stable")[:, :K]  # (a single agent's WAIT: N, S, W)
        joint = self.chosen[s][:, None].repeat(K, 1)
        joint[rows[:, None], np.arange(K), i[:, None]] = u
        tgt = core.pos[real][:, None] + core.delta[joint]  # (S, K, N)
        ok = ~core.views["obstacle"][tgt[rows, :, i]] | (u == gridworld.WAIT)
        working = core.active[real] & ~core.frozen[real]
        ok &= working[rows, i][:, None]
        gain = (~core.views["covered"][tgt] & ~core.views["obstacle"][tgt] & (joint != gridworld.WAIT)).sum(2)
        n_work = np.maximum(working.sum(1), 1)[:, None]
        lb = 1 + -(-np.maximum(core.remaining[real][:, None] - gain, 0) // n_work)
        ok &= lb < self.cost[s][:, None]
        has = ok.any(1)
        go = s[has]
        if len(go):
            slots = (real[has][:, None] + 1 + np.arange(K))[ok[has]]
            self.copy(np.repeat(real[has], ok[has].sum(1)), slots)
            self.cand[go], self.run[go], self.first[go] = joint[has], ok[has], ok[has]
            self.final[go] = np.inf
            self.start[go] = core.steps[real[has]][:, None]
            self.probe[go], self.phase[go], self.best[go], self.best_slot[go] = False, _RUN, self.cost[go], -1
            if self.markov:
                for m in go:
                    self.seen[m], self.hist[m] = {}, [[] for _ in range(K)]
        idle = s[~has]
        self.agent[idle] += 1
        self.phase[idle[self.agent[idle] == N]] = _APPLY
        return idle[self.agent[idle] < N]

    def _judge(self, r: np.ndarray, events: dict) -> None:
        """After a step: candidates that finished, met a state of known cost, met a state another
        candidate reached first, cannot beat the best cost known, ran out of battery or (first move)
        were blocked stop; a map whose candidates have all stopped takes the best."""
        core, K = self.core, self.K
        w = self.real[r][:, None] + 1 + np.arange(K)
        blocked = self.first[r] & events["blocked"][w, self.agent[r][:, None]] & ~self.probe[r][:, None]
        run = self.run[r] & ~blocked  # a blocked first move is the WAIT candidate's, or a wasted step
        steps = (core.steps[w] - self.start[r]).astype(float)
        rem = core.remaining[w]
        done_cost = np.where(run & (rem == 0), steps, np.inf)
        stop = run & (rem == 0)
        if self.markov:
            keys = self.keys(w.ravel()).reshape(w.shape)
            for j, k in zip(*np.nonzero(run & (rem > 0))):
                m, key, s = r[j], keys[j, k], steps[j, k]
                self.hist[m][k].append(key)
                togo = self.togo[m].get(key)
                if togo is not None:  # the base's cost from here is known
                    done_cost[j, k], stop[j, k] = s + togo, True
                    continue
                prev = self.seen[m].setdefault(key, (s, k))
                if prev != (s, k):  # reached before (or at once by a lower slot, or by itself: a loop)
                    stop[j, k] = True
        self.final[r] = np.minimum(self.final[r], done_cost)
        k = done_cost.argmin(1)
        rows = np.arange(len(r))
        better = done_cost[rows, k] < self.best[r]
        self.best[r[better]], self.best_slot[r[better]] = done_cost[better, k[better]], k[better]
        working = (core.active[w] & ~core.frozen[w]).sum(2)
        lb = steps + -(-rem // np.maximum(working, 1))
        stop |= (lb >= self.best[r][:, None]) | (core.battery[w] <= 0)
        self.run[r] = run & ~stop
        self.first[r] = False
        over = r[~self.run[r].any(1)]
        for m in over:
            self._decide(m)

    def _decide(self, m: int) -> None:
        k = self.best_slot[m]
        if self.markov:  # the states of candidates that finished have known costs to go
            if self.probe[m]:
                self.togo[m][self.keys(self.real[m:m + 1])[0]] = self.best[m]
            togo = self.togo[m]
            for j in np.flatnonzero(np.isfinite(self.final[m])):
                cost = self.final[m, j]
                for t, key in enumerate(self.hist[m][j]):
                    togo.setdefault(key, cost - 1 - t)
        if self.probe[m]:
            self.cost[m], self.phase[m] = self.best[m], _SPAWN
            return
        if k >= 0:
            self.chosen[m] = self.cand[m, k]
            self.cost[m] = self.best[m]
        self.agent[m] += 1
        self.phase[m] = _APPLY if self.agent[m] == self.N else _SPAWN


def team_rollout_many(scenarios: list[Scenario], dead_ends_first: bool = True,
                      far_first: bool = False) -> list[list[np.ndarray]]:
    """The multiagent rollout (Bertsekas 2020) of the heuristic with claims for many maps at once:
    gridworld.team_rollout_actions at every step (agent i tries each move with agents < i on their chosen
    moves and agents > i on the heuristic's and keeps the one whose imagined team finishes first, then with the
    fewest agent moves: N * 4 tries a step, not 5^N); never a longer makespan than the heuristic's own."""
    return _run_many(scenarios, lambda core, live: gridworld.team_rollout_actions(core, live, dead_ends_first,
                                                                                   far_first=far_first))


def rollout(scenario: Scenario) -> list[np.ndarray]:
    """One-step lookahead over greedy-dead-ends (plan("rollout") for one map)."""
    return plan("rollout", [scenario])[0]


# ----------------------------------------------------------------------------- several agents
def partition(scenario: Scenario) -> list[np.ndarray]:
    """Balanced connected regions, then greedy coverage inside each. Regions grow from the
    starts breadth-first, always extending the currently smallest region (so each region is
    connected and sizes stay as even as the map allows); each agent then covers its region
    alone, treating other regions as walls, so the agents never meet."""
    grid = _grid(scenario)
    starts = [int(y) * grid.w + int(x) for y, x in scenario.starts]
    owner = np.full(grid.h * grid.w, -1)
    frontier = [deque([s]) for s in starts]
    size = [0] * len(starts)
    for i, s in enumerate(starts):
        owner[s], size[i] = i, 1
    heap = [(1, i) for i in range(len(starts))]
    while heap:
        _, i = heapq.heappop(heap)
        while frontier[i]:  # claim one more cell next to region i
            u = frontier[i][0]
            free_nb = [v for v in grid.neighbours[u] if owner[v] < 0]
            if not free_nb:
                frontier[i].popleft()
                continue
            owner[free_nb[0]] = i
            frontier[i].append(free_nb[0])
            size[i] += 1
            heapq.heappush(heap, (size[i], i))
            break
    covered = np.zeros((grid.h, grid.w), bool) if scenario.covered is None else scenario.covered
    regions, paths = [], [np.asarray(scenario.starts[i:i + 1]) for i in range(len(starts))]
    for i in range(len(starts)):
        own = (owner == i).reshape(grid.h, grid.w)
        region_covered = covered & own
        region_covered[tuple(scenario.starts[i])] = True
        if (own & ~region_covered).any():  # an agent with nothing to cover stays put
            regions.append((i, Scenario(~own, scenario.starts[i:i + 1], region_covered)))
    for (i, _), p in zip(regions, greedy_many([r for _, r in regions])):
        paths[i] = p[0]
    return paths


def lower_bound(scenario: Scenario) -> int:
    """No schedule of N agents finishes in fewer steps T than ceil(n_poi / N), each step covering at most N cells
    (n_poi = free cells not yet covered; ceil((n_free - N) / N) when only the starts are), nor than the checkerboard
    allows: a move changes the colour (row + col) % 2 of the agent's cell, so in T steps an agent reaches at most
    ceil(T / 2) cells of the other colour than its start and floor(T / 2) of its own (a wait or a bump only loses a
    step). One agent starting on the minority colour of an open 5x5 map, for instance, needs a revisit."""
    covered = np.zeros_like(scenario.obstacles) if scenario.covered is None else scenario.covered
    covered = covered.copy()
    covered[scenario.starts[:, 0], scenario.starts[:, 1]] = True
    poi = ~scenario.obstacles & ~covered
    colour = np.indices(poi.shape).sum(0) % 2
    need = [int((poi & (colour == k)).sum()) for k in (0, 1)]
    agents = np.bincount(colour[scenario.starts[:, 0], scenario.starts[:, 1]], minlength=2)  # by their start's colour
    steps = math.ceil(poi.sum() / len(scenario.starts))
    while any(agents[k] * (steps // 2) + agents[1 - k] * ((steps + 1) // 2) < need[k] for k in (0, 1)):
        steps += 1
    return steps


PLANNERS = {"greedy": greedy, "greedy-dead-ends": greedy_dead_ends, "greedy-far-first": greedy_far_first,
            "rollout": rollout, "boustrophedon": boustrophedon, "spiral-stc": spiral_stc, "wavefront": wavefront,
            "lkh": lkh, "partition": partition}
# planned all at once: name -> (dead_ends_first, far_first)
BATCHED = {"greedy": (False, False), "greedy-dead-ends": (True, False), "greedy-far-first": (True, True), "rollout": None}
SINGLE_AGENT = {"boustrophedon", "spiral-stc", "wavefront", "lkh"}


# ----------------------------------------------------------------------------- replay
def replay(scenario: Scenario, paths: list[np.ndarray], complete: bool = True) -> dict:
    """Run per-agent paths through gridworld and return its episode metrics. Raises ValueError
    if a path leaves the map, jumps, enters an obstacle, is blocked by the safety controller or
    (unless `complete` is False: then "completed" says so) leaves a free cell uncovered."""
    n = len(scenario.starts)
    if len(paths) != n:
        raise ValueError(f"{len(paths)} paths for {n} agents")
    for i, p in enumerate(paths):
        p = np.asarray(p)
        if p.ndim != 2 or p.shape[1] != 2 or len(p) == 0 or (p[0] != scenario.starts[i]).any():
            raise ValueError(f"path {i} must be [row, col] cells starting at the agent's start")
        if (np.abs(np.diff(p, axis=0)).sum(1) > 1).any():
            raise ValueError(f"path {i} jumps: consecutive cells must be 4-adjacent")
    core = GridWorldCore(EnvConfig(load_state=True, number_agents=n, battery_factor=1e6), 1)
    core.configure(scenarios=[scenario])
    core.reset()
    T = max(len(p) for p in paths)
    for t in range(1, T):
        actions = []
        for p in paths:
            if t >= len(p) or (p[t] == p[t - 1]).all():
                actions.append(gridworld.WAIT)
            else:
                d = tuple(int(v) for v in p[t] - p[t - 1])
                actions.append(MOVES.index(d))
        events = core.step(np.array([actions]))
        if events["blocked"].any():
            raise ValueError(f"step {t}: a move is blocked (obstacle, border or another agent)")
    metrics = {k: v[0].item() for k, v in core.metrics().items()}
    if complete and not metrics["completed"]:
        raise ValueError(f"the paths leave {core.remaining[0]} free cells uncovered")
    metrics["lower_bound"] = lower_bound(scenario)
    return metrics


def plan(name: str, scenarios: list[Scenario], rollout_base: str = "greedy-dead-ends") -> list[list[np.ndarray]]:
    """Paths of planner `name` for every scenario (greedy and rollout are batched over all of them;
    rollout looks ahead with `rollout_base`, one of ROLLOUT_BASES: gridworld.rollout_actions at every step for
    one agent, 3-4x faster than rollout_many and as cheap but for ties, team_rollout_many for several)."""
    if name not in PLANNERS:
        raise ValueError(f"unknown planner {name!r}; choose from {sorted(PLANNERS)}")
    if name in SINGLE_AGENT and any(len(s.starts) != 1 for s in scenarios):
        raise ValueError(f"{name} is a single-agent planner; use {', '.join(BATCHED)} or partition for several")
    if name == "rollout":
        if rollout_base not in ROLLOUT_BASES:
            raise ValueError(f"unknown rollout base {rollout_base!r}; choose from {sorted(ROLLOUT_BASES)}")
        dead_ends_first, far_first = BATCHED[rollout_base]
        singles = iter(_run_many([s for s in scenarios if len(s.starts) == 1], lambda core, live: gridworld.rollout_actions(core,
            live, dead_ends_first, far_first=far_first).reshape(-1, 1)))  # the teacher's walkers: rollout_many's costs
        teams = iter(team_rollout_many([s for s in scenarios if len(s.starts) > 1], dead_ends_first, far_first))
        return [next(teams if len(s.starts) > 1 else singles) for s in scenarios]
    if name in BATCHED:
        return greedy_many(scenarios, *BATCHED[name])
    return [PLANNERS[name](s) for s in scenarios]


# ----------------------------------------------------------------------------- command line
@dataclass
class Args:
    planner: str = "greedy"
    """one of greedy, greedy-dead-ends, greedy-far-first, rollout, boustrophedon, spiral-stc, wavefront, lkh, partition"""
    rollout_base: str = "greedy-dead-ends"
    """the base policy --planner rollout looks ahead with (greedy or greedy-dead-ends)"""
    maps: tuple[str, ...] = ()
    """MovingAI .map or ASCII map files (starts from the file, else drawn with --seed)"""
    dataset: str | None = None
    """a gridworld .npz dataset (e.g. maps/cpp_eval.npz)"""
    agents: int = 1
    """agents per scenario: the first N stored starts, or N random starts"""
    limit: int = 0
    """use only the first LIMIT scenarios (0: all)"""
    seed: int = 0
    """seed for starts drawn at random"""
    out: str | None = None
    """a file for one JSON line of metrics per scenario; with --report the folder for classical_cpp.json
    (default results/)"""
    report: bool = False
    """instead: run every planner on maps/cpp_eval.npz (--per-size maps per size), the external
    maps, maps/marl_eval.npz and maps/structured_eval.npz (--structured-per-band maps per family and size
    band), write OUT/classical_cpp.json and print the README tables"""
    per_size: int = 20
    """maps per size for --report (LKH takes seconds per map)"""
    structured_per_band: int = STRUCTURED_PER_BAND
    """structured_eval maps per family and size band for --report (4 families x 4 bands)"""
    quiet: bool = False
    """no progress bar"""
    overwrite: bool = False
    """let --out (or --report's OUT/classical_cpp.json, the committed results/classical_cpp.json by default) replace
    a file that is there already"""


def load_scenarios(args: Args) -> list[Scenario]:
    if args.agents < 1:
        raise ValueError(f"--agents must be >= 1, got {args.agents}")
    if args.limit < 0:
        raise ValueError(f"--limit must be >= 0 (0: all), got {args.limit}")
    scenarios = gridworld.load_dataset(args.dataset) if args.dataset else []
    names = [f"{args.dataset}[{i}]" for i in range(len(scenarios))] + list(args.maps)
    for path in args.maps:
        scenarios.append(gridworld.load_map(path))
    if not scenarios:
        raise ValueError("give --maps FILE... or --dataset FILE")
    if args.limit:
        scenarios = scenarios[:args.limit]
    rng = np.random.default_rng(args.seed)
    for s, name in zip(scenarios, names):
        s.starts = starts_for(s, args.agents, rng, name)
        s.covered = None if s.covered is None else s.covered & ~s.obstacles
        with_starts(s)
    return scenarios


def starts_for(s: Scenario, agents: int, rng: np.random.Generator, name: str) -> np.ndarray:
    """The first `agents` stored starts, else that many distinct random free cells."""
    if s.starts is not None and len(s.starts) >= agents:
        return s.starts[:agents]
    free = np.argwhere(~s.obstacles)
    if len(free) <= agents:
        raise ValueError(f"{name}: {len(free)} free cells for {agents} agents")
    return free[rng.choice(len(free), agents, replace=False)]


def with_starts(s: Scenario) -> Scenario:
    """Mark the start cells covered (Algorithm 9 line 17), as gridworld does at reset."""
    s.covered = np.zeros_like(s.obstacles) if s.covered is None else s.covered.copy()
    s.covered[s.starts[:, 0], s.starts[:, 1]] = True
    return s


def evaluate(name: str, scenarios: list[Scenario], bar: tqdm | None = None,
             rollout_base: str = "greedy-dead-ends", complete: bool = True) -> tuple[list[dict], float]:
    """Plan and replay every scenario: the metrics of each, and the planning time in ms per map. The
    batched planners plan 64 maps at a time, the others one at a time, so that `bar` moves. With
    `complete` False an incomplete path is a row with "completed" False instead of a ValueError."""
    rows, seconds = [], 0.0
    step = 64 if name in BATCHED else 1
    for i in range(0, len(scenarios), step):
        part = scenarios[i:i + step]
        t0 = time.perf_counter()
        paths = plan(name, part, rollout_base)
        seconds += time.perf_counter() - t0
        rows += [replay(s, p, complete) for s, p in zip(part, paths)]
        if bar is not None:
            bar.update(len(part))
    return rows, 1000 * seconds / max(len(scenarios), 1)


def cpp_eval_subset(per_size: int) -> tuple[list[Scenario], np.ndarray]:
    """The first `per_size` cpp_eval maps of each size 5-30, and their sizes."""
    path = os.path.join(ROOT, "maps", "cpp_eval.npz")
    sizes = np.load(path)["size"]
    keep = np.concatenate([np.flatnonzero(sizes == s)[:per_size] for s in range(5, 31)])
    all_maps = gridworld.load_dataset(path)
    return [all_maps[i] for i in keep], sizes[keep]


def marl_eval_subset(agents: int, every: int = MARL_EVERY) -> tuple[list[Scenario], np.ndarray]:
    """Every `every`-th marl_eval layout of sizes 10-30 with its first `agents` starts (the
    N + 1-agent episode adds one agent to the N-agent one, §7.5.1), and their sizes."""
    path = os.path.join(ROOT, "maps", "marl_eval.npz")
    sizes = np.load(path)["size"]
    keep = np.flatnonzero(sizes >= MARL_MIN_SIZE)[::every]
    all_maps = gridworld.load_dataset(path)
    return [with_starts(Scenario(all_maps[i].obstacles, all_maps[i].starts[:agents])) for i in keep], sizes[keep]


def external_episodes() -> list[tuple[str, Scenario]]:
    """Every MovingAI map of maps/external with each of its reference starts."""
    folder = os.path.join(ROOT, "maps", "external")
    with open(os.path.join(folder, "references.json")) as f:
        refs = json.load(f)
    episodes = []
    for name, rs in refs.items():
        grid = gridworld.load_map(os.path.join(folder, name)).obstacles
        episodes += [(name, with_starts(Scenario(grid, np.array([r["start"]])))) for r in rs]
    return episodes


def structured_eval_subset(per_band: int) -> tuple[list[Scenario], np.ndarray, np.ndarray]:
    """`per_band` maps of each structured_eval family and size band (STRUCTURED_BANDS), spread evenly over the
    band's sizes (the first map of each size first; 3 of sizes 10-15: one each of 11, 13, 15), each with its
    first stored start (the single-agent scenario) marked covered; and their families and sizes."""
    path = os.path.join(ROOT, "maps", "structured_eval.npz")
    with np.load(path) as data:
        families, sizes = data["family"], data["size"]
    keep = []
    for family in gridworld.STRUCTURED_FAMILIES:
        for a, b in STRUCTURED_BANDS:
            by_size = [np.flatnonzero((families == family) & (sizes == z)) for z in range(a, b + 1)]
            used = [0] * len(by_size)
            for j in range(per_band):
                k = int((j + 0.5) * len(by_size) / per_band) % len(by_size)
                if used[k] < len(by_size[k]):
                    keep.append(by_size[k][used[k]])
                    used[k] += 1
    keep = np.array(keep, np.int64)
    all_maps = gridworld.load_dataset(path)
    chosen = [with_starts(Scenario(all_maps[i].obstacles, all_maps[i].starts[:1])) for i in keep]
    return chosen, families[keep], sizes[keep]


def _band(a: int, b: int) -> str:
    return f"{a}-{b}"


def _single_agent(names, cpp: list[Scenario], sizes: np.ndarray, external: list, bar) -> tuple[dict, dict]:
    """Planners `names` on the cpp_eval maps (mean overlap by REPORT_BANDS, planning ms) and the external
    episodes (overlap per start): the "cpp_eval" and "external" entries of `compare`."""
    by_size, by_map = {}, {}
    for name in names:
        bar.set_description(name)
        rows, ms = evaluate(name, cpp, bar)
        overlap = np.array([r["overlap"] for r in rows])
        by_size[name] = {
            "plan_ms_per_map": round(ms, 2), "all": round(float(overlap.mean()), 4),
            **{_band(a, b): round(float(overlap[(sizes >= a) & (sizes <= b)].mean()), 4) for a, b in REPORT_BANDS}}
        rows, _ = evaluate(name, [s for _, s in external], bar)
        for (m, _), r in zip(external, rows):
            by_map.setdefault(m, {}).setdefault(name, []).append(r["overlap"])
    return by_size, by_map


def _bar(total: int, quiet: bool) -> tqdm:
    return tqdm(total=total, desc="planners", unit="map", disable=quiet or not sys.stdout.isatty())


def compare_structured(per_band: int = STRUCTURED_PER_BAND, quiet: bool = False, bar: tqdm | None = None) -> dict:
    """STRUCTURED_PLANNERS on `structured_eval_subset(per_band)`: per planner and family (and over all of
    them) the mean overlap, the completion rate and the planning ms per map, and the mean overlap per size
    band (over the families, and per family); the "structured_eval" entry of `compare`."""
    if per_band < 1:
        raise ValueError(f"--structured-per-band must be >= 1, got {per_band}")
    scenarios, families, sizes = structured_eval_subset(per_band)
    names = [f for f in gridworld.STRUCTURED_FAMILIES if (families == f).any()]
    bands = [(a, b) for a, b in STRUCTURED_BANDS if ((sizes >= a) & (sizes <= b)).any()]
    result = {"per_band": per_band, "bands": [list(b) for b in bands], "lkh_time_limit_s": LKH_TIME_LIMIT,
              "maps": {f: int((families == f).sum()) for f in names}, "planners": {}}

    def summary(rows, ms, pick):
        overlap = np.array([r["overlap"] for r in rows])
        done = np.array([r["completed"] for r in rows])
        out = {"overlap": round(float(overlap.mean()), 4), "completion": round(float(done.mean()), 4),
               "plan_ms_per_map": round(float(ms), 2)}
        out["by_band"] = {_band(a, b): round(float(overlap[(pick >= a) & (pick <= b)].mean()), 4)
                          for a, b in bands if ((pick >= a) & (pick <= b)).any()}
        return out

    own = bar is None
    bar = _bar(len(STRUCTURED_PLANNERS) * len(scenarios), quiet) if own else bar
    try:
        for name in STRUCTURED_PLANNERS:
            bar.set_description(f"{name}, structured_eval")
            entry, rows, seconds = {}, [], 0.0
            for f in names:
                idx = np.flatnonzero(families == f)
                got, ms = evaluate(name, [scenarios[i] for i in idx], bar, complete=False)
                entry[f] = summary(got, ms, sizes[idx])
                rows += got
                seconds += ms * len(idx)
            order = np.concatenate([np.flatnonzero(families == f) for f in names])
            entry["all"] = summary(rows, seconds / len(rows), sizes[order])
            result["planners"][name] = entry
    finally:
        if own:
            bar.close()
    return result


def compare_rollout(per_size: int, quiet: bool = False) -> dict:
    """The rollout planner alone on `compare`'s cpp_eval subset and external episodes: `compare`'s "cpp_eval"
    and "external" entries for rollout only (for a classical_cpp.json collected before rollout was added)."""
    if per_size < 1:
        raise ValueError(f"--per-size must be >= 1, got {per_size}")
    cpp, sizes = cpp_eval_subset(per_size)
    external = external_episodes()
    with _bar(len(cpp) + len(external), quiet) as bar:
        by_size, by_map = _single_agent(["rollout"], cpp, sizes, external, bar)
    return {"per_size": per_size, "planners": ["rollout"], "cpp_eval": by_size, "external": by_map}


def structured_team_subset(agents: int, every: int) -> tuple[list[Scenario], np.ndarray]:
    """Every `every`-th structured_eval map (all families, sizes 10-30) with its first `agents` starts (covered), and
    their sizes."""
    path = os.path.join(ROOT, "maps", "structured_eval.npz")
    sizes = np.load(path)["size"][::every]
    maps = gridworld.load_dataset(path)[::every]
    return [with_starts(Scenario(s.obstacles, s.starts[:agents])) for s in maps], sizes


def compare_team_rollout(agents=TEAM_AGENTS, marl_every: int = TEAM_MARL_EVERY, structured_every: int = TEAM_STRUCTURED_EVERY,
                         structured_agents: int = 5, quiet: bool = False) -> dict:
    """The multiagent rollout planner beside its base (greedy-dead-ends with claims) and greedy with claims: on every
    `marl_every`-th marl_eval layout of sizes 10-30 at each N of `agents`, and on every `structured_every`-th
    structured_eval map at N = `structured_agents` (0: none). Per planner the mean time-save factor (eq. 7.6), the
    seconds per map and the ms per team step (planning and replay), beside the lower bound ceil(n_poi / N) / n_poi
    averaged the same way, and the maps where the rollout's makespan is longer than its base's (0 by construction)."""
    if not agents or min(agents) < 2 or structured_agents < 2:
        raise ValueError("the team rollout needs >= 2 agents (one agent: the rollout planner)")
    if marl_every < 1 or structured_every < 0:
        raise ValueError(f"marl_every must be >= 1 and structured_every >= 0, got {marl_every}, {structured_every}")
    sets = [("marl_eval", n, *marl_eval_subset(n, marl_every)) for n in agents]
    if structured_every:
        sets.append(("structured_eval", structured_agents, *structured_team_subset(structured_agents, structured_every)))
    result = {"marl_every": marl_every, "structured_every": structured_every, "planners": list(TEAM_PLANNERS),
              "marl_eval": {}, "structured_eval": {}}
    with _bar(len(TEAM_PLANNERS) * sum(len(c) for _, _, c, _ in sets), quiet) as bar:
        for dataset, n, scenarios, sizes in sets:
            bound = np.mean([lower_bound(s) / max(int((~s.obstacles).sum()) - n, 1) for s in scenarios])
            entry = {"maps": len(scenarios), "sizes": [int(sizes.min()), int(sizes.max())],
                     "lower_bound_time_save": round(float(bound), 4)}
            steps = {}
            for name in TEAM_PLANNERS:
                bar.set_description(f"{name}, {n} agents, {dataset}")
                t0 = time.perf_counter()
                rows, _ = evaluate(name, scenarios, bar)
                seconds = time.perf_counter() - t0
                steps[name] = np.array([r["steps"] for r in rows])
                entry[name] = {"time_save": round(float(np.mean([r["time_save"] for r in rows])), 4),
                               "s_per_map": round(seconds / len(rows), 3),
                               "ms_per_team_step": round(1000 * seconds / max(int(steps[name].sum()), 1), 2)}
            entry["rollout_longer_than_base"] = int((steps["rollout"] > steps["greedy-dead-ends"]).sum())
            result[dataset][str(n)] = entry
    return result


def team_rollout_table(result: dict) -> str:
    """compare_team_rollout's result as a Markdown table."""
    rows = ["| dataset | N | maps | greedy (claims) | greedy-dead-ends (claims) | rollout | lower bound | rollout s/map |",
            "|---|---|---|---|---|---|---|---|"]
    for dataset in ("marl_eval", "structured_eval"):
        for n, e in result[dataset].items():
            rows.append(f"| {dataset} | {n} | {e['maps']} | {e['greedy']['time_save']:.3f} | "
                        f"{e['greedy-dead-ends']['time_save']:.3f} | **{e['rollout']['time_save']:.3f}** | "
                        f"{e['lower_bound_time_save']:.3f} | {e['rollout']['s_per_map']:.2f} |")
    return "\n".join(rows)


def compare(per_size: int, quiet: bool = False, structured_per_band: int = STRUCTURED_PER_BAND) -> dict:
    """Every report planner on the first `per_size` cpp_eval maps of each size (mean overlap by size
    band) and on the external maps (overlap per reference start), the multi-agent baselines'
    mean time-save factor on marl_eval beside the lower bound, and `compare_structured` on
    `structured_per_band` structured_eval maps per family and size band."""
    if per_size < 1:
        raise ValueError(f"--per-size must be >= 1, got {per_size}")
    if structured_per_band < 1:
        raise ValueError(f"--structured-per-band must be >= 1, got {structured_per_band}")
    cpp, sizes = cpp_eval_subset(per_size)
    external = external_episodes()
    teams = {n: marl_eval_subset(n) for n in REPORT_AGENTS}
    result = {"per_size": per_size, "lkh_time_limit_s": LKH_TIME_LIMIT, "marl_every": MARL_EVERY,
              "marl_sizes": [int(min(z.min() for _, z in teams.values())), int(max(z.max() for _, z in teams.values()))],
              "cpp_eval": {}, "external": {}, "marl_eval": {}}
    structured = len(structured_eval_subset(structured_per_band)[0])
    total = (len(REPORT_PLANNERS) * (len(cpp) + len(external)) + 2 * sum(len(c) for c, _ in teams.values())
             + len(STRUCTURED_PLANNERS) * structured)
    with _bar(total, quiet) as bar:
        result["cpp_eval"], result["external"] = _single_agent(REPORT_PLANNERS, cpp, sizes, external, bar)
        for n, (chosen, _) in teams.items():
            bound = np.mean([lower_bound(s) / max(int((~s.obstacles).sum()) - n, 1) for s in chosen])
            entry = {"maps": len(chosen), "lower_bound_time_save": round(float(bound), 4)}
            for name in ("greedy", "partition"):
                bar.set_description(f"{name}, {n} agents")
                rows, _ = evaluate(name, chosen, bar)
                entry[name] = round(float(np.mean([r["time_save"] for r in rows])), 4)
            result["marl_eval"][str(n)] = entry
        result["structured_eval"] = compare_structured(structured_per_band, quiet, bar)
    return result


def tables(result: dict) -> str:
    """The README tables of a `compare` result, as Markdown."""
    names, bands = list(result["cpp_eval"]), [k for k in next(iter(result["cpp_eval"].values())) if "-" in k]
    lines = ["| planner | " + " | ".join(b.replace("-", "–") for b in bands) + " | all | plan ms/map |",
             "|---" * (len(bands) + 3) + "|"]
    for name, r in result["cpp_eval"].items():
        lines.append(f"| {name} | " + " | ".join(f"{r[b]:.3f}" for b in bands)
                     + f" | {r['all']:.3f} | {r['plan_ms_per_map']:.1f} |")
    lines += ["", "| map | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
    for m, per in result["external"].items():
        lines.append(f"| {m} | " + " | ".join(f"{np.mean(per[n]):.3f}" for n in names) + " |")
    lines += ["", "| agents | maps | greedy (claims) | partition | lower bound |", "|---|---|---|---|---|"]
    for n, e in result["marl_eval"].items():
        lines.append(f"| {n} | {e['maps']} | {e['greedy']:.3f} | {e['partition']:.3f} | {e['lower_bound_time_save']:.3f} |")
    if "structured_eval" in result:
        lines += ["", structured_table(result["structured_eval"])]
    return "\n".join(lines)


def structured_table(structured: dict) -> str:
    """`compare_structured`'s mean overlap per planner and family, as Markdown (completion below 100% shown)."""
    planners = structured["planners"]
    families = list(structured["maps"])

    def cell(r):
        return f"{r['overlap']:.3f}" + ("" if r["completion"] == 1 else f" ({100 * r['completion']:.0f}% done)")

    lines = ["| planner | " + " | ".join(families) + " | all | plan ms/map |", "|---" * (len(families) + 3) + "|"]
    for name, r in planners.items():
        lines.append(f"| {name} | " + " | ".join(cell(r[f]) for f in families)
                     + f" | {cell(r['all'])} | {r['all']['plan_ms_per_map']:.1f} |")
    return "\n".join(lines)


def report(per_size: int, out: str, quiet: bool = False, structured_per_band: int = STRUCTURED_PER_BAND) -> dict:
    """`compare` into OUT/classical_cpp.json, and its tables printed."""
    if os.path.exists(out) and not os.path.isdir(out):
        raise ValueError(f"--out {out}: not a folder")
    result = compare(per_size, quiet, structured_per_band)
    gridworld.write_json(os.path.join(out, "classical_cpp.json"), result, "result", overwrite=True, flag="--out")
    print(tables(result))
    return result


def main(args: Args) -> None:
    if args.report and (args.maps or args.dataset):
        raise ValueError("--report plans its own maps (see --help); drop --maps and --dataset")
    if args.report:
        out = args.out or os.path.join(ROOT, "results")
        target = os.path.join(out, "classical_cpp.json")
        gridworld.check_output(target, "result", args.overwrite, "--out")  # before the minutes of planning
        report(args.per_size, out, args.quiet, args.structured_per_band)
        return
    if args.planner not in PLANNERS:
        raise ValueError(f"unknown planner {args.planner!r}; choose from {sorted(PLANNERS)}")
    if args.rollout_base not in ROLLOUT_BASES:
        raise ValueError(f"unknown rollout base {args.rollout_base!r}; choose from {sorted(ROLLOUT_BASES)}")
    if args.out and not os.path.isdir(os.path.dirname(os.path.abspath(args.out))):
        raise ValueError(f"--out {args.out}: no such folder")
    if args.out:
        gridworld.check_output(args.out, "result", args.overwrite, "--out")
    scenarios = load_scenarios(args)
    with tqdm(total=len(scenarios), desc=args.planner, unit="map", disable=args.quiet or not sys.stdout.isatty()) as bar:
        rows, ms = evaluate(args.planner, scenarios, bar, args.rollout_base)
    if args.out:
        with gridworld.staged_output(args.out, "result", overwrite=True, flag="--out") as tmp, open(tmp, "w") as f:
            f.write("".join(json.dumps({"size": list(s.obstacles.shape), **r}) + "\n" for s, r in zip(scenarios, rows)))
    print(f"{args.planner}: {len(rows)} scenario(s), {args.agents} agent(s) each, "
          f"mean overlap {np.mean([r['overlap'] for r in rows]):.4f}, "
          f"mean time-save factor {np.mean([r['time_save'] for r in rows]):.4f}, "
          f"planning {ms:.2f} ms per map" + (f" -> {args.out}" if args.out else ""))


if __name__ == "__main__":
    with gridworld.cli_errors():  # Ctrl-C: one line, exit 130; --out and --report are written only at the end
        main(gridworld.cli(Args))
