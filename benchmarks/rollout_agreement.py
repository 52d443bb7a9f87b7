"""Would expert iteration with --teacher policy-rollout label anything new? A probe of issue 17's teacher.

    python benchmarks/rollout_agreement.py                 # ~10 min on one core

A rainbow_cpp export (--model, with the heuristic fallback, as evaluate.py runs it) walks fresh maps of each family
(sizes --min-size..--size); every --every-th step each unfinished world is labelled twice: by the one-step rollout of
the model itself (rainbow_cpp.policy_rollout_actions, the policy-rollout teacher and evaluate.py's rainbow-rollout)
and by the one-step rollout of greedy-far-first, the model's hint (GridWorldCore.rollout_actions, the rollout teacher).

Prints, cumulated family after family: the states, how often the two labels agree, how often each leaves the model's
own move, and how often the model's rollout leaves it for the far-first rollout's move; one JSON line at the end.
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
import torch  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import gridworld as gw  # noqa: E402
import rainbow_cpp as rc  # noqa: E402

FAMILIES = ("random", *gw.STRUCTURED_FAMILIES)


@dataclass
class Args:
    model: str = os.path.join(ROOT, "models", "rainbow_cpp.pt")
    """the rainbow_cpp export that walks and whose rollout labels"""
    worlds: int = 20
    """maps walked at once, per family"""
    size: int = 24
    """largest map side"""
    min_size: int = 8
    """smallest map side"""
    every: int = 3
    """label every this many steps of the walk"""
    seed: int = 778
    """maps (no dataset uses this seed)"""
    cpu: int = 0
    """the CPU to pin to (-1: no pinning)"""


def main(args: Args) -> None:
    pin(args.cpu)
    torch.set_num_threads(1)
    q = rc.load_policy(args.model)
    spec = q.network()
    hint, far_first, observation = bool(spec.get("hint")), bool(spec.get("far_first")), rc.observation_settings(spec)
    count = dict(states=0, agree=0, policy_rollout_departs=0, far_first_rollout_departs=0, departs_to_far_first=0)
    tick = time.perf_counter()
    q.reset_noise(False)
    for family in FAMILIES:
        scenarios = gw.generate_scenarios(args.worlds, seed=args.seed, size=args.size, min_size=args.min_size,
                                          random_size=True, map_family=family, number_obstacles=20,
                                          obstacles_random=True, battery_factor=5.0)
        n = len(scenarios)
        core = gw.GridWorldCore(rc.eval_config(scenarios, "full", 3, 0.0, observation), n, seed=0)
        core.configure(scenarios=scenarios)
        core.reset()
        stack = rc.Stacker(n, spec["frames"], *rc.frame_shape(observation)[::-1], hint=hint)
        stack.push(rc.observe(core, hint, True, far_first), np.ones(n, bool))
        fallback = rc.Fallback(core, False, True, far_first)
        done, t = np.zeros(n, bool), 0
        with torch.no_grad():
            while not done.all():
                live = np.flatnonzero(~done)
                maps, extras = stack.get()
                own = np.full(n, gw.WAIT)
                own[live] = q(*rc.to_torch(maps[live], extras[live])).argmax(1).numpy()
                if t % args.every == 0:
                    searched = rc.policy_rollout_actions(core, live, q, stack, True, far_first)
                    taught = core.rollout_actions(live, True, far_first=far_first)
                    count["states"] += len(live)
                    count["agree"] += int((searched == taught).sum())
                    count["policy_rollout_departs"] += int((searched != own[live]).sum())
                    count["far_first_rollout_departs"] += int((taught != own[live]).sum())
                    count["departs_to_far_first"] += int(((searched != own[live]) & (searched == taught)).sum())
                action, _ = fallback.act(core, own, done)
                ev = core.step(np.where(done, gw.WAIT, action)[:, None])
                fallback.stepped(core, ev["new"][:, 0])
                done |= ev["terminated"] | ev["truncated"]
                stack.push(rc.observe(core, hint, True, far_first), np.zeros(n, bool))
                t += 1
        print(f"{family:10s} {count} ({time.perf_counter() - tick:.0f} s)", flush=True)
    s, departs = max(count["states"], 1), max(count["policy_rollout_departs"], 1)
    print(f"the two rollouts agree at {count['agree'] / s:.3f} of {count['states']:,} states; the model's rollout "
          f"leaves its move at {count['policy_rollout_departs'] / s:.3f}, far-first's rollout at "
          f"{count['far_first_rollout_departs'] / s:.3f}; {count['departs_to_far_first'] / departs:.3f} "
          "of the former's departures are the latter's move")
    print(json.dumps({**count, "seconds": round(time.perf_counter() - tick, 1)}))


if __name__ == "__main__":
    with gw.cli_errors():  # a ValueError or Ctrl-C: one line, no traceback
        try:
            main(gw.cli(Args))
        except OSError as e:
            sys.exit(f"error: {e}")
