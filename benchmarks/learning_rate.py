"""The learning rate of the dissertation's recipe (issue 43): Table 6.2's stages 1-2 from scratch at several rates.

    taskset -c 1 python benchmarks/learning_rate.py --out runs/learning_rate.json       # ~10 min a rate, one core
    taskset -c 1 python benchmarks/learning_rate.py --network fig6.8 --rates 5e-5 5e-4 --total-steps 24000 \
        --eval-every 8000 --out results/learning_rate_fig68.json                       # Fig. 6.8, stage fi1
    taskset -c 1 python benchmarks/learning_rate.py --trainer rainbow_marl --rates 1e-5 5e-4 \
        --out results/learning_rate_marl.json                                       # Table 7.1's rate, N = 2
    python report.py render                                  # RESULTS.md's learning-rate tables read these JSONs

Each rate trains rainbow_cpp.py with the scale run's flags (the compact network on one thread, the dissertation's
random-tie heuristic as teacher and fallback, every §6.4.2 feature, no margin loss) over stages fi1 and fi2 of Table
6.2 at `--stage-steps-scale` (0.05: 50 k + 100 k steps), evaluating the greedy policy every `--eval-every` steps on
held-out cpp_eval maps up to the stage's size beside the heuristic on the same maps (the trainer's eval/overlap,
eval/heuristic_overlap, eval/completion and eval/heuristic_share), and records them with the last logged Q value.
With --trainer rainbow_marl the same for the team trainer from scratch (no --init-from) over its first two stages
(n2_env1-2 of §7.4.2.1, up to two agents), scored by the time-save factor on marl_eval beside the heuristic's.
"""
from __future__ import annotations

import datetime
import importlib
import json
import os
import sys
import tempfile
import time
from dataclasses import dataclass, field
from typing import Literal

import torch
import tyro
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import gridworld  # noqa: E402

COMMON = ["--no-cuda", "--threads", "1", "--no-heuristic-dead-ends", "--heuristic-random-ties", "--save-every", "0",
          "--quiet"]
RECIPE = {"rainbow_cpp": [*COMMON, "--no-camera-stages"], "rainbow_marl": [*COMMON, "--init-from", ""]}
SCORE = {"rainbow_cpp": "overlap", "rainbow_marl": "time_save"}  # what each trainer's evaluation logs (eval/...)


@dataclass
class Args:
    rates: list[float] = field(default_factory=lambda: [5e-5, 1.5e-4, 5e-4, 1.5e-3])
    """Adam learning rates to train with (Table 6.1's is 5e-5)"""
    stage_steps_scale: float = 0.05
    """Table 6.2's steps times this (0.05: fi1 50 k, fi2 100 k)"""
    eval_every: int = 25_000
    """environment steps between evaluations"""
    eval_maps: int = 64
    """held-out maps an evaluation"""
    seed: int = 1
    """the trainer's seed"""
    trainer: Literal["rainbow_cpp", "rainbow_marl"] = "rainbow_cpp"
    """the trainer swept: rainbow_cpp, or rainbow_marl (Table 7.1's rate is 1e-5) from scratch"""
    network: str = "compact"
    """the scale run's compact network, or fig6.8 (the dissertation's, ~12x the cost of an update)"""
    total_steps: int = 0
    """environment steps a rate trains (0: stages fi1 and fi2 whole at --stage-steps-scale)"""
    out: str = "runs/learning_rate.json"
    """where the results go, each rate as soon as it is done; a file there from the same settings is continued (its
    rates are kept and not rerun), one from other settings is refused"""


def rate_entry(run_dir: str, wall_seconds: float, score: str) -> dict:
    """One rate's figures from its run's TensorBoard events, and the git commit of the code that trained it."""
    tags = (f"eval/{score}", f"eval/heuristic_{score}", "eval/completion", "eval/heuristic_share")
    return {"git_commit": gridworld.provenance("benchmarks/learning_rate.py")["git_commit"],
            **{tag.split("/")[1]: scalars(run_dir, tag) for tag in tags},
            "q_values": scalars(run_dir, "losses/q_values")[-1:], "wall_seconds": round(wall_seconds)}


def scalars(run_dir: str, tag: str) -> list[tuple[int, float]]:
    acc = EventAccumulator(run_dir, size_guidance={"scalars": 0})
    acc.Reload()
    return [(e.step, round(e.value, 4)) for e in acc.Scalars(tag)] if tag in acc.Tags()["scalars"] else []


def main(a: Args) -> None:
    if not a.rates or any(not 0 < r < 1 for r in a.rates) or not 0 < a.stage_steps_scale <= 1 or a.eval_every < 16:
        raise ValueError("--rates in (0, 1), --stage-steps-scale in (0, 1] and --eval-every >= 16")
    gridworld.check_choices(a)
    trainer = importlib.import_module(a.trainer)
    if a.network not in trainer.NETWORKS or a.total_steps < 0:
        raise ValueError(f"--network must be one of {', '.join(trainer.NETWORKS)} and --total-steps >= 0")
    total = a.total_steps or int(1_000_000 * a.stage_steps_scale) + int(2_000_000 * a.stage_steps_scale)
    flags = ["--network", a.network, *RECIPE[a.trainer]]
    results = {"trainer": a.trainer, "flags": flags, "stage_steps_scale": a.stage_steps_scale, "total_steps": total,
               "seed": a.seed, "eval_every": a.eval_every, "eval_maps": a.eval_maps, "torch": torch.__version__, "rates": {},
               "provenance": gridworld.provenance("benchmarks/learning_rate.py")
               | {"date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")}}
    if os.path.exists(a.out):
        try:
            with open(a.out) as f:
                before = json.load(f)
            same = all(before[k] == results[k] for k in ("flags", "stage_steps_scale", "total_steps", "seed",
                                                         "eval_every", "eval_maps"))
        except (OSError, ValueError, KeyError, TypeError):
            same = False
        if not same:
            raise ValueError(f"--out {a.out} holds another sweep (or no sweep): choose another path")
        results["rates"] = before["rates"]
    gridworld.check_output(a.out, "result", overwrite=True, flag="--out")  # a sweep's own file, continued
    out = os.path.abspath(a.out)
    here = os.getcwd()
    with tempfile.TemporaryDirectory() as workdir:
        os.chdir(workdir)
        try:
            for rate in a.rates:
                if f"{rate:g}" in results["rates"]:
                    continue
                name = f"lr{rate:g}"
                args = tyro.cli(trainer.Args, args=[*flags, "--learning-rate", str(rate), "--stage-steps-scale",
                                               str(a.stage_steps_scale), "--total-steps", str(total), "--eval-every",
                                               str(a.eval_every), "--eval-maps", str(a.eval_maps), "--seed",
                                               str(a.seed), "--run-name", name])
                start = time.time()
                trainer.main(args)
                run_dir = os.path.join("runs", name)
                results["rates"][f"{rate:g}"] = rate_entry(run_dir, time.time() - start, SCORE[a.trainer])
                gridworld.write_json(out, results, "result", overwrite=True, flag="--out")
                print(f"learning rate {rate:g}: eval {SCORE[a.trainer]} {results['rates'][f'{rate:g}'][SCORE[a.trainer]]}",
                      flush=True)
        finally:
            os.chdir(here)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    try:
        main(tyro.cli(Args))
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
