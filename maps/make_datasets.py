"""Regenerate the evaluation datasets in maps/ (deterministic from --seed).

    python maps/make_datasets.py            # writes maps/*.npz, about a minute on 2 cores

Every scenario is drawn by gridworld's Algorithms 9-10 (random obstacles, random distinct
starts, cells unreachable from agent 0 filled) and stored with gridworld.save_dataset; load
them with gridworld.load_dataset or EnvConfig(dataset_path=..., load_state=True). Extra
per-scenario columns (read with numpy.load) record the settings each scenario was drawn with.
"""
from __future__ import annotations

import os
import sys
from dataclasses import dataclass

import numpy as np
import tyro

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import gridworld  # noqa: E402

SIZES = range(5, 31)  # §6.5.1.1: map sizes 5..30, one subset per size (26 subsets)


@dataclass
class Args:
    seed: int = 0
    """base seed; every subset derives its own seed from it"""
    out: str = os.path.dirname(os.path.abspath(__file__))
    """folder for the .npz files"""
    per_size: int = 100
    """scenarios per map size in cpp_eval and marl_eval (§6.5.1.1, §7.5.1)"""
    p2p_total: int = 10_000
    """point-to-point scenarios in p2p_eval (§6.5.1.2)"""
    marl_agents: int = 15
    """starts stored per marl_eval layout; the N-agent scenario uses the first N (Fig. 7.5)"""
    ch5_per_setting: int = 100
    """scenarios per (size, obstacles) setting of ch5_eval (the dissertation used 1,000)"""


def draw(n: int, seed: int, **config) -> list[gridworld.Scenario]:
    return gridworld.generate_scenarios(n, seed=seed, battery_factor=5.0, **config)


def subset(args: Args, tag: int, size: int, max_obstacle_fraction: float, n: int, **config):
    """n maps of one size: obstacles uniform in [0, fraction of the cells], random starts."""
    return draw(n, seed=args.seed * 1_000_003 + tag * 1000 + size, size=size,
                number_obstacles=int(max_obstacle_fraction * size * size), obstacles_random=True,
                **config)


def by_size(args: Args, tag: int, max_obstacle_fraction: float, per_size: int, **config):
    """One subset per size in SIZES, concatenated, with the size of each scenario."""
    scenarios = [s for size in SIZES
                 for s in subset(args, tag, size, max_obstacle_fraction, per_size, **config)]
    return scenarios, np.repeat(list(SIZES), per_size)


def main(args: Args) -> None:
    os.makedirs(args.out, exist_ok=True)

    def save(name, scenarios, **columns):
        path = os.path.join(args.out, f"{name}.npz")
        gridworld.save_dataset(path, scenarios, **columns)
        print(f"{path}: {len(scenarios)} scenarios, {os.path.getsize(path) / 1e3:.0f} kB")

    scenarios, sizes = by_size(args, 1, 0.10, args.per_size)  # §6.5.1.1 complete coverage
    save("cpp_eval", scenarios, size=sizes)

    per = -(-args.p2p_total // len(SIZES))  # §6.5.1.2 one point of interest, random target
    scenarios, sizes = by_size(args, 2, 0.10, per, number_points_of_interest=1)
    save("p2p_eval", scenarios[:args.p2p_total], size=sizes[:args.p2p_total])

    scenarios, sizes = by_size(args, 3, 0.15, args.per_size, number_agents=args.marl_agents)
    save("marl_eval", scenarios, size=sizes)  # §7.5.1: up to 15% obstacles, agents as prefixes

    corners = []  # §5.4.1: 6x6, starts in the corners, no obstacle or one random obstacle
    for obstacles in (0, 1):
        for k, corner in enumerate([[0, 0], [0, 5], [5, 0], [5, 5]]):
            corners += draw(25, seed=args.seed * 1_000_003 + 4000 + 10 * obstacles + k, size=6,
                            number_obstacles=obstacles, starting_position=[corner],
                            starting_position_random=False)
    save("ch5_6x6", corners, requested_obstacles=np.repeat([0, 1], 100))

    settings = [(s, o) for s in (4, 6, 8, 10, 12, 15, 20) for o in (0, 2, 4, 6, 8, 10)]
    scenarios, columns = [], []
    for i, (size, obstacles) in enumerate(settings):  # Fig. 5.5: larger, more cluttered maps
        scenarios += draw(args.ch5_per_setting, seed=args.seed * 1_000_003 + 5000 + i, size=size,
                          number_obstacles=obstacles)
        columns += [(size, obstacles)] * args.ch5_per_setting
    columns = np.array(columns)
    save("ch5_eval", scenarios, size=columns[:, 0], requested_obstacles=columns[:, 1])


if __name__ == "__main__":
    main(tyro.cli(Args))
