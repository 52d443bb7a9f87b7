"""Classical coverage planners, multi-agent baselines and a near-optimal reference.

Every planner takes a map with its start(s) (a gridworld.Scenario) and returns one path per
agent: an array of [row, col] cells, one per time step, consecutive cells 4-adjacent (or equal:
the agent waits). `replay` runs the paths through gridworld's own environment, so every metric
(steps, overlap, time-save factor) is counted by the same code that scores the learned agents,
and it rejects illegal or incomplete paths.

    python classical_cpp.py --planner boustrophedon --maps maps/external/room-32-32-4.map
    python classical_cpp.py --planner greedy --dataset maps/cpp_eval.npz --limit 200
    python classical_cpp.py --planner partition --dataset maps/marl_eval.npz --agents 5

Single agent: greedy (the navigation heuristic run to completion), greedy-dead-ends (the same
with Warnsdorff's tie-break: of the nearest uncovered cells, the one with the fewest uncovered
neighbours first; also for several agents), boustrophedon (BA*-style
back-and-forth with shortest-path repositioning), spiral-stc (Spiral-STC on 2x2 blocks, partly
blocked blocks kept), wavefront (Zelinsky's distance transform), lkh (the TSP over the
shortest-path metric closure solved by LKH-3 through elkai: the near-optimal reference).
Several agents: greedy (with claims), partition (balanced connected regions, then greedy in
each), and `lower_bound` = ceil((n_free - N) / N) steps.
"""
from __future__ import annotations

import heapq
import json
import math
import os
import time
from collections import deque
from dataclasses import dataclass

import numpy as np
import tyro

import gridworld
from gridworld import EnvConfig, GridWorldCore, Scenario

MOVES = ((-1, 0), (1, 0), (0, -1), (0, 1))  # N, S, W, E: the gridworld action order
LKH_TIME_LIMIT = 10.0  # seconds of LKH search per map (plus reading the problem)
ROOT = os.path.dirname(os.path.abspath(__file__))


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
def greedy_many(scenarios: list[Scenario], dead_ends_first: bool = False) -> list[list[np.ndarray]]:
    """The navigation heuristic run to completion in gridworld itself, for many maps at once:
    nearest known point of interest, first in row-major order on ties (with dead_ends_first,
    the one with the fewest uncovered neighbours first); several agents claim distinct targets
    (the nearest agent-target pair first)."""
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
            actions = np.where(done[:, None], gridworld.WAIT, core.heuristic_actions(False, dead_ends_first))
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
    """No schedule of N agents finishes in fewer steps than ceil(n_poi / N): each step covers
    at most N cells (n_poi = free cells not yet covered; ceil((n_free - N) / N) when only the
    starts are)."""
    covered = np.zeros_like(scenario.obstacles) if scenario.covered is None else scenario.covered
    covered = covered.copy()
    covered[scenario.starts[:, 0], scenario.starts[:, 1]] = True
    return math.ceil((~scenario.obstacles & ~covered).sum() / len(scenario.starts))


PLANNERS = {"greedy": greedy, "greedy-dead-ends": greedy_dead_ends, "boustrophedon": boustrophedon,
            "spiral-stc": spiral_stc, "wavefront": wavefront, "lkh": lkh, "partition": partition}
BATCHED = {"greedy": False, "greedy-dead-ends": True}  # planned all at once: name -> dead_ends_first
SINGLE_AGENT = {"boustrophedon", "spiral-stc", "wavefront", "lkh"}


# ----------------------------------------------------------------------------- replay
def replay(scenario: Scenario, paths: list[np.ndarray]) -> dict:
    """Run per-agent paths through gridworld and return its episode metrics. Raises ValueError
    if a path leaves the map, jumps, enters an obstacle, is blocked by the safety controller or
    leaves a free cell uncovered."""
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
    if not metrics["completed"]:
        raise ValueError(f"the paths leave {core.remaining[0]} free cells uncovered")
    metrics["lower_bound"] = lower_bound(scenario)
    return metrics


def plan(name: str, scenarios: list[Scenario]) -> list[list[np.ndarray]]:
    """Paths of planner `name` for every scenario (greedy is batched over all of them)."""
    if name not in PLANNERS:
        raise ValueError(f"unknown planner {name!r}; choose from {sorted(PLANNERS)}")
    if name in SINGLE_AGENT and any(len(s.starts) != 1 for s in scenarios):
        raise ValueError(f"{name} is a single-agent planner; use {', '.join(BATCHED)} or partition for several")
    if name in BATCHED:
        return greedy_many(scenarios, dead_ends_first=BATCHED[name])
    return [PLANNERS[name](s) for s in scenarios]


# ----------------------------------------------------------------------------- command line
@dataclass
class Args:
    planner: str = "greedy"
    """one of greedy, greedy-dead-ends, boustrophedon, spiral-stc, wavefront, lkh, partition"""
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
    """write one JSON line of metrics per scenario here"""
    report: bool = False
    """instead: run every planner on maps/cpp_eval.npz (--per-size maps per size), the external
    maps and maps/marl_eval.npz, write results/classical_cpp.json and print the README tables"""
    per_size: int = 20
    """maps per size for --report (LKH takes seconds per map)"""


def load_scenarios(args: Args) -> list[Scenario]:
    scenarios = gridworld.load_dataset(args.dataset) if args.dataset else []
    for path in args.maps:
        scenarios.append(gridworld.load_map(path))
    if not scenarios:
        raise ValueError("give --maps FILE... or --dataset FILE")
    if args.limit:
        scenarios = scenarios[:args.limit]
    rng = np.random.default_rng(args.seed)
    for s in scenarios:
        s.starts = starts_for(s, args.agents, rng, "a map")
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


