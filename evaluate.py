"""Evaluate an agent or a planner on maps; one row per episode, and a summary.

    python evaluate.py --policy greedy --dataset maps/cpp_eval.npz --out runs/eval/greedy
    python evaluate.py --policy lkh --maps maps/external/room-32-32-4.map --starts starts.json --out DIR
    python evaluate.py --policy partition --dataset maps/marl_eval.npz --agents 5 --out DIR

Writes DIR/episodes.csv (map, size, n_free, agents, start, steps, revisits, overlap, time_save,
completed, truncated, heuristic_steps) and DIR/summary.json (mean, median, std, min, max of
overlap, time-save factor and steps, completion rate; overall and by map size). Every metric is
counted by gridworld's own environment. Policies: the planners of classical_cpp.py (greedy,
greedy-dead-ends, boustrophedon, spiral-stc, wavefront, lkh, partition) and the chapter-6 agent `rainbow`
(rainbow_cpp.py; --checkpoint, default models/rainbow_cpp.pt, noise off, heuristic fallback
unless --no-heuristic), the chapter-7 agents `marl` (rainbow_marl.py; default
models/rainbow_marl.pt, decentralised: every agent acts on its own observation; --action-loss,
--faulty-agent-at), the chapter-5 agent `tabular` (tabular_q.py; --checkpoint, default
models/tabular_q.npz, greedy, the heuristic at dead ends unless --no-heuristic, --sensor builds
the heuristic's map).

    python evaluate.py --policy marl --dataset maps/marl_eval.npz --agents 5 --faulty-agent-at 0.5 --out DIR
"""
from __future__ import annotations

import csv
import json
import os
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np
import tyro
from tqdm import tqdm

import classical_cpp
import gridworld
from gridworld import Scenario

LEARNED = ("rainbow", "marl", "tabular")
DEFAULT_CHECKPOINT = {"rainbow": "models/rainbow_cpp.pt", "marl": "models/rainbow_marl.pt",
                      "tabular": "models/tabular_q.npz"}
COLUMNS = ["map", "size", "n_free", "agents", "start", "steps", "revisits", "overlap", "time_save",
           "completed", "truncated", "heuristic_steps"]


@dataclass
class Args:
    policy: str = "greedy"
    """a classical_cpp planner (greedy, greedy-dead-ends, boustrophedon, spiral-stc, wavefront, lkh,
    partition) or a learned agent (rainbow, marl, tabular)"""
    checkpoint: str | None = None
    """weights / table of a learned agent"""
    maps: tuple[str, ...] = ()
    """MovingAI .map or ASCII map files"""
    dataset: str | None = None
    """a gridworld .npz dataset (maps/cpp_eval.npz, maps/marl_eval.npz, ...)"""
    agents: int = 1
    """agents per episode: the first N stored starts, else N starts drawn with --seed"""
    starts: str | None = None
    """JSON file {map file name: [[row, col], ...]}: agent i starts at entry i; with one agent
    and several entries, one episode per entry"""
    seed: int = 0
    """seed for starts drawn at random"""
    sensor: str = "full"
    """full, camera or lidar (learned policies; the planners plan with full information)"""
    sensor_range: int = 3
    """sensor range K in cells"""
    sensor_failure: float = 0.0
    """fraction of steps whose sensor reading is dropped (§6.5.3.3)"""
    faulty_agent_at: float | None = None
    """marl: the last agent freezes once this fraction of the points of interest is covered
    (§7.5.3.3: 0.5, halfway)"""
    action_loss: float = 0.0
    """marl: chance an agent misses its action at a step and stays where it is"""
    heuristic: bool = True
    """learned policies: hand over to the navigation heuristic when stuck (§6.5.2.1)"""
    heuristic_dead_ends: bool = True
    """rainbow, marl: the fallback heuristic takes the nearest cell with the fewest uncovered
    neighbours first (as the shipped models were taught); --no-heuristic-dead-ends: the
    dissertation's nearest-cell heuristic"""
    limit: int = 0
    """evaluate only the first LIMIT scenarios (0: all)"""
    min_size: int = 0
    """evaluate only maps whose longer edge is at least this"""
    max_size: int = 0
    """evaluate only maps whose longer edge is at most this (0: no bound)"""
    every: int = 1
    """evaluate every k-th of the maps left"""
    workers: int = 1
    """processes to spread the episodes over"""
    out: str = "runs/eval"
    """output folder for episodes.csv and summary.json"""


def scenarios_from(args: Args) -> list[tuple[str, Scenario]]:
    """(map name, scenario with starts covered) for every episode asked for."""
    if args.agents < 1:
        raise ValueError(f"--agents must be >= 1, got {args.agents}")
    named: list[tuple[str, Scenario]] = []
    if args.dataset:
        base = os.path.basename(args.dataset)
        named += [(f"{base}[{i}]", s) for i, s in enumerate(gridworld.load_dataset(args.dataset))]
    for path in args.maps:
        named.append((os.path.basename(path), gridworld.load_map(path)))
    if not named:
        raise ValueError("give --maps FILE... or --dataset FILE")
    if args.every < 1:
        raise ValueError(f"--every must be >= 1, got {args.every}")
    named = [(n, s) for n, s in named
             if args.min_size <= max(s.obstacles.shape) <= (args.max_size or max(s.obstacles.shape))][::args.every]
    if not named:
        raise ValueError(f"no map has an edge in [{args.min_size}, {args.max_size or 'any'}]")
    if args.limit:
        named = named[:args.limit]
    given = {}
    if args.starts:
        try:
            with open(args.starts) as f:
                given = json.load(f)
        except (OSError, json.JSONDecodeError) as e:
            raise ValueError(f"{args.starts}: cannot read starts ({e})") from None
    rng = np.random.default_rng(args.seed)
    episodes = []
    for name, s in named:
        if name in given:
            cells = np.asarray(given[name], np.int64).reshape(-1, 2)
            groups = ([cells[i:i + 1] for i in range(len(cells))] if args.agents == 1
                      else [cells[:args.agents]])
            if len(groups[0]) < args.agents:
                raise ValueError(f"{args.starts}: {name} has {len(cells)} starts for {args.agents} agents")
        else:
            groups = [classical_cpp.starts_for(s, args.agents, rng, name)]
        for starts in groups:
            scenario = classical_cpp.with_starts(Scenario(s.obstacles, starts, s.covered))
            gridworld.check_scenario(scenario, name)
            episodes.append((name, scenario))
    return episodes


