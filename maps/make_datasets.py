"""Regenerate the evaluation datasets in maps/ (deterministic from --seed).

    python maps/make_datasets.py --overwrite   # rewrites the committed maps/*.npz, a few seconds on one core
    python maps/make_datasets.py --out runs/maps   # the same files elsewhere
    python maps/make_datasets.py --pictures # writes docs/images/map_families.png only
    python maps/make_datasets.py --crops maps/external/*.map --out runs   # writes runs/crops.npz only

Every scenario is drawn by gridworld's Algorithms 9-10 (random obstacles, random distinct
starts, cells unreachable from agent 0 filled) and stored with gridworld.save_dataset; load
them with gridworld.load_dataset or EnvConfig(dataset_path=..., load_state=True). Extra
per-scenario columns (read with numpy.load) record the settings each scenario was drawn with.
structured_eval holds gridworld's structured map families (rooms, corridors, clutter, maze;
default FamilyParams) with columns `family` and `size`, 15 distinct starts per map and no
pre-covered cell: the N-agent scenario is the map with its first N starts (the single-agent
one: the first start), covered at reset, as in marl_eval.
--crops cuts square crops from given maps (MovingAI's real layouts): maps no generator here drew, for checks.
Every setting is checked before anything is drawn, and the files are written only once all
are drawn, so a bad flag leaves --out untouched. A file already in --out (the committed maps/*.npz by default) is
replaced only with --overwrite.
"""
from __future__ import annotations

import os
import sys
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import gridworld  # noqa: E402

SIZES = range(5, 31)  # §6.5.1.1: map sizes 5..30, one subset per size (26 subsets)
CROP_SIDES = (16, 20, 24, 28)  # --crops: the sides of the squares cut from a map (at most its own)
STRUCTURED_SIZES = range(10, 31)  # structured_eval: maps big enough for rooms, passages and maze cells
NO_COVERAGE = ("marl_eval", "structured_eval")  # no covered cells stored: any prefix of the starts is a clean scenario
PICTURE = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "docs", "images",
                       "map_families.png")


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
    """starts stored per marl_eval and structured_eval map; the N-agent scenario uses the first N (Fig. 7.5)"""
    structured_per_size: int = 20
    """scenarios per (map family, size) in structured_eval (4 families x sizes 10..30)"""
    ch5_per_setting: int = 100
    """scenarios per (size, obstacles) setting of ch5_eval (the dissertation used 1,000)"""
    quiet: bool = False
    """no progress bar (there is none either when stdout is not a terminal)"""
    pictures: bool = False
    """write only docs/images/map_families.png: the first 20x20 map of each family (random: cpp_eval's); --overwrite
    to replace the committed one"""
    crops: tuple[str, ...] = ()
    """map files (MovingAI .map or ASCII): write only OUT/crops.npz, --crops-per-map square crops of each at random
    places, --marl-agents starts each (columns family: the map's name, size: the crop's side, row and col: its corner)"""
    crops_per_map: int = 8
    """crops cut from each --crops map"""
    overwrite: bool = False
    """replace .npz files already in --out (without it such a file is an error and nothing is written)"""


def draw(n: int, seed: int, **config) -> list[gridworld.Scenario]:
    return gridworld.generate_scenarios(n, seed=seed, battery_factor=5.0, **config)


def subset_draw(args: Args, tag: int, size: int, max_obstacle_fraction: float, n: int, **config) -> tuple:
    """The draw (n, seed, settings) of n maps of one size: obstacles uniform in [0, fraction of
    the cells], random starts."""
    return n, args.seed * 1_000_003 + tag * 1000 + size, dict(
        size=size, number_obstacles=int(max_obstacle_fraction * size * size), obstacles_random=True, **config)


def subset(args: Args, tag: int, size: int, max_obstacle_fraction: float, n: int, **config):
    """n maps of one size: obstacles uniform in [0, fraction of the cells], random starts."""
    n, seed, settings = subset_draw(args, tag, size, max_obstacle_fraction, n, **config)
    return draw(n, seed, **settings)


def by_size(args: Args, tag: int, max_obstacle_fraction: float, per_size: int, **config) -> list[tuple]:
    """One subset draw per size in SIZES, in order."""
    return [subset_draw(args, tag, size, max_obstacle_fraction, per_size, **config) for size in SIZES]


