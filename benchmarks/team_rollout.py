"""Time-save factor and planning time of the multiagent rollout planner against its base, on one core.

    python benchmarks/team_rollout.py                          # marl_eval N = 2, 5, 10 and structured_eval N = 5
    python benchmarks/team_rollout.py --agents 5 --structured-every 0   # marl_eval at N = 5 only

The rollout planner with several agents (classical_cpp.team_rollout_many: gridworld.team_rollout_actions at
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

from cpu import pin  # sets one BLAS thread: imported before numpy

# isort: split

import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import classical_cpp as cc  # noqa: E402
import gridworld  # noqa: E402


@dataclass
class Args:
    agents: tuple[int, ...] = cc.TEAM_AGENTS
    """team sizes on marl_eval"""
    marl_every: int = cc.TEAM_MARL_EVERY
    """every k-th marl_eval layout of sizes 10-30 (100: 21 maps, one of each size)"""
    structured_every: int = cc.TEAM_STRUCTURED_EVERY
    """every k-th structured_eval map (21: 80 maps, all families and sizes); 0: none"""
    structured_agents: int = 5
    """the team size on structured_eval"""
    cpu: int = -1
    """the CPU to pin to (-1: the first one this process may use)"""


def main(args: Args) -> dict:
    pin(args.cpu)
    t0 = time.perf_counter()
    try:
        out = cc.compare_team_rollout(args.agents, args.marl_every, args.structured_every, args.structured_agents)
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
    out["wall_seconds"] = round(time.perf_counter() - t0, 1)
    print(cc.team_rollout_table(out))
    longer = {f"{d} N = {n}": e["rollout_longer_than_base"] for d in ("marl_eval", "structured_eval")
              for n, e in out[d].items() if e["rollout_longer_than_base"]}
    print("\n" + json.dumps(out))
    if longer:
        raise SystemExit(f"error: the rollout is longer than its base on {longer} map(s)")
    return out


if __name__ == "__main__":
    with gridworld.cli_errors():  # a bad flag or Ctrl-C: one line, no traceback
        main(gridworld.cli(Args))
