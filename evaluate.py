"""Evaluate an agent or a planner on maps; one row per episode, a summary, a comparison with other
policies on the same episodes, and videos of the agents at work.

    python evaluate.py --policy rainbow --maps maps/external/*.map --starts maps/external/references.json \
        --compare greedy,greedy-dead-ends,lkh --video runs/eval/main/video --out runs/eval/main
    python evaluate.py --policy greedy --dataset maps/cpp_eval.npz --out runs/eval/greedy
    python evaluate.py --policy partition --dataset maps/marl_eval.npz --agents 5 --out DIR
    python evaluate.py --policy marl --dataset maps/marl_eval.npz --agents 5 --faulty-agent-at 0.5 --out DIR
    python evaluate.py --policy rainbow --sensor camera --sensor-range 3 --compare frontier,frontier-rollout \
        --dataset maps/cpp_eval.npz --every 10 --out DIR

Writes DIR/episodes.csv (map, size, n_free, agents, start, steps, revisits, overlap, time_save,
completed, truncated, heuristic_steps) and DIR/summary.json (mean, median, std, min, max of
overlap, time-save factor and steps, completion rate; overall and by map size) and prints one line
(mean and median overlap, time-save, completion, the heuristic's share of a learned agent's steps).
Every metric is counted by gridworld's own environment. Policies: the planners of classical_cpp.py (greedy,
greedy-dead-ends, greedy-far-first, rollout, boustrophedon, spiral-stc, wavefront, lkh, partition) and the chapter-6
agent `rainbow` (rainbow_cpp.py; --checkpoint, default models/rainbow_cpp.pt, noise off, heuristic fallback unless
--no-heuristic), the chapter-7 agents `marl` (rainbow_marl.py; default models/rainbow_marl.pt, decentralised: every
agent acts on its own observation; --action-loss, --faulty-agent-at), the chapter-5 agent `tabular` (tabular_q.py;
--checkpoint, default models/tabular_q.npz, greedy, the heuristic at dead ends unless --no-heuristic, --sensor builds
the heuristic's map), and the exploration baselines, policies of the agent's known map under --sensor, --sensor-range
and --sensor-failure (one agent): `frontier` (the navigation heuristic: nearest known point of interest, else nearest
frontier cell, dead-ends-first ties), `frontier-row-major` (row-major ties), `frontier-far-first` (far-first ties:
steps from the start over the known map) and `frontier-rollout` (the one-step rollout of `frontier` planned on the
known map, unknown cells taken as points of interest). With --sensor full they are greedy-dead-ends, greedy,
greedy-far-first and rollout.

--compare greedy,lkh runs the same episodes (same maps, same starts) with each listed policy (learned
ones with their default model) and prints and writes DIR/compare.md and DIR/compare.json: mean overlap,
time-save and completion per policy, by map when there are at most 12 maps. --video VDIR films the
first --video-episodes episodes of each map (at most --video-max in all): VDIR/<episode>.mp4 and a PNG
of the final coverage with the path drawn in step order; with --compare also DIR/compare.png, the first
episode of --policy beside each compared policy's, a panel each. --starts takes {map file name: [[row, col], ...]}
or maps/external/references.json's {map file name: [{"start": [row, col], ...}, ...]}; starts drawn with
--seed depend on the seed and the map's file name only. Bad input is a one-line error and writes nothing;
the files are written only once everything has run.
"""
from __future__ import annotations

import contextlib
import csv
import json
import math
import os
import pickle
import re
import signal
import sys
import zipfile
import zlib
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from functools import partial

import numpy as np
from tqdm import tqdm

import classical_cpp
import gridworld
from gridworld import Scenario

LEARNED = ("rainbow", "marl", "tabular")
# policies of the agent's known map (the heuristic, or its one-step rollout): name -> (dead_ends_first, rollout, far_first)
FRONTIER = {"frontier": (True, False, False), "frontier-row-major": (False, False, False),
            "frontier-far-first": (True, False, True), "frontier-rollout": (True, True, False)}
DEFAULT_CHECKPOINT = {"rainbow": "models/rainbow_cpp.pt", "marl": "models/rainbow_marl.pt",
                      "tabular": "models/tabular_q.npz"}
COLUMNS = ["map", "size", "n_free", "agents", "start", "steps", "revisits", "overlap", "time_save",
           "completed", "truncated", "heuristic_steps"]
OPTIONAL_COLUMNS = ["walled_off"]  # marl --faulty-agent-at: the frozen agent left cells no working agent can reach
BY_MAP_UP_TO = 12  # compare tables list the maps one by one up to this many maps, else only the overall means
VIDEO_PIXELS = 384  # longer side of a video frame: 12 px a cell on 32x32 maps, ~1 s to encode 1,000 steps
VIDEO_SECONDS = 30  # long episodes play faster than 10 steps/s so that a video lasts about this long