def run_planner(policy: str, episodes: list[tuple[str, Scenario]]) -> list[dict]:
    """Plan and replay every episode; one row per episode."""
    paths = classical_cpp.plan(policy, [s for _, s in episodes])
    return [_row(name, s, classical_cpp.replay(s, p)) for (name, s), p in zip(episodes, paths)]


def run_rainbow(args: Args, episodes: list[tuple[str, Scenario]]) -> list[dict]:
    """The chapter-6 agent (rainbow_cpp.py): noise off, heuristic fallback unless disabled."""
    import rainbow_cpp
    if args.agents != 1:
        raise ValueError("rainbow is single-agent; use --agents 1 (marl for several)")
    if args.faulty_agent_at is not None or args.action_loss:
        raise ValueError("--faulty-agent-at and --action-loss need several agents (the marl policy)")
    q = rainbow_cpp.load_policy(args.checkpoint or DEFAULT_CHECKPOINT["rainbow"])
    frames = q.conv[0].in_channels // 4
    return _rollout_rows(episodes, lambda scenarios, i: rainbow_cpp.evaluate_policy(
        q, scenarios, frames, args.sensor, args.sensor_range, args.sensor_failure, args.heuristic,
        dead_ends_first=args.heuristic_dead_ends))


def _rollout_rows(episodes: list[tuple[str, Scenario]], rollout) -> list[dict]:
    """A learned agent's batched `rollout(scenarios, first index)` on 64 worlds at a time; one
    row per episode."""
    rows = []
    for i in range(0, len(episodes), 64):
        part = episodes[i:i + 64]
        m = rollout([s for _, s in part], i)
        rows += [_row(name, s, {k: v[j].item() for k, v in m.items()}) for j, (name, s) in enumerate(part)]
    return rows


def run_marl(args: Args, episodes: list[tuple[str, Scenario]]) -> list[dict]:
    """The chapter-7 agents (rainbow_marl.py): noise off, decentralised, heuristic fallback
    unless disabled; heuristic_steps counts agent-steps."""
    import rainbow_marl
    if args.faulty_agent_at is not None and (args.agents < 2 or not 0 <= args.faulty_agent_at <= 1):
        raise ValueError("--faulty-agent-at needs --agents >= 2 and a fraction in [0, 1]")
    if not 0 <= args.action_loss < 1:
        raise ValueError(f"--action-loss must be in [0, 1), got {args.action_loss}")
    q = rainbow_marl.load_policy(args.checkpoint or DEFAULT_CHECKPOINT["marl"])
    frames = q.conv[0].in_channels // 4
    return _rollout_rows(episodes, lambda scenarios, i: rainbow_marl.evaluate_policy(
        q, scenarios, frames, args.sensor, args.sensor_range, args.sensor_failure, args.heuristic,
        action_loss=args.action_loss, faulty_at=args.faulty_agent_at, seed=args.seed + i,
        dead_ends_first=args.heuristic_dead_ends))


def run_tabular(args: Args, episodes: list[tuple[str, Scenario]]) -> list[dict]:
    """The chapter-5 agent (tabular_q.py): greedy, never-seen states and dead ends take the
    heuristic (off with --no-heuristic); --sensor builds the map the heuristic plans on."""
    import tabular_q
    if args.agents != 1:
        raise ValueError("tabular is single-agent; use --agents 1")
    if args.sensor_failure or args.faulty_agent_at is not None or args.action_loss:
        raise ValueError("tabular: --sensor-failure, --faulty-agent-at and --action-loss are not modelled in chapter 5")
    path = args.checkpoint or DEFAULT_CHECKPOINT["tabular"]
    table = tabular_q.QTable.load(path)
    if table.sensor_range != args.sensor_range:
        raise ValueError(f"{path}: trained with r = {table.sensor_range}; --sensor-range is {args.sensor_range}")
    m = tabular_q.evaluate_table(table, [s for _, s in episodes], args.heuristic, args.sensor, args.seed)
    return [_row(name, s, {k: v[j].item() for k, v in m.items()}) for j, (name, s) in enumerate(episodes)]


def _row(name: str, s: Scenario, m: dict) -> dict:
    return dict(map=name, size=f"{s.obstacles.shape[0]}x{s.obstacles.shape[1]}",
                n_free=int((~s.obstacles).sum()), agents=len(s.starts), start=json.dumps(s.starts.tolist()),
                steps=m["steps"], revisits=m["revisits"], overlap=round(m["overlap"], 6),
                time_save=round(m["time_save"], 6), completed=m["completed"],
                truncated=m.get("truncated", False), heuristic_steps=m.get("heuristic_steps", 0))


def _run_chunk(job):
    policy, chunk = job
    return run_planner(policy, chunk)