def evaluate(name: str, scenarios: list[Scenario]) -> tuple[list[dict], float]:
    t0 = time.perf_counter()
    paths = plan(name, scenarios)
    seconds = time.perf_counter() - t0
    return [replay(s, p) for s, p in zip(scenarios, paths)], 1000 * seconds / len(scenarios)


def cpp_eval_subset(per_size: int) -> tuple[list[Scenario], np.ndarray]:
    """The first `per_size` cpp_eval maps of each size 5-30, and their sizes."""
    path = os.path.join(ROOT, "maps", "cpp_eval.npz")
    sizes = np.load(path)["size"]
    keep = np.concatenate([np.flatnonzero(sizes == s)[:per_size] for s in range(5, 31)])
    all_maps = gridworld.load_dataset(path)
    return [all_maps[i] for i in keep], sizes[keep]


def marl_eval_subset(agents: int, every: int = 5) -> tuple[list[Scenario], np.ndarray]:
    """Every `every`-th marl_eval layout of sizes 10-30 with its first `agents` starts (the
    N + 1-agent episode adds one agent to the N-agent one, §7.5.1), and their sizes."""
    path = os.path.join(ROOT, "maps", "marl_eval.npz")
    sizes = np.load(path)["size"]
    keep = np.flatnonzero(sizes >= 10)[::every]
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


def report(per_size: int) -> None:
    """The README tables: mean overlap by size band on cpp_eval, per external map, and the
    multi-agent baselines' time-save factor on marl_eval."""
    bands = [(5, 10), (11, 15), (16, 20), (21, 25), (26, 30)]
    cpp, sizes = cpp_eval_subset(per_size)
    external = external_episodes()
    result = {"per_size": per_size, "lkh_time_limit_s": LKH_TIME_LIMIT, "cpp_eval": {},
              "external": {}, "marl_eval": {}}
    for name in ("greedy", "boustrophedon", "spiral-stc", "wavefront", "lkh"):
        rows, ms = evaluate(name, cpp)
        overlap = np.array([r["overlap"] for r in rows])
        result["cpp_eval"][name] = {
            "plan_ms_per_map": round(ms, 2), "all": round(float(overlap.mean()), 4),
            **{f"{a}-{b}": round(float(overlap[(sizes >= a) & (sizes <= b)].mean()), 4) for a, b in bands}}
        rows, _ = evaluate(name, [s for _, s in external])
        for (m, _), r in zip(external, rows):
            result["external"].setdefault(m, {}).setdefault(name, []).append(r["overlap"])
        print(name, json.dumps(result["cpp_eval"][name]), flush=True)
    for n in (2, 5, 10):
        chosen, _ = marl_eval_subset(n)
        bound = np.mean([lower_bound(s) / max(int((~s.obstacles).sum()) - n, 1) for s in chosen])
        entry = {"maps": len(chosen), "lower_bound_time_save": round(float(bound), 4)}
        for name in ("greedy", "partition"):
            rows, _ = evaluate(name, chosen)
            entry[name] = round(float(np.mean([r["time_save"] for r in rows])), 4)
        result["marl_eval"][str(n)] = entry
        print(n, json.dumps(entry), flush=True)
    os.makedirs(os.path.join(ROOT, "results"), exist_ok=True)
    with open(os.path.join(ROOT, "results", "classical_cpp.json"), "w") as f:
        json.dump(result, f, indent=1)
    names = list(result["cpp_eval"])
    print("\n| planner | " + " | ".join(f"{a}–{b}" for a, b in bands) + " | all | plan ms/map |")
    print("|---" * (len(bands) + 3) + "|")
    for name in names:
        r = result["cpp_eval"][name]
        print(f"| {name} | " + " | ".join(f"{r[f'{a}-{b}']:.3f}" for a, b in bands)
              + f" | {r['all']:.3f} | {r['plan_ms_per_map']:.1f} |")
    print("\n| map | " + " | ".join(names) + " |")
    print("|---" * (len(names) + 1) + "|")
    for m, per in result["external"].items():
        print(f"| {m} | " + " | ".join(f"{np.mean(per[n]):.3f}" for n in names) + " |")
    print("\n| agents | maps | greedy (claims) | partition | lower bound |")
    print("|---|---|---|---|---|")
    for n, e in result["marl_eval"].items():
        print(f"| {n} | {e['maps']} | {e['greedy']:.3f} | {e['partition']:.3f} "
              f"| {e['lower_bound_time_save']:.3f} |")


def main(args: Args) -> None:
    if args.report:
        return report(args.per_size)
    scenarios = load_scenarios(args)
    rows, ms = evaluate(args.planner, scenarios)
    if args.out:
        with open(args.out, "w") as f:
            for s, r in zip(scenarios, rows):
                f.write(json.dumps({"size": list(s.obstacles.shape), **r}) + "\n")
    print(json.dumps(dict(planner=args.planner, scenarios=len(rows), agents=args.agents,
                          overlap_mean=round(float(np.mean([r["overlap"] for r in rows])), 4),
                          time_save_mean=round(float(np.mean([r["time_save"] for r in rows])), 4),
                          plan_ms_per_map=round(ms, 2))))


if __name__ == "__main__":
    try:
        main(tyro.cli(Args))
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