@dataclass
class Args:
    policy: str = "greedy"
    """a classical_cpp planner (greedy, greedy-dead-ends, greedy-far-first, rollout, boustrophedon, spiral-stc,
    wavefront, lkh, partition), a learned agent (rainbow, marl, tabular) or a policy of the known map under
    --sensor (frontier: the heuristic with dead-ends-first ties, the better on random maps; frontier-row-major:
    row-major ties; frontier-far-first: far-first ties, the better on structured maps; frontier-rollout: its
    one-step rollout on the known map)"""
    checkpoint: str | None = None
    """weights / table of a learned agent"""
    maps: tuple[str, ...] = ()
    """MovingAI .map or ASCII map files"""
    dataset: str | None = None
    """a gridworld .npz dataset (maps/cpp_eval.npz, maps/marl_eval.npz, ...)"""
    agents: int = 1
    """agents per episode: the first N stored starts, else N starts drawn with --seed"""
    starts: str | None = None
    """JSON file {map file name: [[row, col], ...]} (or references.json's [{"start": [row, col]}, ...]):
    agent i starts at entry i; with one agent and several entries, one episode per entry"""
    seed: int = 0
    """seed for starts drawn at random (with the map's file name: a map gets the same starts wherever it is
    listed), and for the sensor failures and lost actions (with the episode's batch of 64)"""
    sensor: str = "full"
    """full, camera or lidar (learned and frontier policies; the planners plan with full information)"""
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
    rollout_base: str = "greedy-dead-ends"
    """the rollout planner's base policy: greedy-dead-ends, greedy or greedy-far-first"""
    limit: int = 0
    """evaluate only the first LIMIT scenarios (0: all)"""
    min_size: int = 0
    """evaluate only maps whose longer edge is at least this"""
    max_size: int = 0
    """evaluate only maps whose longer edge is at most this (0: no bound)"""
    every: int = 1
    """evaluate every k-th of the maps left"""
    workers: int = 1
    """processes to spread a planner's episodes over"""
    compare: str = ""
    """policies, comma-separated, also run on the same episodes (same maps, same starts), e.g.
    greedy,greedy-dead-ends,lkh; learned ones with their default model; table in DIR/compare.md"""
    video: str | None = None
    """folder for an MP4 and a PNG (final coverage, the path in step order) per filmed episode"""
    video_episodes: int = 1
    """episodes filmed per map"""
    video_max: int = 8
    """episodes filmed in all, at most"""
    quiet: bool = False
    """no progress bars (they are off anyway when stdout is not a terminal)"""
    trainer: str | None = None
    """the trainer script whose model --checkpoint holds, for a model of a copied and changed trainer (its network,
    observation and evaluation are used); default: the script the model's JSON names, looked for in the working
    folder and beside evaluate.py, else rainbow_cpp.py (rainbow) or rainbow_marl.py (marl)"""
    out: str = "runs/eval"
    """output folder for episodes.csv, summary.json and, with --compare, compare.md / .json / .png"""
    overwrite: bool = False
    """replace the files of an earlier --out (or --video) outside runs/; under runs/ they are replaced anyway"""


def _progress(quiet: bool, **kw) -> tqdm:
    """A tqdm bar, silent with --quiet or when stdout is not a terminal."""
    return tqdm(disable=quiet or not sys.stdout.isatty(), **kw)


def _load(loader, path: str, what: str):
    """loader(path), any unreadable file a ValueError naming it (the loaders raise ValueError themselves for
    most; this catches what slips through)."""
    try:
        return loader(path)
    except (OSError, EOFError, RuntimeError, pickle.UnpicklingError, zipfile.BadZipFile, zlib.error, KeyError) as e:
        raise ValueError(f"{path}: not a readable {what} ({(str(e).splitlines() or [type(e).__name__])[0]})") from None


def _finite_model(q, path: str, what: str):
    """The loaded network `q`, refused (a one-line ValueError) if any weight is nan or inf: a diverged model would be
    scored as if it were a policy."""
    for name, value in q.state_dict().items():
        if value.is_floating_point() and not bool(value.isfinite().all()):
            raise ValueError(f"{path}: not a usable {what}: its weights are not finite ({name} holds nan or inf)")
    return q


def _check_counts(args: Args) -> None:
    """The counts and sizes scenarios_from uses, each a one-line error naming its flag."""
    for name, value in vars(args).items():
        if isinstance(value, float) and not math.isfinite(value):
            raise ValueError(f"--{name.replace('_', '-')} must be a finite number, got {value}")
    for flag, value, least in (("--agents", args.agents, 1), ("--every", args.every, 1), ("--limit", args.limit, 0),
                               ("--min-size", args.min_size, 0), ("--max-size", args.max_size, 0),
                               ("--seed", args.seed, 0)):
        if value < least:
            raise ValueError(f"{flag} must be >= {least}, got {value}")
    if args.max_size and args.max_size < max(args.min_size, 2):
        raise ValueError(f"--max-size must be 0 (no bound) or >= 2 and >= --min-size, got {args.max_size}")
    if args.rollout_base not in classical_cpp.ROLLOUT_BASES:
        raise ValueError(f"--rollout-base {args.rollout_base!r}: choose from {', '.join(classical_cpp.ROLLOUT_BASES)}")


def read_starts(path: str, names: list[str]) -> dict[str, np.ndarray]:
    """A starts file: {map file name: [[row, col], ...]} or, as maps/external/references.json,
    {map file name: [{"start": [row, col], ...}, ...]}; (k, 2) cells per map. A name matching none of `names`
    is an error unless every one of `names` has its starts in the file (a typo would leave a map to random
    starts)."""
    try:
        with open(path) as f:
            given = json.load(f)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: cannot read starts ({e})") from None
    usage = 'expected {"map file name": [[row, col], ...]} or {"map file name": [{"start": [row, col]}, ...]}'
    if not isinstance(given, dict):
        raise ValueError(f"{path}: a JSON {type(given).__name__}; {usage}")
    out = {}
    for name, entries in given.items():
        if not isinstance(entries, list) or not entries:
            raise ValueError(f"{path}: {name}: not a non-empty list of starts; {usage}")
        cells = [e.get("start") if isinstance(e, dict) else e for e in entries]
        for entry, cell in zip(entries, cells):
            if not (isinstance(cell, list) and len(cell) == 2
                    and all(type(v) is int and -2 ** 31 <= v < 2 ** 31 for v in cell)):  # int64 holds them
                raise ValueError(f"{path}: {name}: {json.dumps(entry)[:60]} is not a [row, col] start; {usage}")
        out[name] = np.array(cells, np.int64)
    unknown = [n for n in out if n not in names]
    missing = [n for n in names if n not in out]
    if unknown and missing:
        raise ValueError(f"{path}: {unknown[0]!r} is none of the maps given (their file names: {', '.join(names[:4])}"
                         f"{', ...' if len(names) > 4 else ''})")
    return out


