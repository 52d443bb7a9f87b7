"""Labels per second of the rollout teachers, as rainbow_cpp asks for them: one batched call for every world of a core.

    python benchmarks/rollout_labels.py                          # every family at sizes 10, 20, 30 (a few minutes)
    python benchmarks/rollout_labels.py --sizes 20 --families maze --policy ""   # one cell of the table

For each map family and size: --worlds worlds (sizes min(5, size)..size, obstacles as rainbow_cpp's stages), walked
--walked of their free cells by the deterministic heuristic with one random move in three (states a learner visits),
then GridWorldCore.rollout_actions (the `rollout` teacher) is called on all of them again and again for --seconds; the
first call, which builds the worlds' shortest-path tables, is timed apart. With --policy (a rainbow_cpp export),
rainbow_cpp.policy_rollout_actions (the `policy-rollout` teacher) is timed the same way. numpy and torch run on one
thread, pinned to one CPU (--cpu). Prints a Markdown table and one JSON line with every number.
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


@dataclass
class Args:
    families: tuple[str, ...] = ("random", "rooms", "corridors", "clutter", "maze")
    """map families (gridworld.MAP_FAMILIES)"""
    sizes: tuple[int, ...] = (10, 20, 30)
    """largest map side of each row"""
    worlds: int = 16
    """worlds labelled in one call (rainbow_cpp's --num-envs)"""
    walked: float = 0.4
    """fraction of each map's free cells walked before labelling"""
    seconds: float = 3.0
    """timing per cell of the table, after the first call"""
    policy: str = os.path.join(ROOT, "models", "rainbow_cpp.pt")
    """a rainbow_cpp export whose policy-rollout is timed too ("" : none)"""
    cpu: int = -1
    """the CPU to pin to (-1: the first one this process may use)"""


def mid_episode(family: str, size: int, args: Args, observation: dict) -> gw.GridWorldCore:
    core = gw.GridWorldCore(gw.EnvConfig(size=size, min_size=min(5, size), random_size=True, map_family=family,
                                         number_obstacles=size * size // 10, obstacles_random=True,
                                         battery_factor=1e6, **observation), args.worlds, seed=size)
    core.reset()
    rng = np.random.default_rng(size)
    for t in range(int(args.walked * size * size)):
        act = rng.integers(0, 4, args.worlds) if t % 3 == 0 else core.heuristic_actions(False, True)[:, 0]
        core.step(act[:, None])
    return core


def rate(label, *inputs, seconds: float) -> tuple[float, float]:
    """(seconds of the first call label(*inputs), labels per second of the calls after it); inputs[1]: the worlds."""
    t0 = time.perf_counter()
    label(*inputs)
    first, calls, t1 = time.perf_counter() - t0, 0, time.perf_counter()
    while time.perf_counter() - t1 < seconds:
        label(*inputs)
        calls += 1
    return first, calls * len(inputs[1]) / (time.perf_counter() - t1)


def main(args: Args) -> None:
    pin(args.cpu)
    unknown = sorted(set(args.families) - set(gw.MAP_FAMILIES))
    if unknown:
        raise SystemExit(f"error: unknown map families {', '.join(unknown)}; choose from {', '.join(gw.MAP_FAMILIES)}")
    q = None
    if args.policy:
        import torch

        import rainbow_cpp as rc
        torch.set_num_threads(1)
        try:
            q = rc.load_policy(args.policy)
        except ValueError as e:
            raise SystemExit(f"error: {e}") from None
        q.reset_noise(False)
        spec = q.network()
        observation = rc.observation_settings(spec)
        channels, view = rc.frame_shape(observation)
    out = []
    print("| family | size | rollout labels/s | first call (s) | policy-rollout labels/s |")
    print("|---|---|---|---|---|")
    for family in args.families:
        for size in args.sizes:
            core = mid_episode(family, size, args, observation if q is not None else {})
            live = np.flatnonzero(core.remaining > 0)
            row = dict(family=family, size=size, worlds=len(live))
            row["rollout_first_s"], row["rollout_labels_per_s"] = rate(gw.GridWorldCore.rollout_actions, core, live,
                                                                       seconds=args.seconds)
            if q is not None:
                stack = rc.Stacker(core.B, spec["frames"], view, channels, bool(spec.get("hint")))
                stack.push(rc.observe(core, stack.hint is not None), np.ones(core.B, bool))
                row["policy_rollout_labels_per_s"] = rate(rc.policy_rollout_actions, core, live, q, stack,
                                                          seconds=args.seconds)[1]
            out.append(row)
            policy = f"{row['policy_rollout_labels_per_s']:.1f}" if q is not None else "—"
            print(f"| {family} | {size} | {row['rollout_labels_per_s']:.0f} | {row['rollout_first_s']:.2f} | "
                  f"{policy} |", flush=True)
    print(json.dumps({"worlds": args.worlds, "walked": args.walked, "rows": out}))


if __name__ == "__main__":
    with gw.cli_errors():  # a bad flag or Ctrl-C: one line, no traceback
        main(gw.cli(Args))
