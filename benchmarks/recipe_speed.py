"""Environment steps/s of the dissertation's recipe (issue 43) and where its wall time goes, on one torch thread.

    taskset -c 1 python benchmarks/recipe_speed.py                 # Table 6.1's settings, the compact network
    taskset -c 1 python benchmarks/recipe_speed.py --steps 2000    # a quicker look

rainbow_cpp.main runs the scale run's flags (Table 6.1: batch 32 every K = 4 steps, replay ratio 8, 16 worlds; stage
fi1 of Table 6.2 with the dissertation's random-tie heuristic) twice, to learning_starts and `steps` further, so that
start-up and the heuristic's prefill cancel: steps/s = steps / (the difference of the two walls). The longer run is
also profiled (cProfile, which slows it a little) and its wall time split into the parts below, by the cumulative time
of the functions that do them.
"""
from __future__ import annotations

import cProfile
import os
import pstats
import sys
import tempfile
import time
from dataclasses import dataclass

import torch
import tyro

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import gridworld  # noqa: E402
import rainbow_cpp as rc  # noqa: E402

RECIPE = ["--network", "compact", "--no-cuda", "--threads", "1", "--no-heuristic-dead-ends", "--heuristic-random-ties",
          "--no-camera-stages", "--learning-rate", "5e-4", "--eval-every", "0", "--save-every", "0", "--quiet"]
# part -> (file suffix, function name) whose cumulative time is that part; "update" leaves out its sampling
PARTS = {
    "the update (forward, backward, Adam, priorities, target, noise)": ("rainbow_cpp.py", "learn"),
    "replay sampling (frames, n-step returns, weights)": ("rainbow_cpp.py", "batch"),
    "stepping the worlds": ("gridworld.py", "step"),
    "observations": ("gridworld.py", "observe"),
    "the heuristic (imitation conditions, partial resets)": ("gridworld.py", "heuristic_actions"),
    "replay writes": ("rainbow_cpp.py", "add_frames"),
    "resets": ("gridworld.py", "reset"),
}


@dataclass
class Args:
    steps: int = 6000
    """environment steps timed after learning starts"""
    learning_starts: int = 5000
    """environment steps of the heuristic's prefill (Table 6.1)"""
    buffer_size: int = 100_000
    """replay memory (Table 6.1's million costs 1.7 GiB and the same time a step)"""
    json: str | None = None
    """also write the figures here"""
    overwrite: bool = False
    """let --json replace a file that is there already"""


def run(total: int, a: Args, workdir: str, name: str, profile: cProfile.Profile | None = None) -> float:
    args = tyro.cli(rc.Args, args=[*RECIPE, "--total-steps", str(total), "--learning-starts", str(a.learning_starts),
                                   "--buffer-size", str(a.buffer_size), "--run-name", name])
    start = time.perf_counter()
    if profile is None:
        rc.main(args)
    else:
        profile.runcall(rc.main, args)
    return time.perf_counter() - start


def split(profile: cProfile.Profile) -> dict[str, float]:
    """Seconds of each part of PARTS, from the profile's cumulative times."""
    stats = pstats.Stats(profile).stats
    seconds = {part: 0.0 for part in PARTS}
    for (path, _, function), (_, _, _, cumulative, _) in stats.items():
        for part, (suffix, name) in PARTS.items():
            if path.endswith(suffix) and function == name:
                seconds[part] += cumulative
    seconds["the update (forward, backward, Adam, priorities, target, noise)"] -= \
        seconds["replay sampling (frames, n-step returns, weights)"]
    return seconds


def main(a: Args) -> None:
    if a.steps < 16 or a.learning_starts < 16 or a.buffer_size < 1024:
        raise ValueError("--steps and --learning-starts must be >= 16 and --buffer-size >= 1024")
    if a.json:
        a.json = os.path.abspath(gridworld.check_output(a.json, "result", a.overwrite, "--json"))  # before the runs
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as workdir:
        here = os.getcwd()
        os.chdir(workdir)
        try:
            short = run(a.learning_starts, a, workdir, "short")
            long = run(a.learning_starts + a.steps, a, workdir, "long")
            profile = cProfile.Profile()
            profiled = run(a.learning_starts + a.steps, a, workdir, "profiled", profile)
        finally:
            os.chdir(here)
    sps = a.steps / max(long - short, 1e-9)
    parts = split(profile)
    print(f"{sps:.0f} environment steps/s past learning_starts ({a.steps:,} steps in {long - short:.1f} s, one thread)")
    print(f"profiled run ({a.learning_starts + a.steps:,} steps, prefill included): {profiled:.1f} s")
    for part, s in sorted(parts.items(), key=lambda kv: -kv[1]):
        print(f"  {100 * s / profiled:5.1f}%  {s:6.1f} s  {part}")
    rest = profiled - sum(parts.values())
    print(f"  {100 * rest / profiled:5.1f}%  {rest:6.1f} s  the rest (acting forward, bookkeeping, start-up)")
    if a.json:
        gridworld.write_json(a.json, {"env_steps_per_s": round(sps, 1), "steps": a.steps,
                                      "profiled_seconds": round(profiled, 1),
                                      "parts_seconds": {k: round(v, 2) for k, v in parts.items()}, "flags": RECIPE,
                                      "torch": torch.__version__}, "result", a.overwrite, "--json")


if __name__ == "__main__":
    try:
        main(tyro.cli(Args))
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
