"""Overlap and planning time of the rollout planner against its base, greedy-dead-ends, on one core.

    python benchmarks/rollout_planner.py                                # cpp_eval_subset(20) + the 9 MovingAI maps
    python benchmarks/rollout_planner.py --per-size 5 --sizes 10 20 30 --no-external   # a few minutes
    python benchmarks/rollout_planner.py --per-size 0 --external-maps maze-32-32-2.map

cpp_eval: the first --per-size maps of each size (classical_cpp.cpp_eval_subset), planned one size
at a time (a size's maps are batched in one core, as classical_cpp.plan batches them), mean overlap
by size band (classical_cpp.REPORT_BANDS) and seconds per map by size; the LKH column is the
near-optimal reference from results/classical_cpp.json (its own per-size count). MovingAI: every
map of maps/external with each start of references.json, batched by map, against its `lkh_overlap`.
Every path is replayed by classical_cpp.replay (legal and complete). numpy runs on one thread,
pinned to one CPU (--cpu). Prints a Markdown table per part and one JSON line with every number.
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

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import classical_cpp as cc  # noqa: E402
import gridworld  # noqa: E402


@dataclass
class Args:
    per_size: int = 20
    """cpp_eval maps per size (0: none)"""
    sizes: tuple[int, ...] = ()
    """only these cpp_eval sizes (default: all, 5-30)"""
    external: bool = True
    """also the MovingAI maps of maps/external"""
    external_maps: tuple[str, ...] = ()
    """only these MovingAI maps (file names in maps/external)"""
    base: str = "greedy-dead-ends"
    """the rollout's base (classical_cpp.ROLLOUT_BASES)"""
    cpu: int = -1
    """the CPU to pin to (-1: the first one this process may use)"""


def timed(name: str, scenarios: list, base: str, stats: dict | None = None) -> tuple[list[dict], float]:
    """Replayed metrics of planner `name` on the scenarios, batched, and the planning seconds per map."""
    t0 = time.perf_counter()
    if name == "rollout":
        paths = cc.rollout_many(scenarios, cc.ROLLOUT_BASES[base], stats=stats)
    else:
        paths = cc.plan(name, scenarios)
    seconds = time.perf_counter() - t0
    return [cc.replay(s, p) for s, p in zip(scenarios, paths)], seconds / max(len(scenarios), 1)


def lkh_reference() -> tuple[dict, int | None]:
    """LKH's mean overlap by band from the committed planner results, and their maps per size."""
    path = os.path.join(cc.ROOT, "results", "classical_cpp.json")
    try:
        with open(path) as f:
            saved = json.load(f)
        return saved["cpp_eval"]["lkh"], saved.get("per_size")
    except (OSError, KeyError, ValueError):
        return {}, None