def summarize(rows: list[dict]) -> dict:
    def stats(group):
        out = {"episodes": len(group),
               "completion_rate": float(np.mean([r["completed"] for r in group]))}
        for key in ("overlap", "time_save", "steps"):
            v = np.array([r[key] for r in group], float)
            out[key] = dict(mean=float(v.mean()), median=float(np.median(v)), std=float(v.std()),
                            min=float(v.min()), max=float(v.max()))
        return out

    sizes = sorted({r["size"] for r in rows}, key=lambda z: tuple(map(int, z.split("x"))))
    return {"all": stats(rows), "by_size": {z: stats([r for r in rows if r["size"] == z]) for z in sizes}}


def main(args: Args) -> dict:
    if args.policy not in classical_cpp.PLANNERS and args.policy not in LEARNED:
        raise ValueError(f"unknown policy {args.policy!r}; choose from "
                         f"{sorted(classical_cpp.PLANNERS) + list(LEARNED)}")
    if args.sensor not in gridworld.SENSORS:
        raise ValueError(f"--sensor must be one of {gridworld.SENSORS}, got {args.sensor!r}")
    if args.policy == "rainbow":
        return _write(args, run_rainbow(args, scenarios_from(args)))
    if args.policy == "marl":
        return _write(args, run_marl(args, scenarios_from(args)))
    if args.policy == "tabular":
        return _write(args, run_tabular(args, scenarios_from(args)))
    if args.sensor != "full" or args.sensor_failure or args.faulty_agent_at is not None or args.action_loss:
        raise ValueError("the classical planners plan with full information and no faults; --sensor, "
                         "--sensor-failure, --faulty-agent-at and --action-loss apply to learned policies")
    episodes = scenarios_from(args)
    rows = []
    if args.workers > 1:  # contiguous chunks, so the rows keep the episodes' order
        k = -(-len(episodes) // args.workers)
        chunks = [episodes[i:i + k] for i in range(0, len(episodes), k)]
        with ProcessPoolExecutor(args.workers) as pool:
            for part in tqdm(pool.map(_run_chunk, [(args.policy, c) for c in chunks]),
                             total=len(chunks), desc=args.policy):
                rows += part
    else:
        step = 64  # planned in slices so the progress bar moves
        for i in tqdm(range(0, len(episodes), step), desc=args.policy):
            rows += run_planner(args.policy, episodes[i:i + step])
    return _write(args, rows)


def _write(args: Args, rows: list[dict]) -> dict:
    os.makedirs(args.out, exist_ok=True)
    with open(os.path.join(args.out, "episodes.csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    summary = {"policy": args.policy, "dataset": args.dataset, "maps": list(args.maps),
               "agents": args.agents, "seed": args.seed, **summarize(rows)}
    with open(os.path.join(args.out, "summary.json"), "w") as f:
        json.dump(summary, f, indent=1)
    s = summary["all"]
    print(f"{args.policy}: {s['episodes']} episodes, overlap {s['overlap']['mean']:.4f}, "
          f"time-save {s['time_save']['mean']:.4f}, completed {100 * s['completion_rate']:.1f}%"
          f" -> {args.out}")
    return summary


# ----------------------------------------------------------------------------- the report
@dataclass
class ReportArgs:
    out: str = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
    """folder for RESULTS.md and the figures"""
    reuse: bool = False
    """re-draw from results/classical_cpp.json instead of re-running the planners (~25 min)"""
    per_size: int = 20
    """maps per cpp_eval size for the planner comparison (LKH takes seconds per map) and the
    learned agents"""
    p2p_maps: int = 1000
    """p2p_eval scenarios for the point-to-point evaluation (of 10,000)"""


def rainbow_results(out: str, per_size: int, p2p_maps: int, model: str) -> dict:
    """A rainbow_cpp model (the committed one in the report) on cpp_eval (full information with and without the
    heuristic fallback, camera r = 3), p2p_eval and the MovingAI maps; the greedy planner per
    size beside it. Written to results/rainbow_cpp.json."""
    root = os.path.dirname(os.path.abspath(__file__))
    scenarios, sizes = classical_cpp.cpp_eval_subset(per_size)
    episodes = [(f"cpp_eval.npz[{z}x{z}]", classical_cpp.with_starts(s)) for s, z in zip(scenarios, sizes)]

    def by_size(rows):
        out = {}
        for r in rows:
            out.setdefault(r["size"].split("x")[0], []).append(r)
        return {z: dict(overlap=round(float(np.mean([r["overlap"] for r in g])), 4),
                        overlap_completed=round(float(np.mean([r["overlap"] for r in g if r["completed"]]
                                                              or [np.nan])), 4),
                        completion=round(float(np.mean([r["completed"] for r in g])), 4),
                        heuristic_share=round(float(np.mean([r["heuristic_steps"] / max(r["steps"], 1)
                                                             for r in g])), 4))
                for z, g in out.items()}

    with open(os.path.splitext(model)[0] + ".json") as f:
        result = {"per_size": per_size, "model": json.load(f)}
    for key, kw in (("full", {}), ("full_no_heuristic", {"heuristic": False}),
                    ("camera_r3", {"sensor": "camera", "sensor_range": 3})):
        rows = run_rainbow(Args(policy="rainbow", checkpoint=model, **kw), episodes)
        result[key] = by_size(rows)
        print(key, json.dumps(result[key]), flush=True)
    result["greedy"] = by_size(run_planner("greedy", episodes))
    result["greedy_dead_ends"] = by_size(run_planner("greedy-dead-ends", episodes))
    p2p = scenarios_from(Args(dataset=os.path.join(root, "maps", "p2p_eval.npz"), limit=p2p_maps))
    shortest = [r["steps"] for r in run_planner("greedy", p2p)]  # one target: greedy walks a shortest path
    rows = run_rainbow(Args(policy="rainbow", checkpoint=model), p2p)
    result["p2p"] = {"maps": len(p2p), "optimal": round(float(np.mean([r["steps"] == b for r, b in
                                                                        zip(rows, shortest)])), 4),
                     "completion": round(float(np.mean([r["completed"] for r in rows])), 4),
                     "mean_extra_steps": round(float(np.mean([r["steps"] - b for r, b in zip(rows, shortest)])), 3)}
    result["external"] = {}
    for row in run_rainbow(Args(policy="rainbow", checkpoint=model), classical_cpp.external_episodes()):
        result["external"].setdefault(row["map"], []).append(row["overlap"])
    with open(os.path.join(out, "rainbow_cpp.json"), "w") as f:
        json.dump(result, f, indent=1)
    return result


def marl_results(out: str, model: str, every: int = 10, agents=range(1, 16)) -> dict:
    """A rainbow_marl model on marl_eval (sizes 10-30, every `every`-th layout) with N = 1..15 agents
    (`agents`) beside the greedy planners with claims, and the faulty-agent
    experiment of §7.5.3.3 (N = 2, 5, 10: the last agent freezes halfway). Written to
    results/rainbow_marl.json."""
    with open(os.path.splitext(model)[0] + ".json") as f:
        result = {"every": every, "model": json.load(f), "agents": {}, "faulty": {}}

    def mean(rows, key):
        return round(float(np.mean([r[key] for r in rows])), 4)

    for n in agents:
        scenarios, sizes = classical_cpp.marl_eval_subset(n, every)
        episodes = [(f"marl_eval.npz[{z}x{z}]", s) for s, z in zip(scenarios, sizes)]
        rows = run_marl(Args(policy="marl", checkpoint=model, agents=n), episodes)
        greedy = run_planner("greedy", episodes)
        dead_ends = run_planner("greedy-dead-ends", episodes)
        result["agents"][str(n)] = {
            "maps": len(rows), "time_save": mean(rows, "time_save"), "completion": mean(rows, "completed"),
            "heuristic_share": round(float(np.mean([r["heuristic_steps"] / (n * r["steps"]) for r in rows])), 4),
            "greedy": mean(greedy, "time_save"), "greedy_dead_ends": mean(dead_ends, "time_save"),
            "by_size": {str(z): mean([r for r, k in zip(rows, sizes) if k == z], "time_save") for z in np.unique(sizes)}}
        if n in (2, 5, 10):
            faulty = run_marl(Args(policy="marl", checkpoint=model, agents=n, faulty_agent_at=0.5), episodes)
            result["faulty"][str(n)] = {"time_save": mean(faulty, "time_save"), "completion": mean(faulty, "completed")}
        print(n, json.dumps(result["agents"][str(n)]), json.dumps(result["faulty"].get(str(n))), flush=True)
    with open(os.path.join(out, "rainbow_marl.json"), "w") as f:
        json.dump(result, f, indent=1)
    return result


def marl_sections(mr: dict, marl: dict, out: str, table) -> list[str]:
    """RESULTS.md lines for the chapter-7 agent, and its time-save figure."""
    import matplotlib.pyplot as plt
    agents = sorted(mr["agents"], key=int)
    n_axis = [int(n) for n in agents]
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4))
    left.plot(n_axis, [mr["agents"][n]["time_save"] for n in agents], marker="o", label="rainbow_marl + heuristic")
    left.plot(n_axis, [mr["agents"][n]["greedy"] for n in agents], marker=".", label="greedy planner (claims)")
    left.plot(n_axis, [mr["agents"][n]["greedy_dead_ends"] for n in agents], marker=".",
              label="greedy-dead-ends planner (claims)")
    base = sorted(marl, key=int)
    left.plot([int(n) for n in base], [marl[n]["partition"] for n in base], "s", label="partition planner")
    left.plot(n_axis, [1 / n for n in n_axis], "k--", label="1/N")
    left.set(xlabel="agents N", ylabel="mean time-save factor $t_{sf}$", yscale="log",
             title="marl_eval, sizes 10-30")
    for n in ("2", "5", "10", "15"):
        by = mr["agents"][n]["by_size"]
        right.plot([int(z) for z in by], list(by.values()), marker=".", label=f"N = {n}")
    right.set(xlabel="map size (edge, cells)", ylabel="mean $t_{sf}$", yscale="log", title="rainbow_marl by size")
    for ax in (left, right):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(out, "rainbow_marl_time_save.png"), dpi=120)
    plt.close(fig)
    m = mr["model"]
    targets = {"2": 0.53, "5": 0.30, "10": 0.15}
    met = [f"N = {n}: {mr['agents'][n]['time_save']:.3f} against ≤ {t} "
           f"({'met' if mr['agents'][n]['time_save'] <= t else 'not met'})" for n, t in targets.items()]
    several = [n for n in agents if int(n) > 1]
    below = [n for n in several if mr["agents"][n]["time_save"] < mr["agents"][n]["greedy"]]
    rewards = []
    for name in ("greedy", "pretrained", "competitive", "cooperative", "size_invariant"):
        path = os.path.join(out, "marl_rewards", name, "summary.json")
        if os.path.exists(path):
            with open(path) as f:
                s = json.load(f)["all"]
            rewards.append([name, str(s["episodes"]), f"{s['time_save']['mean']:.3f}",
                            f"{100 * s['completion_rate']:.0f}%"])
    if rewards:
        rewards = ["", "Reward structures (§7.5.2, Figs. 7.7-7.8) at N = 2, K = 0.25: 15,000 steps each from "
                   "the greedy-teacher `models/rainbow_cpp.pt` of git 0c4b203 with the dissertation's recipe (no margin loss), stage file "
                   "`models/rainbow_marl_reward_stages.yaml`; mean $t_{sf}$ on `marl_eval` sizes 10-24, every 10th map "
                   "(README for the commands; `pretrained` is the single-agent model before any multi-agent training, "
                   "`greedy` the planner with claims on the same maps):",
                   "", table(["reward", "maps", "mean t_sf", "completed"], rewards)]
    return [
        f"Model `models/rainbow_marl.pt` (hidden {m['args']['hidden']}, from `{m['args']['init_from']}`): "
        f"{m['global_step']:,} environment steps, last stage {m['stage']}, {m['wall_seconds'] / 60:.0f} min with "
        f"{m['torch_threads']} torch thread(s) on a 2-core CPU machine; flags in `models/rainbow_marl.json`. Decentralised execution, noise off, heuristic "
        "fallback on." + (f" Training: {m['init_from_note']}." if "init_from_note" in m else ""), "",
        f"Targets (issue #7, mean $t_{{sf}}$ on sizes 10-30): {'; '.join(met)}. Completion "
        f"{100 * min(mr['agents'][n]['completion'] for n in agents):.0f}% at worst. Below the greedy planner at "
        f"{len(below)} of the {len(several)} agent counts 2-{several[-1]}.", "",
        f"`marl_eval` sizes 10-30, every {mr['every']}th layout, the first N stored starts (the N + 1-agent episode "
        "adds one agent to the N-agent one); heuristic share = fraction of agent-steps the fallback took:", "",
        table(["N", "maps", "rainbow_marl", "greedy (claims)", "greedy-dead-ends (claims)", "1/N", "completed",
               "heuristic share"],
              [[n, str(mr["agents"][n]["maps"]), f"{mr['agents'][n]['time_save']:.3f}",
                f"{mr['agents'][n]['greedy']:.3f}", f"{mr['agents'][n]['greedy_dead_ends']:.3f}", f"{1 / int(n):.3f}",
                f"{100 * mr['agents'][n]['completion']:.0f}%", f"{mr['agents'][n]['heuristic_share']:.2f}"]
               for n in agents]), "",
        "![rainbow_marl time-save factor](rainbow_marl_time_save.png)", "",
        "Faulty agent (§7.5.3.3, Fig. 7.12): the last agent freezes once half the points of interest are covered; "
        "mean $t_{sf}$ beside N and N - 1 working agents on the same maps:", "",
        table(["N", "N working", "N, one faulty", "completed (faulty)", "N - 1 working"],
              [[n, f"{mr['agents'][n]['time_save']:.3f}", f"{f['time_save']:.3f}", f"{100 * f['completion']:.0f}%",
                f"{mr['agents'][str(int(n) - 1)]['time_save']:.3f}" if str(int(n) - 1) in mr["agents"] else "—"]
               for n, f in mr["faulty"].items()]),
        *rewards,
    ]