def scenarios_from(args: Args) -> list[tuple[str, Scenario]]:
    """(map name, scenario with starts covered) for every episode asked for. Starts drawn at random depend on
    --seed and the map's file name only, never on its place in the list."""
    _check_counts(args)
    named: list[tuple[str, Scenario]] = []
    if args.dataset:
        if not os.path.isfile(args.dataset):
            raise ValueError(f"--dataset {args.dataset}: " + ("a folder, not a dataset file" if os.path.isdir(args.dataset)
                                                               else "no such file"))
        base = os.path.basename(args.dataset)
        named += [(f"{base}[{i}]", s) for i, s in enumerate(_load(gridworld.load_dataset, args.dataset, "dataset"))]
    for path in args.maps:
        named.append((os.path.basename(path), _load(gridworld.load_map, path, "map")))
    if not named:
        raise ValueError("give --maps FILE... or --dataset FILE")
    given = read_starts(args.starts, [n for n, _ in named]) if args.starts else {}
    named = [(n, s) for n, s in named
             if args.min_size <= max(s.obstacles.shape) <= (args.max_size or max(s.obstacles.shape))][::args.every]
    if not named:
        raise ValueError(f"no map has an edge in [{args.min_size}, {args.max_size or 'any'}]")
    if args.limit:
        named = named[:args.limit]
    episodes = []
    for name, s in named:
        if name in given:
            cells = given[name]
            groups = [cells[i:i + 1] for i in range(len(cells))] if args.agents == 1 else [cells[:args.agents]]
            if len(groups[0]) < args.agents:
                raise ValueError(f"{args.starts}: {name} has {len(cells)} starts for {args.agents} agents")
            where = f"{args.starts}: {name}"
        else:
            rng = np.random.default_rng([args.seed, zlib.crc32(name.encode())])  # by name: the same starts in any list
            groups, where = [classical_cpp.starts_for(s, args.agents, rng, name)], name
        for starts in groups:
            gridworld.check_scenario(Scenario(s.obstacles, starts, s.covered), where)  # before with_starts indexes them
            episodes.append((name, classical_cpp.with_starts(Scenario(s.obstacles, starts, s.covered))))
    return episodes


def _sliced(episodes: list[tuple[str, Scenario]], step: int, run, desc: str, quiet: bool,
            paths: dict | None) -> list[dict]:
    """Rows of `run(slice of episodes, its first index, trajectories)` over `step` episodes at a time under a
    progress bar. `trajectories` is a list for `run` to extend with every episode's agent paths when the slice
    holds an episode whose index is a key of `paths` (then filled in), else None."""
    rows = []
    with _progress(quiet, total=len(episodes), desc=desc, unit="episode") as bar:
        for i in range(0, len(episodes), step):
            part = episodes[i:i + step]
            wanted = [j for j in paths or () if i <= j < i + len(part)]
            trajectories = [] if wanted else None
            rows += run(part, i, trajectories)
            for j in wanted:
                paths[j] = trajectories[j - i]
            bar.update(len(part))
    return rows


def _rows(part: list[tuple[str, Scenario]], m: dict) -> list[dict]:
    """One row per episode from a batched rollout's per-episode arrays."""
    return [_row(name, s, {k: v[j].item() for k, v in m.items()}) for j, (name, s) in enumerate(part)]


def run_planner(policy: str, episodes: list[tuple[str, Scenario]], trajectories: list | None = None,
                rollout_base: str = "greedy-dead-ends") -> list[dict]:
    """Plan and replay every episode; one row per episode. `trajectories`, if given, is extended with each
    episode's per-agent (T_i+1, 2) paths of (row, col) cells."""
    paths = classical_cpp.plan(policy, [s for _, s in episodes], rollout_base)
    if trajectories is not None:
        trajectories.extend(paths)
    return [_row(name, s, classical_cpp.replay(s, p)) for (name, s), p in zip(episodes, paths)]


def _quiet_worker() -> None:
    """A --workers process dies of Ctrl-C or SIGTERM without a traceback of its own; the main process reports."""
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, signal.SIG_DFL)


def _run_chunk(job):
    policy, chunk, record, rollout_base = job
    trajectories = [] if record else None
    return run_planner(policy, chunk, trajectories, rollout_base), trajectories