def cpp_eval_part(args: Args, out: dict) -> None:
    scenarios, sizes = cc.cpp_eval_subset(args.per_size)
    wanted = sorted(set(args.sizes or range(5, 31)))
    rows: dict[str, list[dict]] = {"greedy-dead-ends": [], "rollout": []}
    seconds: dict[str, dict[int, float]] = {"greedy-dead-ends": {}, "rollout": {}}
    stats: dict[int, dict] = {}
    kept = []
    for z in wanted:
        group = [cc.with_starts(s) for s, size in zip(scenarios, sizes) if size == z]
        if not group:
            continue
        kept += [z] * len(group)
        stats[z] = {}
        for name in rows:
            metrics, per_map = timed(name, group, args.base, stats[z] if name == "rollout" else None)
            rows[name] += metrics
            seconds[name][z] = per_map
        r, g = rows["rollout"][-len(group):], rows["greedy-dead-ends"][-len(group):]
        worse = sum(a["steps"] > b["steps"] for a, b in zip(r, g))
        print(f"  {z}x{z}: {len(group)} maps, greedy-dead-ends {np.mean([m['overlap'] for m in g]):.4f}, rollout "
              f"{np.mean([m['overlap'] for m in r]):.4f} in {seconds['rollout'][z]:.2f} s/map"
              f"{f', {worse} WORSE than the base' if worse else ''}; {stats[z]}", flush=True)
    kept = np.array(kept)
    lkh, lkh_per_size = lkh_reference()
    bands = [(a, b) for a, b in cc.REPORT_BANDS if ((kept >= a) & (kept <= b)).any()]
    table = {name: {f"{a}-{b}": float(np.mean([m["overlap"] for m, z in zip(r, kept) if a <= z <= b])) for a, b in bands}
             | {"all": float(np.mean([m["overlap"] for m in r])),
                "completed": float(np.mean([m["completed"] for m in r]))} for name, r in rows.items()}
    print(f"\ncpp_eval, {args.per_size} maps per size, mean overlap (LKH: results/classical_cpp.json, "
          f"{lkh_per_size} maps per size, all sizes):\n")
    print("| planner | " + " | ".join(f"{a}–{b}" for a, b in bands) + " | all | completed |")
    print("|---" * (len(bands) + 3) + "|")
    for name, t in table.items():
        print(f"| {name} | " + " | ".join(f"{t[f'{a}-{b}']:.4f}" for a, b in bands) + f" | {t['all']:.4f} | "
              f"{100 * t['completed']:.0f}% |")
    if lkh:
        print("| lkh (reference) | " + " | ".join(f"{lkh.get(f'{a}-{b}', float('nan')):.4f}" for a, b in bands)
              + f" | {lkh.get('all', float('nan')):.4f} | |")
    print("\n| size | " + " | ".join(f"{z}" for z in seconds["rollout"]) + " |")
    print("|---" * (len(seconds["rollout"]) + 1) + "|")
    for name, per in seconds.items():
        print(f"| {name} s/map | " + " | ".join(f"{v:.3f}" for v in per.values()) + " |")
    out["cpp_eval"] = {"per_size": args.per_size, "overlap": table, "seconds_per_map": seconds,
                       "lkh_reference": lkh, "lkh_per_size": lkh_per_size, "rollout_stats": stats}


def external_part(args: Args, out: dict) -> None:
    with open(os.path.join(cc.ROOT, "maps", "external", "references.json")) as f:
        refs = json.load(f)
    episodes = cc.external_episodes()
    names = [m for m in refs if not args.external_maps or m in args.external_maps]
    if not names:
        raise SystemExit(f"error: no such map in maps/external: {', '.join(args.external_maps)}")
    result = {}
    print("\nMovingAI maps (maps/external, the starts of references.json), mean overlap:\n")
    print("| map | starts | greedy-dead-ends | rollout | lkh (reference) | rollout s/map |")
    print("|---|---|---|---|---|---|")
    for m in names:
        group = [s for name, s in episodes if name == m]
        g, _ = timed("greedy-dead-ends", group, args.base)
        r, per_map = timed("rollout", group, args.base)
        lkh = float(np.mean([x["lkh_overlap"] for x in refs[m]]))
        result[m] = {"greedy-dead-ends": float(np.mean([x["overlap"] for x in g])),
                     "rollout": float(np.mean([x["overlap"] for x in r])), "lkh": lkh, "rollout_s_per_map": per_map,
                     "completed": float(np.mean([x["completed"] for x in r]))}
        e = result[m]
        print(f"| {m} | {len(group)} | {e['greedy-dead-ends']:.4f} | {e['rollout']:.4f} | {lkh:.4f} | {per_map:.2f} |",
              flush=True)
    out["external"] = result


def main(args: Args) -> dict:
    if args.base not in cc.ROLLOUT_BASES:
        raise SystemExit(f"error: unknown --base {args.base!r}; choose from {sorted(cc.ROLLOUT_BASES)}")
    if args.per_size < 0:
        raise SystemExit(f"error: --per-size must be >= 0, got {args.per_size}")
    pin(args.cpu)
    out: dict = {"base": args.base}
    t0 = time.perf_counter()
    if args.per_size:
        print(f"cpp_eval, rollout over {args.base}:")
        cpp_eval_part(args, out)
    if args.external:
        external_part(args, out)
    out["wall_seconds"] = round(time.perf_counter() - t0, 1)
    print("\n" + json.dumps(out))
    return out


if __name__ == "__main__":
    with gridworld.cli_errors():  # a bad flag or Ctrl-C: one line, no traceback
        main(gridworld.cli(Args))