NOT_TRAINED = ("*Not trained yet:* `{script}` is an open issue; this section fills in when "
               "its model is committed.")


def rainbow_sections(rb: dict, cpp: dict, ext: dict, out: str, table) -> tuple[list, list, list]:
    """RESULTS.md lines for the chapter-6 agent, and its overlap-by-size figure."""
    import matplotlib.pyplot as plt
    sizes = sorted(rb["full"], key=int)
    fig, ax = plt.subplots(figsize=(9.5, 4))
    for key, stat, label in (("full", "overlap", "rainbow + heuristic fallback"),
                             ("full_no_heuristic", "overlap_completed", "rainbow alone (completed maps)"),
                             ("camera_r3", "overlap", "rainbow, camera r = 3"), ("greedy", "overlap", "greedy planner"),
                             ("greedy_dead_ends", "overlap", "greedy-dead-ends planner (the teacher)")):
        ax.plot([int(z) for z in sizes], [rb[key][z][stat] for z in sizes], marker=".", label=label)
    bands = [b for b in cpp["lkh"] if "-" in b]
    ax.plot([np.mean([int(x) for x in b.split("-")]) for b in bands], [cpp["lkh"][b] for b in bands], "k*",
            label="LKH (size-band means)")
    ax.axhline(0.05, color="grey", ls=":", label="target 0.05")
    ax.set(xlabel="map size (edge, cells)", ylabel="mean overlap $O_v$", yscale="log",
           title=f"rainbow_cpp on cpp_eval ({rb['per_size']} maps per size)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1))  # outside: the curves fill the plot
    fig.tight_layout()
    fig.savefig(os.path.join(out, "rainbow_overlap_by_size.png"), dpi=120)
    plt.close(fig)
    m = rb["model"]
    trained = (f"Model `models/rainbow_cpp.pt` (hidden {m['args']['hidden']}): {m['global_step']:,} environment "
               f"steps, last stage {m['stage']}, {m['wall_seconds'] / 3600:.1f} h on a {m['machine']}; "
               "flags in `models/rainbow_cpp.json`. Regenerate these numbers with `python evaluate.py report`."
               + (f" Training: {m['init_from_note']}." if "init_from_note" in m else ""))
    target = [z for z in sizes if 5 <= int(z) <= 20]
    below = sum(rb["full"][z]["overlap"] < rb["greedy"][z]["overlap"] for z in target)
    worst = max(target, key=lambda z: rb["full"][z]["overlap"])
    verdict = (f"Targets on sizes 5-20 (issue #5: 100% completion, mean overlap ≤ 0.05 and below the greedy "
               f"planner at every size): completion {100 * min(rb['full'][z]['completion'] for z in target):.0f}% "
               f"at worst; mean overlap ≤ 0.05 at {sum(rb['full'][z]['overlap'] <= 0.05 for z in target)} of "
               f"{len(target)} sizes (worst {rb['full'][worst]['overlap']:.3f} at {worst}); below greedy at {below} "
               f"of {len(target)}.")
    full = [trained, "", verdict, "", f"`cpp_eval`, the first {rb['per_size']} maps of each size, mean overlap and "
            "completion; heuristic share = fraction of steps the fallback took.", "",
            table(["size", "rainbow + heuristic", "completed", "heuristic share", "rainbow alone (completed maps)",
                   "completed", "greedy planner", "greedy-dead-ends planner"],
                  [[z, f"{rb['full'][z]['overlap']:.3f}", f"{100 * rb['full'][z]['completion']:.0f}%",
                    f"{rb['full'][z]['heuristic_share']:.2f}", f"{rb['full_no_heuristic'][z]['overlap_completed']:.3f}",
                    f"{100 * rb['full_no_heuristic'][z]['completion']:.0f}%", f"{rb['greedy'][z]['overlap']:.3f}",
                    f"{rb['greedy_dead_ends'][z]['overlap']:.3f}"]
                   for z in sizes]), "",
            "![rainbow overlap by size](rainbow_overlap_by_size.png)", "",
            "MovingAI maps, mean overlap over the 3 reference starts:", "",
            table(["map", "rainbow + heuristic", "greedy", "lkh"],
                  [[name, f"{np.mean(v):.3f}", f"{np.mean(ext[name]['greedy']):.3f}", f"{np.mean(ext[name]['lkh']):.3f}"]
                   for name, v in rb["external"].items()])]
    sensor = ["Camera, range r = 3 (the full-information model; no camera stages trained), with the "
              "heuristic fallback, `cpp_eval` as above:", "",
              table(["size", "overlap", "completed"],
                    [[z, f"{rb['camera_r3'][z]['overlap']:.3f}", f"{100 * rb['camera_r3'][z]['completion']:.0f}%"]
                     for z in sizes])]
    p = rb["p2p"]
    p2p = [f"The first {p['maps']:,} scenarios of `p2p_eval` (one point of interest), heuristic fallback on: "
           f"{100 * p['optimal']:.1f}% on a shortest path, {100 * p['completion']:.1f}% reached, "
           f"{p['mean_extra_steps']:.2f} steps beyond the shortest path on average."]
    return full, sensor, p2p


TABLE_5_1 = {"q-learning": (491.1, 492.2, 571.5, 698.9), "sarsa": (615.8, 529.7, 688.9, 791.7),
             "double-q": (477.8, 498.4, 1521.5, 1993.6), "watkins": (985.1, 1448.0, 2285.9, 6934.1)}  # seconds


def tabular_results(out: str) -> dict:
    """Fig. 5.5: the committed tabular_q table (greedy, heuristic on, lidar map) on ch5_eval, mean ρ
    per (size, requested obstacles); beside it the untrained table (every state never seen: a
    random move toward an uncovered neighbour, the heuristic at dead ends). Written to
    results/tabular/fig5_5.json."""
    import tabular_q
    root = os.path.dirname(os.path.abspath(__file__))
    path = os.path.join(root, "maps", "ch5_eval.npz")
    data, scenarios = np.load(path), gridworld.load_dataset(path)
    model = os.path.join(root, DEFAULT_CHECKPOINT["tabular"])
    trained = tabular_q.QTable.load(model)
    result = {"model": {k: v for k, v in json.load(open(os.path.splitext(model)[0] + ".json")).items()
                        if k != "curve_rho"}, "settings": []}
    rho = {name: tabular_q.evaluate_table(t, scenarios, sensor="lidar")["rho"]
           for name, t in (("trained", trained), ("untrained", tabular_q.QTable(trained.memory, trained.sensor_range)))}
    for size, obstacles in sorted({(int(a), int(b)) for a, b in zip(data["size"], data["requested_obstacles"])}):
        pick = (data["size"] == size) & (data["requested_obstacles"] == obstacles)
        result["settings"].append(dict(size=size, obstacles=obstacles, maps=int(pick.sum()),
                                       **{name: round(float(r[pick].mean()), 4) for name, r in rho.items()}))
    os.makedirs(os.path.join(out, "tabular"), exist_ok=True)
    with open(os.path.join(out, "tabular", "fig5_5.json"), "w") as f:
        json.dump(result, f, indent=1)
    return result


def tabular_sections(out: str, fig55: dict, table) -> list[str]:
    """RESULTS.md lines for chapter 5 and its two figures, from results/tabular/ (the training
    runs of Fig. 5.4 and Table 5.1 in fig5_4/, if there)."""
    import matplotlib.pyplot as plt
    runs, folder = {}, os.path.join(out, "tabular", "fig5_4")
    for name in sorted(os.listdir(folder)) if os.path.isdir(folder) else []:
        with open(os.path.join(out, "tabular", "fig5_4", name)) as f:
            run = json.load(f)
        a = run["args"]
        runs[(a["algorithm"], a["number_obstacles"], a["heuristic"])] = run
    algorithms = [a for a in TABLE_5_1 if (a, 0, True) in runs and (a, 1, True) in runs]
    fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    for ax, obstacles in zip(axes, (0, 1) if algorithms else ()):
        for a in algorithms:
            run = runs[(a, obstacles, True)]
            x = (np.arange(len(run["curve_rho"])) + 1) * run["curve_window"]
            ax.plot(x, run["curve_rho"], label=a)
        ax.set(xlabel="training episode", title=f"6x6, corner starts, {obstacles} obstacle(s)")
        ax.grid(alpha=0.3)
    if algorithms:
        axes[0].set_ylabel(f"mean ρ per {run['curve_window']:,} episodes")
        axes[0].legend()
        fig.tight_layout()
        fig.savefig(os.path.join(out, "tabular_fig5_4.png"), dpi=120)
    plt.close(fig)
    settings = fig55["settings"]
    fig, ax = plt.subplots(figsize=(7, 4))
    for obstacles in sorted({s["obstacles"] for s in settings}):
        row = [s for s in settings if s["obstacles"] == obstacles]
        ax.plot([s["size"] for s in row], [s["trained"] for s in row], marker="o", label=f"{obstacles} obstacles")
    ax.set(xlabel="map size N (trained on 4-10)", ylabel="mean ρ", title="Q-learning table on ch5_eval")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(out, "tabular_fig5_5.png"), dpi=120)
    plt.close(fig)

    def last(run):  # mean ρ of the last 10% of training
        c = run["curve_rho"]
        return np.mean(c[-max(1, len(c) // 10):])

    m = fig55["model"]
    sizes = sorted({s["size"] for s in settings})
    obstacle_counts = sorted({s["obstacles"] for s in settings})
    cell = {(s["size"], s["obstacles"]): s for s in settings}
    intro = ["Every number here comes from `tabular_q.py` runs on one core of a 2-core CPU; ρ = steps / free "
             "cells as gridworld counts it, so a perfect sweep of an obstacle-free N×N map is (N² − 1)/N² "
             "(0.972 on 6×6), not the 1 of §5.4.1.", ""]
    comparison = [] if not algorithms else [
        "**Fig. 5.4** — 100,000 training episodes on 6×6 with corner starts, heuristic on, "
        "mean ρ per 1,000 episodes (`results/tabular/fig5_4/*.json`; commands in the README):", "",
        "![Fig. 5.4](tabular_fig5_4.png)", "",
        table(["algorithm", "ρ, last 10k episodes, 0 obstacles", "ρ, last 10k episodes, 1 obstacle"],
              [[a, f"{last(runs[(a, 0, True)]):.4f}", f"{last(runs[(a, 1, True)]):.4f}"] for a in algorithms]), "",
        "**Table 5.1** — training time (s) of those 100,000 episodes, ours (one core of a 2-core CPU, "
        "256 worlds stepped together) / the dissertation's (AMD Ryzen 7 5800H, one episode at a time):", "",
        table(["method", "heuristic, no obstacles", "heuristic, one obstacle", "no heuristic, no obstacles",
               "no heuristic, one obstacle"],
              [[a] + [f"{runs[(a, o, h)]['wall_seconds']:.0f} / {TABLE_5_1[a][k]}" if (a, o, h) in runs else
                      f"– / {TABLE_5_1[a][k]}" for k, (h, o) in enumerate(((True, 0), (True, 1), (False, 0), (False, 1)))]
               for a in algorithms]), ""]
    return intro + comparison + [
        f"**Fig. 5.5** — the committed table `models/tabular_q.npz` (Q-learning, sizes "
        f"{m['args']['min_size']}-{m['args']['size']}, 0-{m['args']['number_obstacles']} obstacles, random starts): "
        f"{m['episodes']:,} training episodes in {m['wall_seconds'] / 60:.0f} min "
        f"({m['episodes_per_second']:,.0f} episodes/s, {m['states']:,} states) against the dissertation's 17.5 M. "
        "Greedy on `maps/ch5_eval.npz`, 100 maps per setting (the dissertation used 1,000), mean ρ; in brackets "
        "the untrained table (a random move toward an uncovered neighbour, the heuristic at dead ends):", "",
        table(["size \\ obstacles"] + [str(o) for o in obstacle_counts],
              [[str(z)] + [f"{cell[(z, o)]['trained']:.3f} ({cell[(z, o)]['untrained']:.3f})" for o in obstacle_counts]
               for z in sizes]), "",
        "![Fig. 5.5](tabular_fig5_5.png)",
    ]


def report(args: ReportArgs) -> None:
    """Regenerate results/: figures (PNG) and RESULTS.md from the committed maps and models."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    os.makedirs(args.out, exist_ok=True)
    data_path = os.path.join(args.out, "classical_cpp.json")
    if not args.reuse or not os.path.exists(data_path):
        classical_cpp.report(args.per_size)
    with open(data_path) as f:
        data = json.load(f)
    cpp, ext, marl = data["cpp_eval"], data["external"], data["marl_eval"]
    planners = list(cpp)
    bands = [k for k in next(iter(cpp.values())) if "-" in k]

    fig, ax = plt.subplots(figsize=(7, 4))
    for name in planners:
        ax.plot(bands, [cpp[name][b] for b in bands], marker="o", label=name)
    ax.set(xlabel="map size (edge, cells)", ylabel="mean overlap $O_v$",
           title=f"Planners on cpp_eval ({data['per_size']} maps per size)")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(os.path.join(args.out, "planners_overlap_by_size.png"), dpi=120)
    plt.close(fig)

    maps = list(ext)
    fig, ax = plt.subplots(figsize=(9, 4))
    width = 0.8 / len(planners)
    for k, name in enumerate(planners):
        ax.bar(np.arange(len(maps)) + k * width, [np.mean(ext[m][name]) for m in maps], width, label=name)
    ax.set_xticks(np.arange(len(maps)) + 0.4 - width / 2, [m.replace(".map", "") for m in maps],
                  rotation=30, ha="right")
    ax.set(ylabel="mean overlap $O_v$ (3 starts)", title="Planners on the MovingAI maps")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(os.path.join(args.out, "planners_external.png"), dpi=120)
    plt.close(fig)

    agents = sorted(int(n) for n in marl)
    fig, ax = plt.subplots(figsize=(6, 4))
    for name in ("greedy", "partition"):
        ax.plot(agents, [marl[str(n)][name] for n in agents], marker="o", label=name)
    bound = [marl[str(n)]["lower_bound_time_save"] for n in agents]
    ax.plot(agents, bound, "k--", label="lower bound ≈ 1/N")
    ax.set(xlabel="agents N", ylabel="mean time-save factor $t_{sf}$",
           title="Multi-agent baselines on marl_eval (sizes 10-30)")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(os.path.join(args.out, "marl_baselines.png"), dpi=120)
    plt.close(fig)

    def table(header, rows):
        return "\n".join(["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
                         + ["| " + " | ".join(r) + " |" for r in rows])

    rainbow_path = os.path.join(args.out, "rainbow_cpp.json")
    model = os.path.join(os.path.dirname(os.path.abspath(__file__)), DEFAULT_CHECKPOINT["rainbow"])
    if os.path.exists(model) and (not args.reuse or not os.path.exists(rainbow_path)):
        rainbow_results(args.out, args.per_size, args.p2p_maps, model)
    full_info = sensor_based = point_to_point = [NOT_TRAINED.format(script="rainbow_cpp.py")]
    if os.path.exists(rainbow_path):
        with open(rainbow_path) as f:
            rb = json.load(f)
        full_info, sensor_based, point_to_point = rainbow_sections(rb, cpp, ext, args.out, table)
    marl_path = os.path.join(args.out, "rainbow_marl.json")
    marl_model = os.path.join(os.path.dirname(os.path.abspath(__file__)), DEFAULT_CHECKPOINT["marl"])
    if os.path.exists(marl_model) and (not args.reuse or not os.path.exists(marl_path)):
        marl_results(args.out, marl_model)
    multi_agent = [NOT_TRAINED.format(script="rainbow_marl.py")]
    if os.path.exists(marl_path):
        with open(marl_path) as f:
            multi_agent = marl_sections(json.load(f), marl, args.out, table)
    tabular_path = os.path.join(args.out, "tabular", "fig5_5.json")
    tabular_model = os.path.join(os.path.dirname(os.path.abspath(__file__)), DEFAULT_CHECKPOINT["tabular"])
    if os.path.exists(tabular_model) and (not args.reuse or not os.path.exists(tabular_path)):
        tabular_results(args.out)
    tabular = [NOT_TRAINED.format(script="tabular_q.py")]
    if os.path.exists(tabular_path):
        with open(tabular_path) as f:
            tabular = tabular_sections(args.out, json.load(f), table)

    lines = [
        "# Results", "",
        "Regenerated by `python evaluate.py report` (add `--reuse` to re-draw from "
        "`results/classical_cpp.json` without re-running the planners). Every number is counted "
        "by gridworld's environment replaying the planned paths (`classical_cpp.replay`).", "",
        "## Single agent, full information (Figs. 6.13-6.16)", "", *full_info, "",
        "## Comparison with classical planners (Table 6.4)", "",
        f"`cpp_eval`, the first {data['per_size']} maps of each size, mean overlap by size band; "
        f"LKH ({data['lkh_time_limit_s']:.0f} s cap per map) is the near-optimal reference.", "",
        table(["planner"] + bands + ["all", "plan ms/map"],
              [[n] + [f"{cpp[n][b]:.3f}" for b in bands] + [f"{cpp[n]['all']:.3f}",
                                                            f"{cpp[n]['plan_ms_per_map']:.1f}"]
               for n in planners]), "",
        "![planners by size](planners_overlap_by_size.png)", "",
        "MovingAI maps (`maps/external`), mean overlap over the 3 reference starts:", "",
        table(["map"] + planners,
              [[m] + [f"{np.mean(ext[m][n]):.3f}" for n in planners] for m in maps]), "",
        "![planners on external maps](planners_external.png)", "",
        "## Sensor-based coverage (Figs. 6.17-6.22)", "", *sensor_based, "",
        "## Point-to-point (Fig. 6.23)", "", *point_to_point, "",
        "## Multi-agent (Figs. 7.11-7.12)", "",
        "Baselines on `marl_eval` sizes 10-30 (every 5th layout), mean time-save factor "
        "$t_{sf} = T / n_{poi}(s_0)$:", "",
        table(["agents", "maps", "greedy (claims)", "partition", "lower bound"],
              [[str(n), str(marl[str(n)]["maps"]), f"{marl[str(n)]['greedy']:.3f}",
                f"{marl[str(n)]['partition']:.3f}", f"{marl[str(n)]['lower_bound_time_save']:.3f}"]
               for n in agents]), "",
        "![multi-agent baselines](marl_baselines.png)", "",
        *multi_agent, "",
        "## Tabular agent (Fig. 5.4, Table 5.1, Fig. 5.5)", "", *tabular, "",
    ]
    with open(os.path.join(args.out, "RESULTS.md"), "w") as f:
        f.write("\n".join(lines))
    print(f"wrote {args.out}/RESULTS.md and its figures")


if __name__ == "__main__":
    try:
        if sys.argv[1:2] == ["report"]:
            report(tyro.cli(ReportArgs, args=sys.argv[2:]))
        else:
            main(tyro.cli(Args))
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