def structured_draws(args: Args) -> list[tuple]:
    """structured_eval's draws (n, seed, settings): per family in STRUCTURED_FAMILIES, one per size."""
    return [(args.structured_per_size, args.seed * 1_000_003 + 6000 + 100 * f + size,
             dict(size=size, map_family=family, number_agents=args.marl_agents))
            for f, family in enumerate(gridworld.STRUCTURED_FAMILIES) for size in STRUCTURED_SIZES]


def plan(args: Args) -> list[tuple[str, list[tuple], int, dict[str, np.ndarray]]]:
    """Every dataset as (name, its draws (n, seed, settings) in order, scenarios kept, extra columns)."""
    sizes = np.repeat(list(SIZES), args.per_size)
    per = -(-args.p2p_total // len(SIZES))  # §6.5.1.2 one point of interest, random target
    p2p_sizes = np.repeat(list(SIZES), per)[:args.p2p_total]
    corners = [(25, args.seed * 1_000_003 + 4000 + 10 * obstacles + k,  # §5.4.1: 6x6, corner starts, 0 or 1 obstacle
                dict(size=6, number_obstacles=obstacles, starting_position=[corner], starting_position_random=False))
               for obstacles in (0, 1) for k, corner in enumerate([[0, 0], [0, 5], [5, 0], [5, 5]])]
    settings = [(s, o) for s in (4, 6, 8, 10, 12, 15, 20) for o in (0, 2, 4, 6, 8, 10)]  # Fig. 5.5
    columns = np.repeat(settings, args.ch5_per_setting, axis=0)
    families = np.repeat(gridworld.STRUCTURED_FAMILIES, len(STRUCTURED_SIZES) * args.structured_per_size)
    structured_sizes = np.tile(np.repeat(list(STRUCTURED_SIZES), args.structured_per_size), 4)
    return [
        ("cpp_eval", by_size(args, 1, 0.10, args.per_size), len(sizes), dict(size=sizes)),  # §6.5.1.1
        ("p2p_eval", by_size(args, 2, 0.10, per, number_points_of_interest=1), args.p2p_total, dict(size=p2p_sizes)),
        ("marl_eval", by_size(args, 3, 0.15, args.per_size, number_agents=args.marl_agents), len(sizes),
         dict(size=sizes)),  # §7.5.1: up to 15% obstacles, agents as prefixes
        ("ch5_6x6", corners, 200, dict(requested_obstacles=np.repeat([0, 1], 100))),
        ("ch5_eval", [(args.ch5_per_setting, args.seed * 1_000_003 + 5000 + i, dict(size=s, number_obstacles=o))
                      for i, (s, o) in enumerate(settings)], len(columns),
         dict(size=columns[:, 0], requested_obstacles=columns[:, 1])),
        ("structured_eval", structured_draws(args), len(families), dict(family=families, size=structured_sizes)),
    ]


def crops(args: Args) -> tuple[list[gridworld.Scenario], dict[str, np.ndarray]]:
    """--crops: from each map, --crops-per-map squares of a side drawn from CROP_SIDES (at most the map's) at random
    places, each with --marl-agents distinct random starts; the cells the first start cannot reach become
    obstacles (as Algorithm 10), and a crop where it reaches under half the free cells, or too few for the
    starts, is drawn again. Returns the scenarios and their columns."""
    rng = np.random.default_rng(args.seed * 1_000_003 + 7000)
    out, columns = [], {"family": [], "size": [], "row": [], "col": []}
    for path in args.crops:
        source = gridworld.load_map(path).obstacles
        H, W = source.shape
        for _ in range(args.crops_per_map):
            for _ in range(1000):
                side = int(rng.choice(CROP_SIDES))
                h, w = min(side, H), min(side, W)
                y, x = int(rng.integers(0, H - h + 1)), int(rng.integers(0, W - w + 1))
                free = np.argwhere(~source[y:y + h, x:x + w])
                if len(free) == 0:
                    continue
                start = free[rng.integers(len(free))]
                seed = np.zeros((1, h, w), bool)
                seed[0, start[0], start[1]] = True
                reach = gridworld.flood(~source[None, y:y + h, x:x + w], seed)[0]
                if reach.sum() >= max(len(free) / 2, 2 * args.marl_agents):
                    break
            else:
                raise ValueError(f"--crops {path}: no crop of it in 1,000 draws has room for {args.marl_agents} starts")
            others = np.argwhere(reach)
            others = others[(others != start).any(1)]
            starts = np.concatenate([start[None], others[rng.choice(len(others), args.marl_agents - 1, replace=False)]])
            out.append(gridworld.Scenario(~reach, starts))
            for key, value in zip(columns, (os.path.splitext(os.path.basename(path))[0], max(h, w), y, x)):
                columns[key].append(value)
    return out, {k: np.array(v) for k, v in columns.items()}


def pictures(args: Args, path: str = PICTURE) -> str:
    """A PNG of one map per family: the first 20x20 map of cpp_eval (random) and of each structured_eval family,
    obstacles black, the single-agent start red and the other starts blue."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cpp = subset_draw(args, 1, 20, 0.10, args.per_size)  # cpp_eval's size-20 subset
    maps = [("random", draw(cpp[0], cpp[1], **cpp[2])[0])]
    maps += [(settings["map_family"], draw(n, seed, **settings)[0])
             for n, seed, settings in structured_draws(args) if settings["size"] == 20]
    fig, axes = plt.subplots(1, len(maps), figsize=(3.2 * len(maps), 3.6))
    for ax, (family, s) in zip(axes, maps):
        ax.imshow(s.obstacles, cmap="gray_r", vmin=0, vmax=1, interpolation="nearest")
        ax.plot(s.starts[1:, 1], s.starts[1:, 0], "o", color="tab:blue", markersize=4)
        ax.plot(s.starts[0, 1], s.starts[0, 0], "o", color="tab:red", markersize=6, markeredgecolor="k")
        ax.set(xticks=[], yticks=[], title=f"{family}: {int(s.obstacles.sum())} obstacle cells")
    fig.tight_layout()
    with gridworld.staged_output(path, "picture", args.overwrite, "--pictures") as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)
    return path


def main(args: Args) -> None:
    for flag, value in (("--per-size", args.per_size), ("--p2p-total", args.p2p_total),
                        ("--marl-agents", args.marl_agents), ("--ch5-per-setting", args.ch5_per_setting),
                        ("--structured-per-size", args.structured_per_size), ("--crops-per-map", args.crops_per_map)):
        if value < 1:
            raise ValueError(f"{flag} must be >= 1, got {value}")
    if args.pictures and args.crops:
        raise ValueError("--pictures and --crops write different files: give one of them")
    if args.pictures:
        print(pictures(args))
        return
    if os.path.exists(args.out) and not os.path.isdir(args.out):
        raise ValueError(f"--out {args.out}: not a folder")
    datasets = [] if args.crops else plan(args)
    names = ["crops"] if args.crops else [name for name, _, _, _ in datasets]
    for name in names:  # gridworld's write rule, before any map is drawn
        gridworld.check_output(os.path.join(args.out, f"{name}.npz"), "dataset", args.overwrite, "--out")
    if args.crops:
        scenarios, columns = crops(args)
        path = os.path.join(args.out, "crops.npz")
        gridworld.save_dataset(path, scenarios, **columns)
        print(f"{path}: {len(scenarios)} crops of {len(args.crops)} map(s)")
        return
    for name, draws, _, _ in datasets:  # every setting is checked before any map is drawn or file written
        for _, _, settings in draws:
            try:
                gridworld.EnvConfig.from_dict({"battery_factor": 5.0, **settings}).validate()
            except ValueError as e:
                raise ValueError(f"{name}: {e}") from None
    drawn = {}
    with tqdm(total=sum(len(d) for _, d, _, _ in datasets), desc="subsets", unit="subset",
              disable=args.quiet or not sys.stdout.isatty()) as bar:
        for name, draws, keep, _ in datasets:
            drawn[name] = []
            for n, seed, settings in draws:
                drawn[name] += draw(n, seed, **settings)
                bar.update()
            drawn[name] = drawn[name][:keep]
            if name in NO_COVERAGE:
                drawn[name] = [gridworld.Scenario(s.obstacles, s.starts) for s in drawn[name]]
    for name, _, _, columns in datasets:
        path = os.path.join(args.out, f"{name}.npz")
        gridworld.save_dataset(path, drawn[name], **columns)
        print(f"{path}: {len(drawn[name])} scenarios, {os.path.getsize(path) / 1e3:.0f} kB")


if __name__ == "__main__":
    try:
        main(gridworld.cli(Args))
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
