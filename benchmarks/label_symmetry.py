"""How much of the rollout's label is the heuristic's arbitrary tie order? A probe of issue 17's teacher.

    python benchmarks/label_symmetry.py                    # ~4 min on one core

Greedy-far-first walks fresh maps of every family (sizes --min-size..--size); every --every-th step each unfinished
world becomes a state (its agent's cell the far-first start). Each state is labelled by the one-step rollout of
greedy-far-first (GridWorldCore.rollout_actions, costs=True) in the 8 mirrored and turned copies of its map
(gridworld._symmetric). Only the heuristic's last tie order, row-major, differs between the copies, so a label that
changes between them is one no student can read off the map.

Prints, over the states whose moves' costs differ: how often one copy's cheapest move is a cheapest move in another
copy; how often the cheapest move by the mean of the 4 quarter turns is one by the mean of the 4 mirror images; how often
greedy-far-first's own move is a cheapest move by one copy and by the mean of all 8; each by family; one JSON line.
"""
from __future__ import annotations

import os

from cpu import pin  # sets one BLAS thread: imported before numpy

# isort: split

import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass  # noqa: E402

import numpy as np  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import gridworld as gw  # noqa: E402

FAMILIES = ("random", *gw.STRUCTURED_FAMILIES)


@dataclass
class Args:
    worlds: int = 24
    """maps walked at once, per family"""
    size: int = 24
    """largest map side"""
    min_size: int = 8
    """smallest map side"""
    every: int = 7
    """a state every this many steps of the walk"""
    seed: int = 710_000
    """maps (no dataset uses these seeds)"""
    cpu: int = 0
    """the CPU to pin to (-1: no pinning)"""


def states(args: Args) -> tuple[list[gw.Scenario], np.ndarray]:
    """The states of greedy-far-first's walks, as scenarios starting at the agent's cell, and their families."""
    out, family = [], []
    for i, name in enumerate(FAMILIES):
        config = gw.EnvConfig(size=args.size, min_size=args.min_size, random_size=True, map_family=name,
                              number_obstacles=int(0.15 * args.size ** 2), obstacles_random=True, battery_factor=1e6)
        core = gw.GridWorldCore(config, args.worlds, seed=args.seed + i)
        core.reset()
        c, H, W = core.c, core.H, core.W
        for t in range(1, 10 * H * W):
            live = core.remaining > 0
            if not live.any():
                break
            if t % args.every == 0:
                cells = core.agent_cells()[:, 0]
                out += [gw.Scenario(core.obstacle[b, c:c + H, c:c + W].copy(), cells[b:b + 1].copy(),
                                    core.covered[b, c:c + H, c:c + W].copy()) for b in np.flatnonzero(live)]
                family += [name] * int(live.sum())
            move = core.heuristic_actions(random_ties=False, dead_ends_first=True, far_first=True)[:, 0]
            core.step(np.where(live, move, gw.WAIT)[:, None])
    return out, np.array(family)


def labels(scenarios: list[gw.Scenario]) -> tuple[np.ndarray, np.ndarray]:
    """Each copy's costs of the moves in the original's move order, (8, S, 4) (-1: not a try), and
    greedy-far-first's move, (S,)."""
    config = gw.EnvConfig(load_state=True, load_random=False, battery_factor=1e6)
    costs = []
    for k in range(8):
        core = gw.GridWorldCore(config, len(scenarios))
        core.configure(scenarios=[gw.Scenario(gw._symmetric(s.obstacles, k),
                                              gw._symmetric_cells(s.starts, k, *s.obstacles.shape),
                                              gw._symmetric(s.covered, k)) for s in scenarios])
        core.reset()
        costs.append(core.rollout_actions(far_first=True, costs=True)[1][:, gw._symmetric_moves(k)])
        if k == 0:
            move = core.heuristic_actions(random_ties=False, dead_ends_first=True, far_first=True)[:, 0]
    return np.stack(costs), move


def main(args: Args) -> None:
    for flag, value in (("--worlds", args.worlds), ("--every", args.every)):
        if value < 1:
            raise ValueError(f"{flag} must be >= 1, got {value}")
    if not 2 <= args.min_size <= args.size <= gw.MAX_MAP_SIDE:
        raise ValueError(f"need 2 <= --min-size <= --size <= {gw.MAX_MAP_SIDE}, got {args.min_size} and {args.size}")
    pin(args.cpu)
    tick = time.perf_counter()
    scenarios, family = states(args)
    cost, move = labels(scenarios)
    tried = (cost >= 0).all(0)
    score = np.where(tried, cost.astype(float), np.inf)
    differ = (tried.sum(1) >= 2) & (np.where(tried, cost[0], -1).max(1) > score[0].min(1))

    def cheapest(pick: np.ndarray, by: np.ndarray) -> np.ndarray:  # is `pick` a cheapest move by the costs `by`
        return by[np.arange(len(pick)), pick] == by.min(1)

    first, second = score[:4].mean(0), score[4:].mean(0)
    mean = score.mean(0)
    measures = {
        "one copy's pick, cheapest in another": lambda s: np.mean(
            [cheapest(score[j].argmin(1), score[k])[s].mean() for j in range(8) for k in range(8) if j != k]),
        "pick by the mean of 4 turns, cheapest by the 4 mirrors": lambda s: cheapest(first.argmin(1), second)[s].mean(),
        "greedy-far-first's move, cheapest in one copy": lambda s: np.mean(
            [cheapest(move, score[k])[s].mean() for k in range(8)]),
        "greedy-far-first's move, cheapest by the mean of 8": lambda s: cheapest(move, mean)[s].mean(),
    }
    result = {"states": int(differ.sum()), "families": {}}
    print(f"{len(scenarios):,} states, {differ.sum():,} where the moves' costs differ "
          f"({time.perf_counter() - tick:.0f} s)")
    for name, measure in measures.items():
        result[name] = round(float(measure(differ)), 3)
        by_family = {f: round(float(measure(differ & (family == f))), 3) for f in FAMILIES}
        for f, v in by_family.items():
            result["families"].setdefault(f, {})[name] = v
        print(f"{name:55s} {result[name]:.3f}  (" + ", ".join(f"{f} {v:.3f}" for f, v in by_family.items()) + ")")
    result["seconds"] = round(time.perf_counter() - tick, 1)
    print(json.dumps(result))


if __name__ == "__main__":
    with gw.cli_errors():  # a bad flag or Ctrl-C: one line, no traceback
        main(gw.cli(Args))
