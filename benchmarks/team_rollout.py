"""Time-save factor and planning time of the multiagent rollout planner against its base, on one core.

    python benchmarks/team_rollout.py                          # marl_eval N = 2, 5, 10 and structured_eval N = 5
    python benchmarks/team_rollout.py --agents 5 --structured-every 0   # marl_eval at N = 5 only

The rollout planner with several agents (classical_cpp.team_rollout_many: GridWorldCore.team_rollout_actions at
every step, Bertsekas' multiagent rollout of greedy-dead-ends with claims) beside its base, greedy-dead-ends with
claims, and greedy with claims, on the same scenarios: every --marl-every-th marl_eval layout of sizes 10-30
(classical_cpp.marl_eval_subset) with its first N stored starts, and every --structured-every-th structured_eval map
(all of sizes 10-30) with its first N starts. Mean time-save factor t_sf = T / n_poi(s0) (eq. 7.6, as evaluate.py and
report.py count it) beside the lower bound ceil(n_poi / N) / n_poi averaged the same way; each planner's seconds
per map and milliseconds per team step (one joint move of one map), planning and replay, the maps batched 64 at a
time as classical_cpp.evaluate plans them. Every path is replayed by classical_cpp.replay (legal and complete); the rollout's
makespan is checked against its base's on every map (never longer). numpy runs on one thread, pinned to one CPU
(--cpu). Prints a Markdown table and one JSON line with every number.
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):  # before numpy loads
    os.environ[_var] = "1"

import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass  # noqa: E402

import numpy as np  # noqa: E402
import tyro  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import classical_cpp as cc  # noqa: E402
import gridworld  # noqa: E402

PLANNERS = ("greedy", "greedy-dead-ends", "rollout")


@dataclass
class Args:
    agents: tuple[int, ...] = (2, 5, 10)
    """team sizes on marl_eval"""
    marl_every: int = 100
    """every k-th marl_eval layout of sizes 10-30 (100: 21 maps, one of each size)"""
    structured_every: int = 21
    """every k-th structured_eval map (21: 80 maps, all families and sizes); 0: none"""
    structured_agents: int = 5
    """the team size on structured_eval"""
    cpu: int = -1
    """the CPU to pin to (-1: the first one this process may use)"""


def structured_subset(agents: int, every: int) -> tuple[list, np.ndarray]:
    """Every `every`-th structured_eval map with its first `agents` starts (covered), and their sizes."""
    path = os.path.join(cc.ROOT, "maps", "structured_eval.npz")
    sizes = np.load(path)["size"][::every]
    maps = gridworld.load_dataset(path)[::every]
    return [cc.with_starts(gridworld.Scenario(s.obstacles, s.starts[:agents])) for s in maps], sizes


def measure(label: str, agents: int, scenarios: list, sizes: np.ndarray) -> dict:
    """Every planner on the scenarios: mean time-save factor, the lower bound, the time it takes (with the replay)."""
    bound = np.mean([cc.lower_bound(s) / max(int((~s.obstacles).sum()) - agents, 1) for s in scenarios])
    entry = {"maps": len(scenarios), "sizes": [int(sizes.min()), int(sizes.max())],
             "lower_bound_time_save": round(float(bound), 4)}
    steps = {}
    for name in PLANNERS:
        t0 = time.perf_counter()
        rows, _ = cc.evaluate(name, scenarios)  # plans 64 maps at a time and replays every path
        seconds = time.perf_counter() - t0
        steps[name] = np.array([r["steps"] for r in rows])
        entry[name] = {"time_save": round(float(np.mean([r["time_save"] for r in rows])), 4),
                       "s_per_map": round(seconds / len(rows), 3),
                       "ms_per_team_step": round(1000 * seconds / steps[name].sum(), 2)}
    worse = int((steps["rollout"] > steps["greedy-dead-ends"]).sum())
    if worse:
        raise SystemExit(f"error: {label} N = {agents}: the rollout is longer than its base on {worse} map(s)")
    r = entry["rollout"]
    print(f"| {label} | {agents} | {len(scenarios)} | {entry['greedy']['time_save']:.3f} | "
          f"{entry['greedy-dead-ends']['time_save']:.3f} | **{r['time_save']:.3f}** | {bound:.3f} | "
          f"{r['s_per_map']:.2f} | {r['ms_per_team_step']:.1f} |", flush=True)
    return entry


def main(args: Args) -> dict:
    if not args.agents or min(args.agents) < 2 or args.structured_agents < 2:
        raise SystemExit("error: --agents and --structured-agents must be >= 2 (one agent: benchmarks/rollout_planner.py)")
    if args.marl_every < 1 or args.structured_every < 0:
        raise SystemExit("error: --marl-every must be >= 1 and --structured-every >= 0")
    allowed = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    if allowed:
        cpu = allowed[0] if args.cpu < 0 else args.cpu
        if cpu not in allowed:
            raise SystemExit(f"error: --cpu {cpu} is not one of this process's CPUs {allowed}")
        os.sched_setaffinity(0, {cpu})
    out: dict = {"marl_every": args.marl_every, "structured_every": args.structured_every, "marl_eval": {},
                 "structured_eval": {}}
    t0 = time.perf_counter()
    print("| dataset | N | maps | greedy (claims) | greedy-dead-ends (claims) | rollout | lower bound | rollout s/map | "
          "rollout ms/team step |")
    print("|---|---|---|---|---|---|---|---|---|")
    for n in args.agents:
        scenarios, sizes = cc.marl_eval_subset(n, args.marl_every)
        out["marl_eval"][str(n)] = measure("marl_eval", n, scenarios, sizes)
    if args.structured_every:
        n = args.structured_agents
        out["structured_eval"][str(n)] = measure("structured_eval", n, *structured_subset(n, args.structured_every))
    out["wall_seconds"] = round(time.perf_counter() - t0, 1)
    print("\n" + json.dumps(out))
    return out


if __name__ == "__main__":
    main(tyro.cli(Args))