def _plan_rows(args: Args, policy: str, episodes: list[tuple[str, Scenario]], paths: dict | None) -> list[dict]:
    """A planner on every episode, in --workers processes, the rows in the episodes' order."""
    if args.workers == 1:  # greedy plans a slice at once, the others map by map
        return _sliced(episodes, 64 if policy in classical_cpp.BATCHED else 1,
                       lambda part, i, trajectories: run_planner(policy, part, trajectories, args.rollout_base), policy,
                       args.quiet, paths)
    k = -(-len(episodes) // args.workers)  # contiguous chunks, so the rows keep the episodes' order
    with ProcessPoolExecutor(args.workers, initializer=_quiet_worker) as pool:
        jobs = {i: pool.submit(_run_chunk, (policy, episodes[i:i + k], any(i <= j < i + k for j in paths or ()),
                                            args.rollout_base))
                for i in range(0, len(episodes), k)}

        def collect(part, i, trajectories):
            rows, plans = jobs[i].result()
            if trajectories is not None:
                trajectories.extend(plans)
            return rows

        return _sliced(episodes, k, collect, policy, args.quiet, paths)


def checkpoint_of(args: Args, policy: str) -> str:
    """--checkpoint, else the shipped model: models/... under the working folder, else beside this script."""
    if args.checkpoint:
        return args.checkpoint
    here = DEFAULT_CHECKPOINT[policy]
    return here if os.path.exists(here) else os.path.join(os.path.dirname(os.path.abspath(__file__)), here)


def made_by(path: str) -> str | None:
    """The trainer script an export's JSON names (its provenance), or None."""
    try:
        with open(os.path.splitext(path)[0] + ".json") as f:
            return json.load(f)["provenance"]["script"]
    except (OSError, ValueError, KeyError, TypeError):
        return None


def trainer_of(args: Args, path: str, shipped: str):
    """The module of the trainer that made the model at `path`, whose load_policy and evaluate_policy score it:
    --trainer, else the script the model's JSON names, else the shipped trainer `shipped`. A copied trainer is
    imported from its file (the working folder's, else the one beside evaluate.py)."""
    import importlib
    import importlib.util
    script = args.trainer or made_by(path) or f"{shipped}.py"
    name = os.path.splitext(os.path.basename(script))[0]
    if name in ("rainbow_cpp", "rainbow_marl") and not args.trainer:
        return importlib.import_module(name)
    here = os.path.join(os.path.dirname(os.path.abspath(__file__)), os.path.basename(script))
    found = next((p for p in (script, here) if os.path.isfile(p)), None)
    if found is None:
        raise ValueError(f"{'--trainer ' + script if args.trainer else path + ': made by ' + script}: no such file in "
                         "the working folder nor beside evaluate.py (--trainer PATH names it)")
    loaded = sys.modules.get(name)
    if loaded is not None and os.path.abspath(getattr(loaded, "__file__", "")) == os.path.abspath(found):
        return loaded
    spec = importlib.util.spec_from_file_location(name, found)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up while it runs
    try:
        spec.loader.exec_module(module)
    except Exception as e:  # noqa: BLE001 (any failure of a user's script is one line)
        del sys.modules[name]
        raise ValueError(f"{found}: cannot import it ({type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''})") \
            from None
    missing = [f for f in ("load_policy", "evaluate_policy") if not hasattr(module, f)]
    if missing:
        raise ValueError(f"{found}: no {' or '.join(missing)}; a trainer copied from {shipped}.py has them")
    return module


def _rainbow(args: Args):
    """Check the settings and load the model; returns run(episodes, paths) -> rows."""
    if args.agents != 1:
        raise ValueError("rainbow is single-agent; use --agents 1 (marl for several)")
    if args.faulty_agent_at is not None or args.action_loss:
        raise ValueError("--faulty-agent-at and --action-loss need several agents (the marl policy)")
    path = checkpoint_of(args, "rainbow")
    rainbow_cpp = trainer_of(args, path, "rainbow_cpp")
    kind = f"{rainbow_cpp.__name__} model"
    q = _finite_model(_load(rainbow_cpp.load_policy, path, kind), path, kind)
    frames = q.conv[0].in_channels // 4

    def run(part, i, trajectories):
        return _rows(part, rainbow_cpp.evaluate_policy(
            q, [s for _, s in part], frames, args.sensor, args.sensor_range, args.sensor_failure, args.heuristic,
            dead_ends_first=args.heuristic_dead_ends, trajectories=trajectories, seed=args.seed + i))

    return lambda episodes, paths=None: _sliced(episodes, 64, run, "rainbow", args.quiet, paths)


def run_rainbow(args: Args, episodes: list[tuple[str, Scenario]], paths: dict | None = None) -> list[dict]:
    """The chapter-6 agent (rainbow_cpp.py): noise off, heuristic fallback unless disabled; 64 worlds at a time.
    `paths`, if given, maps episode indices to fill with the agent's (T+1, 1, 2) cells."""
    return _rainbow(args)(episodes, paths)


def _marl(args: Args):
    """Check the settings and load the model; returns run(episodes, paths) -> rows."""
    if args.faulty_agent_at is not None and (args.agents < 2 or not 0 <= args.faulty_agent_at <= 1):
        raise ValueError("--faulty-agent-at needs --agents >= 2 and a fraction in [0, 1]")
    if not 0 <= args.action_loss < 1:
        raise ValueError(f"--action-loss must be in [0, 1), got {args.action_loss}")
    path = checkpoint_of(args, "marl")
    rainbow_marl = trainer_of(args, path, "rainbow_marl")
    kind = f"{rainbow_marl.__name__} model"
    q = _finite_model(_load(rainbow_marl.load_policy, path, kind), path, kind)
    frames = q.conv[0].in_channels // 4

    def rollout(part, i, trajectories):
        return _rows(part, rainbow_marl.evaluate_policy(
            q, [s for _, s in part], frames, args.sensor, args.sensor_range, args.sensor_failure, args.heuristic,
            action_loss=args.action_loss, faulty_at=args.faulty_agent_at, seed=args.seed + i,
            dead_ends_first=args.heuristic_dead_ends, trajectories=trajectories))

    return lambda episodes, paths=None: _sliced(episodes, 64, rollout, "marl", args.quiet, paths)


def run_marl(args: Args, episodes: list[tuple[str, Scenario]], paths: dict | None = None) -> list[dict]:
    """The chapter-7 agents (rainbow_marl.py): noise off, decentralised, heuristic fallback unless disabled;
    heuristic_steps counts agent-steps. `paths` as for run_rainbow, (T+1, N, 2) cells."""
    return _marl(args)(episodes, paths)


def _tabular(args: Args):
    """Check the settings and load the table; returns run(episodes, paths) -> rows."""
    import tabular_q
    if args.agents != 1:
        raise ValueError("tabular is single-agent; use --agents 1")
    if args.sensor_failure or args.faulty_agent_at is not None or args.action_loss:
        raise ValueError("tabular: --sensor-failure, --faulty-agent-at and --action-loss are not modelled in chapter 5")
    path = checkpoint_of(args, "tabular")
    table = _load(tabular_q.QTable.load, path, "tabular_q table")
    if not np.isfinite(table.q[:, :table.size]).all():
        raise ValueError(f"{path}: not a usable tabular_q table: its Q-values are not finite (nan or inf)")
    if table.sensor_range != args.sensor_range:
        raise ValueError(f"{path}: trained with r = {table.sensor_range}; --sensor-range is {args.sensor_range}")

    def run(episodes, paths=None):  # evaluate_table keeps its worlds busy from a queue and draws its own bar
        trajectories = [] if paths else None
        m = tabular_q.evaluate_table(table, [s for _, s in episodes], args.heuristic, args.sensor, args.seed,
                                     trajectories=trajectories, quiet=args.quiet)
        for j in paths or ():
            paths[j] = trajectories[j]
        return _rows(episodes, m)

    return run


def _frontier(args: Args, policy: str):
    """Check the settings; returns run(episodes, paths) -> rows."""
    if args.agents != 1:
        raise ValueError(f"{policy} is single-agent; use --agents 1")
    if args.faulty_agent_at is not None or args.action_loss:
        raise ValueError("--faulty-agent-at and --action-loss need several agents (the marl policy)")
    dead_ends_first, lookahead, far_first = FRONTIER[policy]

    def play(part, i, trajectories):
        config = gridworld.EnvConfig(load_state=True, load_random=False, sensor=args.sensor,
                                     sensor_range=args.sensor_range, sensor_failure=args.sensor_failure)
        core = gridworld.GridWorldCore(config, len(part), seed=args.seed + i)  # the seed draws the sensor failures
        core.configure(scenarios=[s for _, s in part])
        core.reset()
        done, truncated = np.zeros(core.B, bool), np.zeros(core.B, bool)
        steps = np.zeros(core.B, np.int64)  # each world's own, not counting the waits after its end
        cells = [core.agent_cells()]
        while not done.all():
            action = np.full(core.B, gridworld.WAIT)
            live = np.flatnonzero(~done)
            action[live] = (gridworld.rollout_actions(core, live, dead_ends_first, view="known", far_first=far_first) if lookahead
                            else gridworld.heuristic_actions(core, False, dead_ends_first, far_first)[live, 0])
            ev = core.step(action[:, None])
            steps += ~done
            truncated |= ev["truncated"] & ~done
            done |= ev["terminated"] | ev["truncated"]
            if trajectories is not None:
                cells.append(core.agent_cells())
        if trajectories is not None:
            trajectories.extend(np.stack(cells)[:t + 1, b] for b, t in enumerate(steps))
        m = core.metrics()
        return _rows(part, {**m, "steps": steps, "time_save": steps / np.maximum(m["n_poi_start"], 1),
                            "truncated": truncated})

    return lambda episodes, paths=None: _sliced(episodes, 64, play, policy, args.quiet, paths)


def run_frontier(args: Args, episodes: list[tuple[str, Scenario]], paths: dict | None = None) -> list[dict]:
    """The frontier policies: args.policy (one of FRONTIER) on the agent's known map under --sensor, --sensor-range
    and --sensor-failure, stepped in gridworld, 64 worlds at a time. `paths` as for run_rainbow."""
    return _frontier(args, args.policy)(episodes, paths)


def run_tabular(args: Args, episodes: list[tuple[str, Scenario]], paths: dict | None = None) -> list[dict]:
    """The chapter-5 agent (tabular_q.py): greedy, never-seen states and dead ends take the heuristic (off with
    --no-heuristic); --sensor builds the map the heuristic plans on. `paths` as for run_rainbow."""
    return _tabular(args)(episodes, paths)


def _row(name: str, s: Scenario, m: dict) -> dict:
    return dict(map=name, size=f"{s.obstacles.shape[0]}x{s.obstacles.shape[1]}",
                n_free=int((~s.obstacles).sum()), agents=len(s.starts), start=json.dumps(s.starts.tolist()),
                steps=m["steps"], revisits=m["revisits"], overlap=round(m["overlap"], 6),
                time_save=round(m["time_save"], 6), completed=m["completed"],
                truncated=m.get("truncated", False), heuristic_steps=m.get("heuristic_steps", 0),
                **({"walled_off": m["walled_off"]} if "walled_off" in m else {}))


def summarize(rows: list[dict], families: dict[str, str] | None = None) -> dict:
    """Statistics of some episodes: over all, by size and, given each map's family (dataset_families), by family."""
    def stats(group):
        out = {"episodes": len(group),
               "completion_rate": float(np.mean([r["completed"] for r in group]))}
        for key in ("overlap", "time_save", "steps"):
            v = np.array([r[key] for r in group], float)
            out[key] = dict(mean=float(v.mean()), median=float(np.median(v)), std=float(v.std()),
                            min=float(v.min()), max=float(v.max()))
        return out

    sizes = sorted({r["size"] for r in rows}, key=lambda z: tuple(map(int, z.split("x"))))
    out = {"all": stats(rows), "by_size": {z: stats([r for r in rows if r["size"] == z]) for z in sizes}}
    if families:
        out["by_family"] = {f: stats(of_family(rows, families, f))
                            for f in dict.fromkeys(families.get(r["map"]) for r in rows) if f is not None}
    return out


def of_family(rows: list[dict], families: dict[str, str], family: str) -> list[dict]:
    """The episodes whose map is of `family` (families: dataset_families)."""
    return [r for r in rows if families.get(r["map"]) == family]


def dataset_families(path: str | None) -> dict[str, str]:
    """Episode map name -> map family, for a dataset that stores a `family` column (structured_eval, or one saved
    with gridworld.save_dataset(..., family=...)); empty otherwise."""
    if not path:
        return {}
    with np.load(path) as data:
        if "family" not in data.files:
            return {}
        base = os.path.basename(path)
        return {f"{base}[{i}]": str(f) for i, f in enumerate(data["family"])}


def describe(policy: str, rows: list[dict]) -> str:
    """One readable line: mean and median overlap, time-save, completion and, for a learned policy, the share
    of (agent-)steps the heuristic took."""
    s = summarize(rows)["all"]
    text = (f"{policy} on {s['episodes']} episodes: overlap {s['overlap']['mean']:.3f} (median "
            f"{s['overlap']['median']:.3f}), time-save {s['time_save']['mean']:.3f}, completed "
            f"{100 * s['completion_rate']:.0f}%")
    if policy in LEARNED:
        share = sum(r["heuristic_steps"] for r in rows) / max(1, sum(r["steps"] * r["agents"] for r in rows))
        text += f", heuristic steps {100 * share:.1f}%"
    walled = [r for r in rows if r.get("walled_off")]
    if walled:  # --faulty-agent-at: no team completes these maps
        others = [r for r in rows if not r.get("walled_off")]
        text += f"; {len(walled)} walled off by the frozen agent" + (
            f", completed {100 * np.mean([r['completed'] for r in others]):.0f}% of the others" if others else "")
    return text


def comparison(results: dict[str, list[dict]], families: dict[str, str] | None = None) -> tuple[dict, str]:
    """The policies side by side on the same episodes: mean overlap, time-save and completion overall, by
    map family when the dataset stores one (dataset_families) and by map (JSON), and as markdown tables, by
    map when there are at most BY_MAP_UP_TO maps. The tables print the means, the JSON holds them to 4 decimals."""
    def means(rows):
        return {"episodes": len(rows), "overlap": float(np.mean([r["overlap"] for r in rows])),
                "time_save": float(np.mean([r["time_save"] for r in rows])),
                "completion_rate": float(np.mean([r["completed"] for r in rows]))}

    first = next(iter(results.values()))
    maps = list(dict.fromkeys(r["map"] for r in first))
    table = {"policies": list(results), "episodes": len(first), "agents": first[0]["agents"],
             "all": {p: means(rows) for p, rows in results.items()},
             "by_map": {m: {p: means([r for r in rows if r["map"] == m]) for p, rows in results.items()} for m in maps}}
    lines = [f"Same {len(first)} episodes (same maps, same starts) for every policy, means:", "",
             "| policy | overlap | time-save | completed |", "|---|---|---|---|"]
    lines += [f"| {p} | {m['overlap']:.3f} | {m['time_save']:.3f} | {100 * m['completion_rate']:.0f}% |"
              for p, m in table["all"].items()]
    key = "overlap" if table["agents"] == 1 else "time_save"  # several agents: §7.5's time-save factor
    groups = list(dict.fromkeys(families[r["map"]] for r in first if r["map"] in families)) if families else []
    if groups:
        table["by_family"] = {f: {p: means(of_family(rows, families, f))
                                  for p, rows in results.items()} for f in groups}
        lines += ["", f"Mean {key.replace('_', '-')} by map family (completion when below 100%):", "",
                  "| family | episodes | " + " | ".join(results) + " |", "|---|---|" + "---|" * len(results)]
        lines += [_table_row(f, by_policy, key) for f, by_policy in table["by_family"].items()]
    if len(maps) <= BY_MAP_UP_TO:
        lines += ["", f"Mean {key.replace('_', '-')} by map (completion when below 100%):", "",
                  "| map | episodes | " + " | ".join(results) + " |", "|---|---|" + "---|" * len(results)]
        lines += [_table_row(m, by_policy, key) for m, by_policy in table["by_map"].items()]
    return _rounded(table), "\n".join(lines)


def _rounded(value, digits: int = 4):
    """`value` with every float in it (nested dicts) rounded to `digits` decimals."""
    if isinstance(value, dict):
        return {k: _rounded(v, digits) for k, v in value.items()}
    return round(value, digits) if isinstance(value, float) else value


def _table_row(label: str, by_policy: dict, key: str) -> str:
    """A markdown row of comparison's tables: the episodes, then each policy's mean `key` (and completion)."""
    cells = [f"{v[key]:.3f}" + (f" ({100 * v['completion_rate']:.0f}%)" if v["completion_rate"] < 1 else "")
             for v in by_policy.values()]
    return f"| {label} | {next(iter(by_policy.values()))['episodes']} | " + " | ".join(cells) + " |"


def _runner(args: Args, policy: str):
    """Check `policy`'s settings and load its model; returns run(episodes, paths=None) -> rows."""
    if policy in LEARNED:
        return {"rainbow": _rainbow, "marl": _marl, "tabular": _tabular}[policy](args)
    if policy in FRONTIER:
        return _frontier(args, policy)
    if policy in classical_cpp.SINGLE_AGENT and args.agents != 1:
        raise ValueError(f"{policy} is a single-agent planner; use --agents 1 (or greedy, greedy-dead-ends, "
                         "rollout or partition for several)")
    return lambda episodes, paths=None: _plan_rows(args, policy, episodes, paths)


def _filmed(args: Args, episodes: list[tuple[str, Scenario]]) -> list[int]:
    """The first --video-episodes episodes of each map, at most --video-max in all."""
    taken: dict[str, int] = {}
    picked = []
    for i, (name, _) in enumerate(episodes):
        if taken.get(name, 0) < args.video_episodes and len(picked) < args.video_max:
            taken[name] = taken.get(name, 0) + 1
            picked.append(i)
    return picked


def main(args: Args) -> dict:
    """Run --policy (and every --compare policy) on the episodes asked for; only once everything has run,
    write DIR/episodes.csv and DIR/summary.json (+ the comparison and the videos) and print a summary."""
    compared = [p.strip() for p in args.compare.split(",")] if args.compare.strip() else []
    if "" in compared:
        raise ValueError(f"--compare {args.compare}: an empty name in the list")
    policies = [args.policy] + compared
    for flag, p in [("--policy", args.policy)] + [("--compare", p) for p in compared]:
        if p not in classical_cpp.PLANNERS and p not in LEARNED and p not in FRONTIER:
            raise ValueError(f"{flag}: unknown policy {p!r}; choose from "
                             f"{sorted(classical_cpp.PLANNERS) + list(LEARNED) + list(FRONTIER)}")
    if len(set(policies)) != len(policies):
        raise ValueError(f"--compare {args.compare}: a policy is listed twice (or is --policy itself)")
    if args.sensor not in gridworld.SENSORS:
        raise ValueError(f"--sensor must be one of {gridworld.SENSORS}, got {args.sensor!r}")
    if args.sensor_range < 1:
        raise ValueError(f"--sensor-range must be >= 1, got {args.sensor_range}")
    if not any(p in LEARNED or p in FRONTIER for p in policies) and (
            args.sensor != "full" or args.sensor_failure or args.faulty_agent_at is not None or args.action_loss):
        raise ValueError("the classical planners plan with full information and no faults; --sensor, "
                         "--sensor-failure, --faulty-agent-at and --action-loss apply to learned and frontier policies")
    for flag, value in (("--workers", args.workers), ("--video-episodes", args.video_episodes),
                        ("--video-max", args.video_max)):
        if value < 1:
            raise ValueError(f"{flag} must be >= 1, got {value}")
    if args.checkpoint and args.policy not in LEARNED:
        raise ValueError(f"--checkpoint is for the learned policies ({', '.join(LEARNED)}), not {args.policy}")
    if args.trainer and args.policy not in ("rainbow", "marl"):
        raise ValueError(f"--trainer is for the policies rainbow and marl, not {args.policy}")
    for flag, folder in (("--out", args.out), ("--video", args.video)):
        if folder is not None and os.path.exists(folder) and not os.path.isdir(folder):
            raise ValueError(f"{flag} {folder}: exists and is not a folder")
    if args.out and os.path.isdir(args.out) and not os.path.exists(os.path.join(args.out, "summary.json")) and any(
            os.path.isfile(os.path.join(args.out, name)) for name in os.listdir(args.out)):  # models/, results/, ...
        raise ValueError(f"--out {args.out}: a folder of other files; name a new folder or an earlier --out")
    for name in ("episodes.csv", "summary.json") + (("compare.json", "compare.md", "compare.png") if compared else ()):
        gridworld.check_output(os.path.join(args.out, name), "result", args.overwrite, "--out")  # before the minutes
    if args.video:
        gridworld.check_output(os.path.join(args.video, "episode.mp4"), "result", True, "--video")  # its folder's kind
    runners = {p: _runner(args if p == args.policy else replace(args, policy=p, checkpoint=None, trainer=None), p)
               for p in policies}  # every check and model load before anything runs
    episodes = scenarios_from(args)
    filmed = _filmed(args, episodes) if args.video else []
    results, paths = {}, {}
    for p, run in runners.items():
        paths[p] = dict.fromkeys(filmed if p == args.policy else [0] if filmed else [])  # compare.png: episode 0
        results[p] = run(episodes, paths[p] or None)
    return _write(args, episodes, results, paths)


def _write(args: Args, episodes: list[tuple[str, Scenario]], results: dict[str, list[dict]],
           paths: dict[str, dict]) -> dict:
    rows, families = results[args.policy], dataset_families(args.dataset)
    label = args.policy
    summary = {"policy": args.policy, "dataset": args.dataset, "maps": list(args.maps),
               "agents": args.agents, "seed": args.seed,
               **summarize(rows, families)}
    files = {os.path.join(args.out, "episodes.csv"): partial(_write_csv, rows=rows),
             os.path.join(args.out, "summary.json"): partial(_write_json, data=summary)}
    lines = [describe(label, rows)]
    if families:
        lines += ["  " + describe(f, of_family(rows, families, f)) for f in summary["by_family"]]
    if len(results) > 1:
        named = {label if p == args.policy else p: r for p, r in results.items()}
        table, text = comparison(named, families)
        files[os.path.join(args.out, "compare.json")] = partial(_write_json, data=table)
        files[os.path.join(args.out, "compare.md")] = partial(_write_text, text=f"# {' vs '.join(named)}\n\n{text}\n")
        lines += ["", text]
    sensed = args.policy in LEARNED or args.policy in FRONTIER
    config = {"sensor": args.sensor, "sensor_range": args.sensor_range} if sensed else None
    for i, cells in paths[args.policy].items():
        name, scenario = episodes[i]
        stem = os.path.join(args.video, f"{i:03d}-" + re.sub(r"[^A-Za-z0-9_-]+", "-", name).strip("-"))
        files[stem + ".mp4"] = partial(_write_video, scenario=scenario, cells=cells, config=config)
        files[stem + ".png"] = partial(gridworld.plot_path, scenario, cells, title=_title(label, name, rows[i]))
    compared = list(results)[1:]
    if paths[args.policy] and compared:
        name, scenario = episodes[0]
        files[os.path.join(args.out, "compare.png")] = partial(
            _write_panels, scenario=scenario, title=f"{name}, start {rows[0]['start']}",
            sides=[(paths[p][0], f"{shown}: overlap {results[p][0]['overlap']:.3f}, {results[p][0]['steps']} steps")
                   for p, shown in ((args.policy, label), *((p, p) for p in compared))])
    _commit(files, args.overwrite, args.quiet)
    print("\n".join(lines))
    print(f"wrote {args.out}" + (f" and {len(paths[args.policy])} videos in {args.video}" if args.video else ""))
    return summary


def _title(policy: str, name: str, row: dict) -> str:
    return f"{policy} on {name}, start {row['start']}\noverlap {row['overlap']:.3f}, {row['steps']} steps"


def _write_csv(path: str, rows: list[dict]) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, COLUMNS + [k for k in OPTIONAL_COLUMNS if rows and k in rows[0]])
        writer.writeheader()
        writer.writerows(rows)


