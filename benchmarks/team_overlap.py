"""Where a greedy-far-first team loses time: its overlap and idle steps against one agent's overlap on the same maps.

    python benchmarks/team_overlap.py                       # 1 in 10 marl_eval layouts, N = 2 (~30 s)
    python benchmarks/team_overlap.py --agents 5 --structured-every 21

Greedy-far-first with claims (classical_cpp.plan) covers the scenarios of report.py's team sets: every --every-th
marl_eval layout of sizes 10-30 with its first N starts (classical_cpp.marl_eval_subset), or with --structured-every
every such structured_eval map (classical_cpp.structured_team_subset). Its makespan T gives t_sf = T / n (n: points of
interest at the start) = (1 + overlap + idle) / N, where overlap = (agent moves onto covered cells) / n and idle =
(agent-steps without a move) / n, both as shares of the work (each agent's share is n / N). Beside it, one agent
(the first start) covers the same map with greedy-far-first: its overlap is what the team would pay per share if
teaming cost nothing. The team's overlap is also split by tenths of the makespan, the agent-steps into new cells,
covered cells and waits, and each agent's last new cell is timed as a share of the makespan (the mean agent, and the
first to run out). Prints a Markdown table and one JSON line.
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

import classical_cpp as cc  # noqa: E402
from gridworld import Scenario, cli, cli_errors  # noqa: E402


@dataclass
class Args:
    agents: int = 2
    """team size N"""
    every: int = 10
    """every this many marl_eval layouts of sizes 10-30 (report.py's team subset: 10)"""
    structured_every: int = 0
    """> 0: every this many structured_eval maps of sizes 10-30 instead of marl_eval"""
    cpu: int = 0
    """the CPU to pin to (-1: no pinning)"""


def shares(scenario: Scenario, paths: list[np.ndarray]) -> tuple[float, float, float, np.ndarray, np.ndarray]:
    """t_sf, overlap and idle as shares of the work (gridworld's counts: classical_cpp.replay), the overlap by
    tenths of the makespan, and each agent's last new cell as a share of the makespan, of one plan."""
    m = cc.replay(scenario, paths)
    n, T, N = m["n_poi_start"], m["steps"], len(paths)
    covered, by_tenth, last_new = scenario.covered.copy(), np.zeros(10), np.zeros(N)
    for t in range(1, T + 1):  # which step each revisit and each agent's last new cell came at
        for i, p in enumerate(paths):
            if t < len(p) and (p[t] != p[t - 1]).any():
                revisit = covered[p[t][0], p[t][1]]
                by_tenth[min(9, 10 * (t - 1) // T)] += revisit
                if not revisit:
                    last_new[i] = t
                covered[p[t][0], p[t][1]] = True
    return T / n, m["revisits"] / n, (N * T - m["revisits"] - m["new_cells"]) / n, by_tenth / n, last_new / T


def main(args: Args) -> None:
    if args.agents < 2:
        sys.exit("error: --agents must be at least 2 (a team)")
    if args.every < 1 or args.structured_every < 0:
        sys.exit(f"error: need --every >= 1 and --structured-every >= 0, got {args.every} and {args.structured_every}")
    pin(args.cpu)
    tick = time.perf_counter()
    if args.structured_every > 0:
        team, _ = cc.structured_team_subset(args.agents, args.structured_every)
        where = f"1 in {args.structured_every} structured_eval maps"
    else:
        team, _ = cc.marl_eval_subset(args.agents, every=args.every)
        where = f"1 in {args.every} marl_eval layouts"
    alone = [cc.with_starts(Scenario(s.obstacles, s.starts[:1])) for s in team]
    per_map = [shares(s, p) for s, p in zip(team, cc.plan("greedy-far-first", team))]
    tsf, overlap, idle = np.mean([m[:3] for m in per_map], 0)
    tenths = np.mean([m[3] for m in per_map], 0)
    last_new = np.mean([m[4].mean() for m in per_map])  # the mean agent's last new cell, share of the makespan
    first_done = np.mean([m[4].min() for m in per_map])  # the first agent out of new cells
    work = 1 + overlap + idle  # agent-steps as shares of the work: new cells (1), revisits, waits
    single = np.mean([shares(s, p)[1] for s, p in zip(alone, cc.plan("greedy-far-first", alone))])
    result = {"agents": args.agents, "maps": len(team), "set": where, "time_save": round(float(tsf), 4),
              "team_overlap": round(float(overlap), 4), "team_idle": round(float(idle), 4),
              "single_agent_overlap": round(float(single), 4),
              "team_overlap_by_tenth": [round(float(v), 4) for v in tenths],
              "agent_steps_new_covered_idle": [round(float(v / work), 4) for v in (1, overlap, idle)],
              "last_new_cell_mean_agent": round(float(last_new), 4),
              "last_new_cell_first_agent": round(float(first_done), 4),
              "seconds": round(time.perf_counter() - tick, 1)}
    print(f"greedy-far-first, N = {args.agents}, {len(team)} maps ({where}):\n")
    print("| t_sf | team overlap (share of the work) | team idle | one agent's overlap, same maps |")
    print("|---|---|---|---|")
    print(f"| {tsf:.4f} | {overlap:.4f} | {idle:.4f} | {single:.4f} |\n")
    print("team overlap by tenth of the makespan: " + " ".join(f"{v:.4f}" for v in tenths))
    print(f"agent-steps: {1 / work:.1%} onto new cells, {overlap / work:.1%} onto covered cells, {idle / work:.1%} "
          f"without a move; last new cell at {last_new:.1%} of the makespan for the mean agent, "
          f"{first_done:.1%} for the first agent to run out")
    print(json.dumps(result))


if __name__ == "__main__":
    with cli_errors():  # a bad flag or Ctrl-C: one line, no traceback
        main(cli(Args))