def _write_json(path: str, data: dict) -> None:
    with open(path, "w") as f:
        json.dump(data, f, indent=1)


def _write_text(path: str, text: str) -> None:
    with open(path, "w") as f:
        f.write(text)


def _write_video(path: str, scenario: Scenario, cells, config: dict | None) -> None:
    frames = gridworld.replay_frames(scenario, cells, max(2, VIDEO_PIXELS // max(scenario.obstacles.shape)), config)
    fps = max(10, math.ceil(len(frames) / VIDEO_SECONDS))
    gridworld.write_video(frames + frames[-1:] * fps, path, fps)  # the final coverage stays on screen for a second


def _write_panels(path: str, scenario: Scenario, title: str, sides: list[tuple]) -> None:
    """Every compared policy's path on the same episode, a panel each, with one legend for the marks."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    h, w = scenario.obstacles.shape
    fig, axes = plt.subplots(1, len(sides), figsize=(len(sides) * max(4.0, w / 5), max(4.0, h / 5) + 1.2),
                             squeeze=False)
    for ax, (cells, side) in zip(axes[0], sides):
        gridworld.plot_path(scenario, cells, title=side, ax=ax)
    marks = [Line2D([], [], marker="o", color="tab:green", markeredgecolor="k", linestyle="", label="start"),
             Line2D([], [], marker="s", color="tab:red", markeredgecolor="k", linestyle="", label="end"),
             Line2D([], [], color="tab:blue", linewidth=2, label="path, light to dark in step order"),
             Line2D([], [], marker="s", color=(1.0, 0.85, 0.85), linestyle="", markersize=10, label="covered"),
             Line2D([], [], marker="s", color="k", linestyle="", markersize=10, label="obstacle")]
    fig.legend(handles=marks, loc="lower center", ncol=len(marks), frameon=False)
    fig.suptitle(title)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _commit(files: dict, overwrite: bool, quiet: bool) -> None:
    """Write every file under a temporary name (gridworld's write rule: --overwrite to replace a file outside runs/),
    then rename them all into place: a failure leaves none of them, nor a folder made for them, behind."""
    made = []
    for folder in dict.fromkeys(os.path.dirname(p) for p in files):
        while folder and not os.path.exists(folder) and folder not in made:
            made.append(folder)
            folder = os.path.dirname(folder)
    try:
        with contextlib.ExitStack() as stack:
            temps = {p: stack.enter_context(gridworld.staged_output(p, "result", overwrite, "--out")) for p in files}
            for path, write in _progress(quiet, iterable=files.items(), total=len(files), desc="writing", unit="file"):
                write(temps[path])
    except BaseException:
        for folder in sorted(made, key=len, reverse=True):  # the deepest first, only if left empty
            with contextlib.suppress(OSError):
                os.rmdir(folder)
        raise


if __name__ == "__main__":
    with gridworld.cli_errors():  # Ctrl-C or SIGTERM: one line, 130 / 143; --out is written only at the end, all at once
        main(gridworld.cli(Args, description=__doc__))
