"""Regenerate results/ in three layers: collect runs the experiments and writes results/*.json, render turns
those JSON files into RESULTS.md (a pure function of them: no experiment, clock or git), plot draws the PNG
figures from the same JSON.

    python report.py --overwrite                  # all: collect every part (replacing results/*.json), render, plot
    python report.py all --reuse                  # collect only the parts whose JSON is missing, then render, plot
    python report.py render                       # RESULTS.md from the JSON in results/, nothing re-run
    python report.py plot --out DIR               # the figures from the JSON in DIR
    python report.py collect --parts classical --per-size 2 --out DIR
    python report.py collect --parts structured rollout --structured-per-band 3 --overwrite   # two planner pieces

Parts (JSON under --out): classical (classical_cpp.json: classical_cpp.compare, structured_eval and rollout
included), structured (planners_structured.json: classical_cpp.compare_structured alone), rollout (rollout.json:
classical_cpp.compare_rollout, the rollout planner alone on classical's maps), rainbow_cpp (rainbow_cpp.json),
rainbow_marl (rainbow_marl.json), tabular (tabular/fig5_5.json); a learned part is skipped while its model is
not trained, structured and rollout while classical is collected too (it holds them). Render and plot take
rollout's rows and structured_eval from classical_cpp.json where it has them, else from those two files.
Read when present, not collected here: tabular/fig5_4/*.json (tabular_q.py training runs) and
marl_rewards/*/summary.json (evaluate.py runs; README for both). Each collected JSON records where it was made
under "provenance" (git commit, CPU, cores, torch threads, date, wall time, flags); the models' training is
described by their own JSON (models/*.json), which collect copies in. Every command writes into a temporary
folder beside --out and moves the files in only once everything asked for has succeeded. collect replaces a JSON
already under --out (the committed results/ by default) only with --overwrite; render and plot rewrite RESULTS.md
and the figures, which are functions of that JSON.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Annotated

import numpy as np
import tyro
from tqdm import tqdm

import classical_cpp
import evaluate
import gridworld

ROOT = os.path.dirname(os.path.abspath(__file__))
RESULTS = os.path.join(ROOT, "results")
PARTS = {"classical": "classical_cpp.json", "structured": "planners_structured.json", "rollout": "rollout.json",
         "team_rollout": "team_rollout.json", "sensors": "rainbow_sensors.json",
         "rainbow_cpp": "rainbow_cpp.json", "rainbow_marl": "rainbow_marl.json",
         "tabular": os.path.join("tabular", "fig5_5.json"),
         "scale_references": "rainbow_cpp_scale_references.json", "rainbow_cpp_scale": "rainbow_cpp_scale.json",
         "scale_figures": "rainbow_cpp_scale_figures.json", "td_finetune": "rainbow_cpp_td_finetune.json"}
IN_CLASSICAL = {"structured": "structured_eval", "rollout": "rollout"}  # parts classical_cpp.compare also holds
MODELS = {"rainbow_cpp": evaluate.DEFAULT_CHECKPOINT["rainbow"], "sensors": evaluate.DEFAULT_CHECKPOINT["rainbow"],
          "rainbow_marl": evaluate.DEFAULT_CHECKPOINT["marl"],
          "tabular": evaluate.DEFAULT_CHECKPOINT["tabular"], "scale_references": evaluate.DEFAULT_CHECKPOINT["rainbow"],
          "rainbow_cpp_scale": "models/rainbow_cpp_dissertation_run.pt",  # the scale run's committed training state
          "scale_figures": "models/rainbow_cpp_dissertation.pt",  # its export at the curriculum's end
          "td_finetune": "models/rainbow_cpp_td_finetune_run.pt"}  # the TD fine-tuning's committed training state
SCRIPTS = {"rainbow_cpp": "rainbow_cpp.py", "sensors": "rainbow_cpp.py", "rainbow_marl": "rainbow_marl.py",
           "tabular": "tabular_q.py", "scale_references": "rainbow_cpp.py", "rainbow_cpp_scale": "rainbow_cpp.py",
           "scale_figures": "rainbow_cpp.py", "td_finetune": "rainbow_cpp.py"}
LEARNING_RATE_SWEEP = "learning_rate_sweep.json"  # benchmarks/learning_rate.py's JSON, read when present
LEARNING_RATE_FIG68 = "learning_rate_fig68.json"  # the same with --network fig6.8, read when present
LEARNING_RATE_MARL = "learning_rate_marl.json"  # the same with --trainer rainbow_marl, read when present
SCALE_REFERENCES = ("greedy", "greedy-far-first", "lkh")  # planners drawn beside the scale run's curve (and the model)
TD_REFERENCES = ("greedy-far-first", "rainbow")  # scale_references drawn beside the TD fine-tuning's curve
# docs/experiments.md's fresh per-family maps: map k of size z of the f-th family drawn with seed
# FRESH_SEED + 10,000 f + 100 k + z (no dataset or training uses these seeds), FRESH_OBSTACLES of the cells requested
FRESH_SEED, FRESH_PER_SIZE, FRESH_SIZES, FRESH_OBSTACLES = 500_000, 8, range(10, 30), 0.15
FIGURES_PER_SIZE, FIGURES_BOX_SIZES = 100, (5, 10, 15, 20, 25, 30)  # Figs. 6.13-6.16: all of cpp_eval; the box plots' sizes
ALGORITHM_NAMES = {"q-learning": "Q-learning", "sarsa": "SARSA", "double-q": "Double Q-learning",
                   "watkins": "Watkins's Q(λ)"}  # tabular_q.py --algorithm, as the figure's title names it
CH5_EVAL = os.path.join("maps", "ch5_eval.npz")  # Fig. 5.5's maps, with their size and requested obstacles
CAMERA_RANGE = 3  # the sensor-based evaluation of the rainbow_cpp model (§6.5.3)
SENSOR_RANGES, SENSOR_FAILURES = (1, 2, 3, 4, 5), (0.25, 0.5)  # Figs. 6.20-6.21 (K) and 6.22 (camera r = 3)
SENSOR_POLICIES = ("rainbow", "frontier", "frontier-row-major", "frontier-far-first")  # the agent, the baselines
SENSOR_PER_SIZE, SENSOR_PER_BAND = 2, 1  # the sensors part: 52 cpp_eval maps, 16 structured_eval maps
MOVINGAI_PLANNERS = ("greedy", "greedy-dead-ends", "wavefront", "rollout", "lkh")  # beside the agent, where collected
MARL_EVERY, MARL_AGENTS = 10, range(1, 16)  # rainbow_marl: every 10th marl_eval layout, N = 1..15 (Fig. 7.11)
MARL_PLANNERS = ("greedy", "greedy-dead-ends", "greedy-far-first", "partition")  # beside rainbow_marl, with claims
FAULTY_AT, FAULTY_AGENTS = 0.5, (2, 5, 10)  # §7.5.3.3: the last agent freezes halfway
MARL_STRUCTURED_EVERY, MARL_STRUCTURED_AGENTS = 21, range(2, 11)  # rainbow_marl on structured_eval: 80 maps, N = 2..10
REWARD_BASELINES = ("greedy", "pretrained")  # results/marl_rewards/: these first, then one folder a training run
T_975 = {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571, 6: 2.447, 7: 2.365, 8: 2.306, 9: 2.262}  # Student's t
FIGURES = {"planners_by_size": "planners_overlap_by_size.png", "planners_external": "planners_external.png",
           "planners_structured": "planners_structured.png", "marl_baselines": "marl_baselines.png",
           "rainbow_cpp": "rainbow_overlap_by_size.png", "sensors": "rainbow_sensors.png",
           "rainbow_marl": "rainbow_marl_time_save.png", "fig5_4": "tabular_fig5_4.png", "fig5_5": "tabular_fig5_5.png",
           "rainbow_cpp_scale": "rainbow_cpp_scale.png", "scale_figures": "rainbow_cpp_scale_figures.png",
           "td_finetune": "rainbow_cpp_td_finetune.png"}
# The numbers the report holds the results against, each with its source; no other number in the text is typed.
REFERENCE = {
    # Table 5.1: training time (s) of 100,000 episodes on 6x6, columns (heuristic, 0 obstacles), (heuristic, 1),
    # (no heuristic, 0), (no heuristic, 1); and the machine it was measured on
    "table_5_1_seconds": {"q-learning": (491.1, 492.2, 571.5, 698.9), "sarsa": (615.8, 529.7, 688.9, 791.7),
                          "double-q": (477.8, 498.4, 1521.5, 1993.6), "watkins": (985.1, 1448.0, 2285.9, 6934.1)},
    "table_5_1_machine": "AMD Ryzen 7 5800H, one episode at a time",
    "fig_5_5_episodes": 17_500_000,  # Fig. 5.5: training episodes of the dissertation's table
    "fig_5_5_maps": 1000,  # Fig. 5.5: evaluation maps per (size, obstacles) setting
    "rho_perfect": 1,  # §5.4.1: ρ of a perfect sweep
    # the repository's acceptance targets for the learned agents (issues #5 and #7)
    "rainbow_cpp_sizes": (5, 20), "rainbow_cpp_completion": 1.0, "rainbow_cpp_overlap": 0.05,
    "rainbow_marl_time_save": {"2": 0.53, "5": 0.30, "10": 0.15},  # mean t_sf on marl_eval
    # §6.5.2: mean overlap below 0.05 at every size (Figs. 6.13, 6.15), completion 100% with the fallback; without it
    # (Fig. 6.16) completion 99.3% and 97.4% of the episodes no outlier (overlap > 0.5 or truncated)
    "fig_6_15_overlap": 0.05, "fig_6_16_completion": 0.993, "fig_6_16_favourable": 0.974, "outlier_overlap": 0.5,
}
NOT_COLLECTED = ("*Not collected:* no `{file}` here; `python report.py collect --parts {part}` fills it in "
                 "once `{model}` is trained (`{script}`).")


# ----------------------------------------------------------------------------- reading and writing
def read_json(path: str) -> dict:
    """A JSON object from `path`; ValueError naming the file if it cannot be read or is not one."""
    try:
        with open(path) as f:
            data = json.load(f)
    except OSError as e:
        raise ValueError(f"{path}: cannot read ({e.strerror})") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: not a JSON file ({e})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: not a JSON object")
    return data


@contextmanager
def reading(path: str):
    """Turn a results JSON that lacks an entry or holds the wrong kind of value into a ValueError naming it."""
    try:
        yield
    except (KeyError, TypeError, IndexError, AttributeError, ValueError, ZeroDivisionError) as e:
        raise ValueError(f"{path}: unexpected content ({type(e).__name__}: {e})") from None


@contextmanager
def staged(out: str, overwrite: bool = False):
    """A temporary folder beside `out`; its files replace those of `out` only if the block succeeds and every one
    passes gridworld's write rule (a results JSON there already is replaced only with `overwrite`)."""
    if os.path.exists(out) and not os.path.isdir(out):
        raise ValueError(f"--out {out}: not a folder")
    parent = os.path.dirname(os.path.abspath(out))
    while not os.path.isdir(parent):  # the nearest folder there is, so a failing run creates none
        parent = os.path.dirname(parent)
    try:
        tmp = tempfile.mkdtemp(prefix=".report-", dir=parent)
    except OSError as e:
        raise ValueError(f"--out {out}: cannot write ({e.strerror})") from None
    try:
        yield tmp
        written = [os.path.relpath(os.path.join(d, n), tmp) for d, _, files in os.walk(tmp) for n in files]
        for rel in written:  # gridworld's write rule; RESULTS.md and the figures are derived, remade by their command
            gridworld.check_output(os.path.join(out, rel), "result", overwrite or rel.endswith((".md", ".png")), "--out")
        for rel in written:
            os.makedirs(os.path.dirname(os.path.join(out, rel)), exist_ok=True)
            os.replace(os.path.join(tmp, rel), os.path.join(out, rel))
    except OSError as e:
        raise ValueError(f"--out {out}: cannot write ({e.strerror})") from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def load_results(*folders: str) -> dict:
    """Every results JSON there is, each from the first of `folders` holding it: the parts (None where missing),
    the tabular training runs of Fig. 5.4 and the reward-structure evaluations, and the path of each."""
    def find(rel):
        return next((os.path.join(f, rel) for f in folders if os.path.exists(os.path.join(f, rel))), None)

    results = {"paths": {part: find(rel) for part, rel in PARTS.items()}}
    if results["paths"]["classical"] is None:
        raise ValueError(f"{folders[-1]}: no {PARTS['classical']}; run `python report.py collect --out {folders[-1]}`")
    for part, path in results["paths"].items():
        results[part] = None if path is None else read_json(path)
    for key, name in (("learning_rate", LEARNING_RATE_SWEEP), ("learning_rate_fig68", LEARNING_RATE_FIG68),
                      ("learning_rate_marl", LEARNING_RATE_MARL)):
        results["paths"][key] = find(name)
        results[key] = None if results["paths"][key] is None else read_json(results["paths"][key])
    runs = find(os.path.join("tabular", "fig5_4"))
    results["paths"]["fig5_4"] = runs
    results["fig5_4"] = {} if runs is None else {
        name: read_json(os.path.join(runs, name)) for name in sorted(os.listdir(runs)) if name.endswith(".json")}
    names = sorted({n for f in folders if os.path.isdir(os.path.join(f, "marl_rewards"))
                    for n in os.listdir(os.path.join(f, "marl_rewards"))}, key=lambda n: (n not in REWARD_BASELINES, n))
    results["marl_rewards"] = {}
    for name in names:  # each an evaluate.py summary.json, and the trained model's own JSON (model.json) beside it
        path, model = find(os.path.join("marl_rewards", name, "summary.json")), None
        if path is not None:
            if os.path.exists(os.path.join(os.path.dirname(path), "model.json")):
                model = read_json(os.path.join(os.path.dirname(path), "model.json"))
            results["marl_rewards"][name] = {**read_json(path), **({"model": model} if model else {})}
    return results


# ----------------------------------------------------------------------------- collect
def _git(*args: str) -> str | None:
    try:
        r = subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.SubprocessError):
        return None
    return r.stdout.strip() if r.returncode == 0 else None


def _cpu() -> str | None:
    try:
        with open("/proc/cpuinfo") as f:
            names = [ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")]
    except OSError:
        return None
    return names[0] if names else None


def provenance(started: float, args: Collect) -> dict:
    """Where and how a results JSON was collected: the code, the machine, the date, the wall time, the flags."""
    torch = sys.modules.get("torch")  # imported only by the learned parts
    commit = _git("rev-parse", "HEAD")
    return {"git_commit": commit,
            "git_dirty": None if commit is None else bool(_git("status", "--porcelain", "--untracked-files=no")),
            "cpu": _cpu(), "cores": os.cpu_count(), "torch_threads": torch.get_num_threads() if torch else None,
            "torch_version": torch.__version__ if torch else None, "numpy_version": np.__version__,
            "date": datetime.now(UTC).isoformat(timespec="seconds"),
            "wall_seconds": round(time.time() - started, 1),
            "flags": {k: v for k, v in dataclasses.asdict(args).items() if k not in ("out", "quiet", "overwrite")}}


def _bar(total: int, desc: str, quiet: bool) -> tqdm:
    return tqdm(total=total, desc=desc, unit="run", disable=quiet or not sys.stdout.isatty())


def _model_json(model: str) -> dict:
    return read_json(os.path.splitext(model)[0] + ".json")


def rainbow_results(per_size: int, p2p_maps: int, model: str, quiet: bool = False) -> dict:
    """A rainbow_cpp model on cpp_eval (full information with and without the heuristic fallback, camera),
    p2p_eval, the MovingAI maps and the planners' structured_eval subset (per family); the greedy planners per size
    beside it."""
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

    result = {"per_size": per_size, "camera_range": CAMERA_RANGE, "model": _model_json(model)}
    bound = {}  # the overlap of the shortest walk classical_cpp.lower_bound allows, by size: no walk goes below it
    for (_, s), z in zip(episodes, sizes):
        poi = int((~s.obstacles & ~s.covered).sum())
        bound.setdefault(str(z), []).append((classical_cpp.lower_bound(s) - poi) / max(poi, 1))
    result["lower_bound"] = {z: round(float(np.mean(v)), 4) for z, v in bound.items()}
    with _bar(9, "rainbow_cpp", quiet) as bar:
        for key, kw in (("full", {}), ("full_no_heuristic", {"heuristic": False}),
                        (f"camera_r{CAMERA_RANGE}", {"sensor": "camera", "sensor_range": CAMERA_RANGE})):
            result[key] = by_size(evaluate.run_rainbow(evaluate.Args(policy="rainbow", checkpoint=model, quiet=quiet, **kw),
                                                       episodes))
            bar.update()
        result["greedy"] = by_size(evaluate.run_planner("greedy", episodes))
        bar.update()
        result["greedy_dead_ends"] = by_size(evaluate.run_planner("greedy-dead-ends", episodes))
        bar.update()
        result["greedy_far_first"] = by_size(evaluate.run_planner("greedy-far-first", episodes))
        result["greedy_far_first_external"] = {}
        for row in evaluate.run_planner("greedy-far-first", classical_cpp.external_episodes()):
            result["greedy_far_first_external"].setdefault(row["map"], []).append(row["overlap"])
        bar.update()
        result["p2p"] = rainbow_p2p(evaluate.Args(policy="rainbow", checkpoint=model, quiet=quiet), p2p_maps)
        bar.update()
        result["external"] = rainbow_external(evaluate.Args(policy="rainbow", checkpoint=model, quiet=quiet))
        bar.update()
        episodes, families = structured_episodes()
        rows = evaluate.run_rainbow(evaluate.Args(policy="rainbow", checkpoint=model, quiet=quiet), episodes)
        result["structured_eval"] = by_family(rows, families)
        result["greedy_far_first_structured"] = by_family(evaluate.run_planner("greedy-far-first", episodes), families)
        bar.update()
    return result


def rainbow_p2p(args: evaluate.Args, maps: int) -> dict:
    """A rainbow_cpp model on the first `maps` p2p_eval scenarios: how often it walks a shortest path, completion and
    the mean steps past a shortest path."""
    p2p = evaluate.scenarios_from(evaluate.Args(dataset=os.path.join(ROOT, "maps", "p2p_eval.npz"), limit=maps))
    shortest = [r["steps"] for r in evaluate.run_planner("greedy", p2p)]  # one target: greedy walks a shortest path
    rows = evaluate.run_rainbow(args, p2p)
    return {"maps": len(p2p), "optimal": round(float(np.mean([r["steps"] == b for r, b in zip(rows, shortest)])), 4),
            "completion": round(float(np.mean([r["completed"] for r in rows])), 4),
            "mean_extra_steps": round(float(np.mean([r["steps"] - b for r, b in zip(rows, shortest)])), 3)}


def rainbow_external(args: evaluate.Args) -> dict:
    """A rainbow_cpp model's overlaps on the MovingAI episodes, by map."""
    result = {}
    for row in evaluate.run_rainbow(args, classical_cpp.external_episodes()):
        result.setdefault(row["map"], []).append(row["overlap"])
    return result


def structured_episodes() -> tuple[list[tuple[str, gridworld.Scenario]], list[str]]:
    """The planners' structured_eval subset as episodes, and each one's family."""
    scenarios, families, _ = classical_cpp.structured_eval_subset(classical_cpp.STRUCTURED_PER_BAND)
    return [(f"structured_eval.npz[{f}]", s) for s, f in zip(scenarios, families)], list(families)


def by_family(rows: list[dict], families: list[str]) -> dict:
    """family_stats of some episodes by family and over all."""
    return {f: family_stats([r for r, g in zip(rows, families) if g == f]) for f in dict.fromkeys(families)} | {
        "all": family_stats(rows)}


def checkpoint_record(path: str, state: dict) -> dict:
    """Which training checkpoint a result comes from: its path, hash, steps and stage."""
    with open(path, "rb") as f:
        digest = hashlib.sha256(f.read()).hexdigest()
    return {"path": os.path.relpath(path, ROOT), "sha256": digest, "global_step": state.get("global_step"),
            "stage": state.get("stage")}


def model_record(path: str) -> dict:
    """checkpoint_record of a training checkpoint, or of an export with the steps and stage of the JSON beside it."""
    state = gridworld.read_model(path)
    return checkpoint_record(path, state if "global_step" in state else _model_json(path))


def scale_references(model: str, quiet: bool = False) -> dict:
    """The references of the scale run's learning curve on its own held-out maps (gridworld.curve_maps): the
    dissertation's heuristic with deterministic ties (greedy), greedy-far-first, LKH and the shipped model with its
    fallback; per set the mean overlap and completion, for cpp_eval also by size."""
    result = {"model": _model_json(model), "slices": gridworld.CURVE_SLICES}
    maps = gridworld.curve_maps()
    with _bar(len(maps) * (len(SCALE_REFERENCES) + 1), "scale references", quiet) as bar:
        for name, scenarios in maps.items():
            episodes = [(f"{name}.npz[{i}]", classical_cpp.with_starts(s)) for i, s in enumerate(scenarios)]
            sizes = [s.obstacles.shape[0] for s in scenarios]
            result[name] = {}
            for policy in (*SCALE_REFERENCES, "rainbow"):
                rows = (evaluate.run_rainbow(evaluate.Args(policy="rainbow", checkpoint=model, quiet=quiet), episodes)
                        if policy == "rainbow" else evaluate.run_planner(policy, episodes))
                row = {"overlap": round(float(np.mean([r["overlap"] for r in rows])), 4),
                       "completion": round(float(np.mean([r["completed"] for r in rows])), 4)}
                if name == "cpp_eval":
                    row["overlap_by_size"] = {str(z): round(float(np.mean([r["overlap"] for r, y in zip(rows, sizes)
                                                                           if y == z])), 4) for z in sorted(set(sizes))}
                result[name][policy] = row
                bar.update()
    return result


def scale_curve(checkpoint: str) -> dict:
    """A run's learning curve and flags, read from its training checkpoint (rainbow_cpp.py --curve-every keeps the
    curve in it), with the checkpoint's steps, stage, wall time and hash, and the model a warm-started run began from."""
    state = gridworld.load_checkpoint(checkpoint, "rainbow_cpp")
    record = checkpoint_record(checkpoint, state)
    parent = state.get("parent")  # --init-from's record; the scale run, from scratch, has none
    return {"checkpoint": record.pop("path"), **record, "wall_seconds": round(state["wall"]), "args": state["args"],
            **({"parent": {k: parent.get(k) for k in ("path", "sha256", "global_step")}} if parent else {}),
            "curve": json.loads(json.dumps(state.get("curve", [])))}  # as JSON keeps it (its keys strings)


def scale_figures(model: str, p2p_maps: int, quiet: bool = False) -> dict:
    """Figs. 6.13-6.16 of the scale run's model: every cpp_eval map (FIGURES_PER_SIZE a size, their first start) with
    the fallback (the dissertation's heuristic, deterministic ties) and without it; per size every episode's overlap,
    whether it completed and whether it was truncated. Then, with the fallback, the report's structured_eval subset,
    the MovingAI episodes and p2p_eval, as the rainbow_cpp part measures the shipped model."""
    scenarios, sizes = classical_cpp.cpp_eval_subset(FIGURES_PER_SIZE)
    episodes = [(f"cpp_eval.npz[{z}x{z}]", classical_cpp.with_starts(s)) for s, z in zip(scenarios, sizes)]
    result = {"model": model_record(model), "per_size": FIGURES_PER_SIZE}
    for key, fallback in (("fallback", True), ("alone", False)):
        rows = evaluate.run_rainbow(evaluate.Args(policy="rainbow", checkpoint=model, heuristic=fallback,
                                                  heuristic_dead_ends=False, quiet=quiet), episodes)
        result[key] = {str(z): {k: [r[k] for r, y in zip(rows, sizes) if y == z]
                                for k in ("overlap", "completed", "truncated")} for z in dict.fromkeys(sizes.tolist())}
    args = evaluate.Args(policy="rainbow", checkpoint=model, heuristic_dead_ends=False, quiet=quiet)
    episodes, families = structured_episodes()
    return result | {"structured_eval": by_family(evaluate.run_rainbow(args, episodes), families),
                     "external": rainbow_external(args), "p2p": rainbow_p2p(args, p2p_maps)}


def structured_eval_episodes() -> tuple[list[tuple[str, gridworld.Scenario]], list[str]]:
    """Every structured_eval map from its first stored start, as `evaluate.py --dataset maps/structured_eval.npz` runs
    them, and each one's family."""
    path = os.path.join(ROOT, "maps", "structured_eval.npz")
    with np.load(path) as data:
        families = data["family"].tolist()
    return evaluate.scenarios_from(evaluate.Args(dataset=path)), families


def fresh_episodes() -> tuple[list[tuple[str, gridworld.Scenario]], list[str]]:
    """docs/experiments.md's fresh per-family maps (FRESH_SEED's recipe), FRESH_PER_SIZE maps of each size in
    FRESH_SIZES for random and each of gridworld.STRUCTURED_FAMILIES, each from its drawn start; and their families."""
    families = ("random", *gridworld.STRUCTURED_FAMILIES)
    keys = [(f, k, z) for f in range(len(families)) for k in range(FRESH_PER_SIZE) for z in FRESH_SIZES]
    episodes = [(f"fresh[{families[f]}]", classical_cpp.with_starts(gridworld.generate_scenarios(
        1, seed=FRESH_SEED + 10_000 * f + 100 * k + z, size=z, map_family=families[f],
        number_obstacles=int(FRESH_OBSTACLES * z * z), obstacles_random=True)[0])) for f, k, z in keys]
    return episodes, [families[f] for f, _, _ in keys]


def td_finetune_results(checkpoint: str, shipped: str, quiet: bool = False) -> dict:
    """The TD fine-tuning of the shipped model: its learning curve (scale_curve), then the greedy network of its
    committed checkpoint beside the shipped model (each with the fallback, and alone) and greedy-far-first on all of
    structured_eval and on the fresh per-family maps; by_family of each, per set."""
    result = scale_curve(checkpoint) | {
        "slices": gridworld.CURVE_SLICES, "shipped": checkpoint_record(shipped, _model_json(shipped)),
        "fresh_recipe": {"seed": FRESH_SEED, "per_size": FRESH_PER_SIZE, "sizes": [FRESH_SIZES[0], FRESH_SIZES[-1]],
                         "obstacles": FRESH_OBSTACLES}}
    models = {"fine_tuned": checkpoint, "shipped": shipped}
    sets = {"structured_eval": structured_eval_episodes(), "fresh": fresh_episodes()}
    with _bar(len(sets) * (2 * len(models) + 1), "td_finetune", quiet) as bar:
        for name, (episodes, families) in sets.items():
            result[name] = {"maps": {f: families.count(f) for f in dict.fromkeys(families)}}
            for key, model in models.items():
                for suffix, fallback in (("", True), ("_alone", False)):
                    args = evaluate.Args(policy="rainbow", checkpoint=model, heuristic=fallback, quiet=quiet)
                    result[name][key + suffix] = by_family(evaluate.run_rainbow(args, episodes), families)
                    bar.update()
            result[name]["greedy_far_first"] = by_family(evaluate.run_planner("greedy-far-first", episodes), families)
            bar.update()
    return result


def family_stats(rows: list[dict]) -> dict:
    """Mean overlap, completion and heuristic share of some episodes."""
    return dict(overlap=round(float(np.mean([r["overlap"] for r in rows])), 4),
                completion=round(float(np.mean([r["completed"] for r in rows])), 4),
                heuristic_share=round(float(np.mean([r["heuristic_steps"] / max(r["steps"], 1) for r in rows])), 4))


def sensor_settings() -> dict[str, dict]:
    """The sensors part's settings: full information, camera and LiDAR at each of SENSOR_RANGES, and camera r = 3
    under each of SENSOR_FAILURES; key -> evaluate.Args fields."""
    out = {"full": {}}
    for sensor in ("camera", "lidar"):
        out |= {f"{sensor}_r{k}": {"sensor": sensor, "sensor_range": k} for k in SENSOR_RANGES}
    out |= {f"camera_r{CAMERA_RANGE}_failure{round(100 * f)}": {"sensor": "camera", "sensor_range": CAMERA_RANGE,
                                                              "sensor_failure": f} for f in SENSOR_FAILURES}
    return out


def sensor_results(model: str, per_size: int = SENSOR_PER_SIZE, per_band: int = SENSOR_PER_BAND,
                   quiet: bool = False) -> dict:
    """Figs. 6.17-6.22: a rainbow_cpp model (heuristic fallback on) beside the frontier baselines of evaluate.py under
    every sensor_settings() setting, on the first `per_size` cpp_eval maps of each size and `per_band` structured_eval
    maps per family and size band: mean overlap, completion and heuristic share, per size band on cpp_eval and per
    family on structured_eval."""
    scenarios, sizes = classical_cpp.cpp_eval_subset(per_size)
    cpp = [(f"cpp_eval.npz[{z}x{z}]", classical_cpp.with_starts(s)) for s, z in zip(scenarios, sizes)]
    scenarios, families, _ = classical_cpp.structured_eval_subset(per_band)
    structured = [(f"structured_eval.npz[{f}]", s) for s, f in zip(scenarios, families)]

    def summary(rows, groups):
        out = family_stats(rows)
        out["by"] = {k: family_stats([r for r, key in zip(rows, groups) if key == k]) for k in dict.fromkeys(groups)}
        return out

    bands = [next(f"{a}-{b}" for a, b in classical_cpp.REPORT_BANDS if a <= z <= b) for z in sizes]
    result = {"per_size": per_size, "per_band": per_band, "model": _model_json(model), "cpp_eval": {},
              "structured_eval": {}}
    settings = sensor_settings()
    with _bar(len(settings) * len(SENSOR_POLICIES), "sensors", quiet) as bar:
        for key, kw in settings.items():
            for policy in SENSOR_POLICIES:
                args = evaluate.Args(policy=policy, checkpoint=model if policy == "rainbow" else None, quiet=True, **kw)
                run = evaluate.run_rainbow if policy == "rainbow" else evaluate.run_frontier
                for name, episodes, groups in (("cpp_eval", cpp, bands), ("structured_eval", structured, families)):
                    result[name].setdefault(key, {})[policy] = summary(run(args, episodes), list(groups))
                bar.update()
    return result


def marl_results(model: str, quiet: bool = False, every: int = MARL_EVERY, agents=MARL_AGENTS,
                 structured_every: int = MARL_STRUCTURED_EVERY) -> dict:
    """A rainbow_marl model on marl_eval (every `every`-th layout of sizes 10-30) with N = `agents` and on every
    `structured_every`-th structured_eval map with N = MARL_STRUCTURED_AGENTS, beside MARL_PLANNERS (the greedy
    planners with claims and partition), and the faulty-agent experiment of §7.5.3.3 at N = FAULTY_AGENTS."""
    result = {"every": every, "faulty_at": FAULTY_AT, "model": _model_json(model), "agents": {}, "faulty": {}}

    def mean(rows, key):
        return round(float(np.mean([r[key] for r in rows])), 4)

    result["structured_eval"] = {"every": structured_every, "agents": {}}
    for n in tqdm(MARL_STRUCTURED_AGENTS, desc="rainbow_marl structured", disable=quiet or not sys.stdout.isatty()):
        episodes = evaluate.scenarios_from(evaluate.Args(dataset=os.path.join(ROOT, "maps/structured_eval.npz"),
                                                         agents=n, every=structured_every))
        rows = evaluate.run_marl(evaluate.Args(policy="marl", checkpoint=model, agents=n, quiet=quiet), episodes)
        result["structured_eval"]["maps"] = len(episodes)
        result["structured_eval"]["agents"][str(n)] = {
            "time_save": mean(rows, "time_save"), "completion": mean(rows, "completed")} | {
            p.replace("-", "_"): mean(evaluate.run_planner(p, episodes), "time_save") for p in MARL_PLANNERS}

    for n in tqdm(agents, desc="rainbow_marl", disable=quiet or not sys.stdout.isatty()):
        scenarios, sizes = classical_cpp.marl_eval_subset(n, every)
        episodes = [(f"marl_eval.npz[{z}x{z}]", s) for s, z in zip(scenarios, sizes)]
        rows = evaluate.run_marl(evaluate.Args(policy="marl", checkpoint=model, agents=n, quiet=quiet), episodes)
        result["agents"][str(n)] = {
            "maps": len(rows), "time_save": mean(rows, "time_save"), "completion": mean(rows, "completed"),
            "heuristic_share": round(float(np.mean([r["heuristic_steps"] / (n * r["steps"]) for r in rows])), 4)} | {
            p.replace("-", "_"): mean(evaluate.run_planner(p, episodes), "time_save") for p in MARL_PLANNERS} | {
            "by_size": {str(z): mean([r for r, k in zip(rows, sizes) if k == z], "time_save") for z in np.unique(sizes)}}
        if n in FAULTY_AGENTS:
            faulty = evaluate.run_marl(evaluate.Args(policy="marl", checkpoint=model, agents=n, faulty_agent_at=FAULTY_AT,
                                                     quiet=quiet), episodes)
            reachable = [r for r in faulty if not r["walled_off"]]
            result["faulty"][str(n)] = {"time_save": mean(faulty, "time_save"), "completion": mean(faulty, "completed"),
                                        "walled_off": len(faulty) - len(reachable),
                                        "completion_reachable": mean(reachable, "completed") if reachable else None,
                                        "time_save_reachable": mean(reachable, "time_save") if reachable else None}
    return result


def tabular_results(model: str, quiet: bool = False) -> dict:
    """Fig. 5.5: a tabular_q table (greedy, heuristic on, lidar map) on ch5_eval, mean ρ per (size, requested
    obstacles); beside it the untrained table (every state never seen: a random move toward an uncovered
    neighbour, the heuristic at dead ends)."""
    import tabular_q
    path = os.path.join(ROOT, CH5_EVAL)
    data, scenarios = np.load(path), gridworld.load_dataset(path)
    trained = tabular_q.QTable.load(model)
    result = {"model": {k: v for k, v in _model_json(model).items() if k != "curve_rho"}, "settings": []}
    rho = {name: tabular_q.evaluate_table(t, scenarios, sensor="lidar", quiet=quiet)["rho"]  # each with its own bar
           for name, t in (("trained", trained), ("untrained", tabular_q.QTable(trained.memory, trained.sensor_range)))}
    for size, obstacles in sorted({(int(a), int(b)) for a, b in zip(data["size"], data["requested_obstacles"])}):
        pick = (data["size"] == size) & (data["requested_obstacles"] == obstacles)
        result["settings"].append(dict(size=size, obstacles=obstacles, maps=int(pick.sum()),
                                       **{name: round(float(r[pick].mean()), 4) for name, r in rho.items()}))
    return result


def parts_to_collect(args: Collect) -> list[str]:
    """The parts `args` asks for, after checking its flags: with --reuse only those whose JSON is missing under
    --out, and never a learned part whose model is not trained. A part whose JSON is there needs --overwrite."""
    unknown = [p for p in args.parts if p not in PARTS]
    if unknown:
        raise ValueError(f"--parts: unknown part(s) {', '.join(unknown)}; choose from {', '.join(PARTS)}")
    if args.per_size < 1:
        raise ValueError(f"--per-size must be >= 1, got {args.per_size}")
    if args.p2p_maps < 1:
        raise ValueError(f"--p2p-maps must be >= 1, got {args.p2p_maps}")
    if args.structured_per_band < 1:
        raise ValueError(f"--structured-per-band must be >= 1, got {args.structured_per_band}")
    todo = []
    for part in dict.fromkeys(args.parts):
        if args.reuse and (os.path.exists(os.path.join(args.out, PARTS[part])) or _in_classical(args.out, part)):
            continue
        if part in IN_CLASSICAL and "classical" in args.parts and not (
                args.reuse and os.path.exists(os.path.join(args.out, PARTS["classical"]))):
            print(f"{part}: collected with classical (into {PARTS['classical']})")
            continue
        if part in MODELS and not os.path.exists(os.path.join(ROOT, MODELS[part])):
            print(f"{part}: skipped, {MODELS[part]} is not trained yet")
            continue
        todo.append(part)
    present = [PARTS[part] for part in todo if os.path.exists(os.path.join(args.out, PARTS[part]))]
    if present and not args.overwrite:
        raise ValueError(f"--out {args.out} already holds {', '.join(present)}: --overwrite replaces "
                         f"{'it' if len(present) == 1 else 'them'}, --reuse keeps {'it' if len(present) == 1 else 'them'}"
                         ", or give another --out")
    return todo


def _in_classical(out: str, part: str) -> bool:
    """Whether OUT/classical_cpp.json already holds what part `part` collects (structured_eval, or rollout)."""
    path = os.path.join(out, PARTS["classical"])
    if part not in IN_CLASSICAL or not os.path.exists(path):
        return False
    c = read_json(path)
    return "structured_eval" in c if part == "structured" else "rollout" in (c.get("cpp_eval") or {})


def collect(args: Collect, staging: str) -> list[str]:
    """Run the parts asked for and write their JSON, each with its provenance, under `staging`."""
    written = []
    for part in parts_to_collect(args):
        started = time.time()
        model = os.path.join(ROOT, MODELS.get(part, ""))
        if part == "classical":
            result = classical_cpp.compare(args.per_size, args.quiet, args.structured_per_band)
        elif part == "structured":
            result = {"structured_eval": classical_cpp.compare_structured(args.structured_per_band, args.quiet)}
        elif part == "rollout":
            result = classical_cpp.compare_rollout(args.per_size, args.quiet)
        elif part == "team_rollout":
            result = classical_cpp.compare_team_rollout(quiet=args.quiet)
        elif part == "sensors":
            result = sensor_results(model, quiet=args.quiet)
        elif part == "rainbow_cpp":
            result = rainbow_results(args.per_size, args.p2p_maps, model, args.quiet)
        elif part == "rainbow_marl":
            result = marl_results(model, args.quiet, MARL_EVERY, MARL_AGENTS, MARL_STRUCTURED_EVERY)
        elif part == "scale_references":
            result = scale_references(model, args.quiet)
        elif part == "rainbow_cpp_scale":
            result = scale_curve(model)
        elif part == "scale_figures":
            result = scale_figures(model, args.p2p_maps, args.quiet)
        elif part == "td_finetune":
            result = td_finetune_results(model, os.path.join(ROOT, MODELS["rainbow_cpp"]), args.quiet)
        else:
            result = tabular_results(model, args.quiet)
        result["provenance"] = provenance(started, args)
        written.append(gridworld.write_json(os.path.join(staging, PARTS[part]), result, "result", overwrite=True,
                                            allow_nan=True))  # NaN: a statistic of no episodes
        print(f"{part}: collected in {time.time() - started:.0f} s -> {os.path.join(args.out, PARTS[part])}", flush=True)
    return written


# ----------------------------------------------------------------------------- render (pure)
def table(header: list[str], rows: list[list[str]]) -> str:
    return "\n".join(["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
                     + ["| " + " | ".join(r) + " |" for r in rows])


def recorded(value, fmt: str = "{}") -> str:
    return "not recorded" if value is None or value == "" else fmt.format(value)


def _commit(p: dict) -> str:
    if not p.get("git_commit"):
        return "not recorded"
    return f"{p['git_commit'][:7]}" + (" (with uncommitted changes)" if p.get("git_dirty") else "")


def _flags(flags) -> str:
    if not flags:
        return "not recorded"
    out = []
    for k, v in flags.items():
        name = "--" + k.replace("_", "-")
        if isinstance(v, bool):
            out.append(name if v else "--no-" + k.replace("_", "-"))
        else:
            out.append(f"{name} {' '.join(map(str, v)) if isinstance(v, list) else v}")
    return "`" + " ".join(out) + "`"


def _sizes(keys) -> str:
    """'a-b' of size keys such as '10' or '10x10'."""
    sizes = sorted(int(str(k).split("x")[0]) for k in keys)
    return f"{sizes[0]}-{sizes[-1]}"


def _ordinal(n: int) -> str:
    return f"{n}{'th' if 10 <= n % 100 <= 20 else {1: 'st', 2: 'nd', 3: 'rd'}.get(n % 10, 'th')}"


def _provenance(m: dict) -> dict:
    """A model JSON's provenance: under `provenance` (the rainbow trainers) or at the top level (tabular_q)."""
    return m.get("provenance") or {k: m[k] for k in ("git_commit", "git_dirty", "cpu", "cores", "date") if k in m}


def lineage(parent) -> str:
    """The warm-start chain of a model from its JSON's `parent` (the trainer's record of the model it started
    from, holding that model's own `parent`), nearest first."""
    links = []
    while isinstance(parent, dict):
        facts = [f"sha256 {parent['sha256'][:12]}" if parent.get("sha256") else None,
                 f"{parent['global_step']:,} steps" if isinstance(parent.get("global_step"), int) else None,
                 f"last stage {parent['stage']}" if parent.get("stage") else None,
                 f"git commit {_commit(_provenance(parent))}"]
        links.append(f"`{recorded(parent.get('path'))}` ({', '.join(f for f in facts if f)})")
        parent = parent.get("parent")
    if parent:
        links.append(str(parent))
    return " ← ".join(links)


def trained_on(m: dict, torch: bool = True) -> str:
    """Where a model was trained, from its JSON: the trainer's provenance, else the older keys, else not recorded;
    then its parent and the trainer's note on it."""
    p = _provenance(m)
    parts = [f"machine: {recorded(p.get('cpu') or m.get('machine'))}" + (f" ({p['cores']} cores)" if p.get("cores") else "")]
    if torch:
        parts.append(f"torch threads: {recorded(p.get('torch_threads', m.get('torch_threads')))}")
    parts += [f"git commit: {_commit(p)}", f"date: {recorded(p.get('date'))}"]
    line = "Trained on " + "; ".join(parts) + "."
    if m.get("parent"):
        line += f" Parent: {lineage(m['parent'])}."
    if "init_from_note" in m:
        line += f" Training: {m['init_from_note']}."
    return line


def _wall(m: dict) -> float | None:
    return (m.get("provenance") or {}).get("wall_seconds", m.get("wall_seconds"))


def provenance_lines(results: dict) -> list[str]:
    rows = []
    for part, rel in PARTS.items():
        if results[part] is None:
            continue
        p = results[part].get("provenance") or {}
        rows.append([f"`{rel}`", recorded(p.get("date")), _commit(p),
                     recorded(p.get("cpu")), recorded(p.get("cores")), recorded(p.get("torch_threads")),
                     recorded(p.get("wall_seconds"), "{:,.0f} s"), _flags(p.get("flags"))])
    return ["Where each results file was collected (its `provenance`, recorded by `python report.py collect`); each "
            "model's training is quoted from its own JSON in its section.", "",
            table(["results", "collected", "git commit", "CPU", "cores", "torch threads", "wall time", "flags"], rows)]


def planners(results: dict) -> dict:
    """classical_cpp.json as the report reads it: planners it lacks on cpp_eval and the MovingAI maps filled in from
    rollout.json (the rollout part), and its "structured_eval" from planners_structured.json (the structured part)
    if it has none; classical_cpp.json's own entries come first. A new dict: `results` is left as it was."""
    with reading(results["paths"]["classical"]):
        c = dict(results["classical"])
        if not isinstance(c["cpp_eval"], dict) or not isinstance(c["external"], dict):
            raise TypeError("cpp_eval and external must be JSON objects")
    ro, st = results.get("rollout"), results.get("structured")
    if ro is not None:
        with reading(results["paths"]["rollout"]):
            extra = [n for n in ro["cpp_eval"] if n not in c["cpp_eval"]]
            if extra:
                cpp = list(c["cpp_eval"])
                at = cpp.index("lkh") if "lkh" in cpp else len(cpp)  # the near-optimal reference stays last
                order = cpp[:at] + extra + cpp[at:]
                both = {**c["cpp_eval"], **ro["cpp_eval"]}
                c["cpp_eval"] = {n: both[n] for n in order}
                c["external"] = {m: {n: {**per, **ro["external"][m]}[n] for n in order} for m, per in c["external"].items()}
                c["filled_in"] = {"planners": extra, "per_size": ro["per_size"], "file": PARTS["rollout"]}
    if st is not None and "structured_eval" not in c:
        with reading(results["paths"]["structured"]):
            c["structured_eval"] = st["structured_eval"]
    return c


def _join(items: list[str]) -> str:
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def _share(x: float) -> str:
    """A share as a percentage that reads 100% only when it is (209 of 210 maps: 99.5%)."""
    return f"{100 * x:.0f}%" if x == 1 or 100 * x < 99.5 else f"{100 * x:.1f}%"


def structured_lines(s: dict) -> list[str]:
    """The planners on structured_eval by map family and size band, rollout against the others and against LKH."""
    plans, families = s["planners"], list(s["maps"])
    bands = [f"{a}-{b}" for a, b in s["bands"]]
    n_maps = sum(s["maps"].values())

    def cell(r):
        return f"{r['overlap']:.3f}" + ("" if r["completion"] == 1 else f" ({_share(r['completion'])} completed)")

    lines = [
        f"`maps/structured_eval.npz` (`maps/make_datasets.py`), {s['per_band']} maps per family and size band "
        f"({', '.join(bands)}; spread over each band's sizes), {n_maps} maps in all, one agent from each map's first "
        f"stored start; mean overlap (completion shown where below 100%), LKH ({s['lkh_time_limit_s']:.0f} s cap per "
        "map) the near-optimal reference.", "",
        table(["planner"] + families + ["all", "completed", "plan ms/map"],
              [[n] + [cell(r[f]) for f in families] + [cell(r["all"]), _share(r['all']['completion']),
                                                       f"{r['all']['plan_ms_per_map']:.1f}"] for n, r in plans.items()])]
    if "rollout" in plans:
        ro = plans["rollout"]
        others = [n for n in plans if n not in ("rollout", "lkh")]
        best = {f: min(plans[n][f]["overlap"] for n in others) for f in families}
        below = [f for f in families if ro[f]["overlap"] < best[f]]

        def rivals(f):
            return _join([n for n in others if plans[n][f]["overlap"] == best[f]])

        tied = [f"{f} ({rivals(f)} also {best[f]:.3f})" for f in families if ro[f]["overlap"] == best[f]]
        above = [f"{f} ({rivals(f)} {best[f]:.3f} against {ro[f]['overlap']:.3f})"
                 for f in families if ro[f]["overlap"] > best[f]]
        done = min(ro[f]["completion"] for f in families)
        sentence = (f"Rollout is below every other planner but LKH ({', '.join(others)}) in {len(below)} of "
                    f"{len(families)} families" + (f"; tied in {_join(tied)}" if tied else "")
                    + (f"; above in {_join(above)}" if above else "")
                    + f"; completion {_share(done)}" + (" in every family." if done == 1 else " at worst."))
        if "lkh" in plans:
            lk = plans["lkh"]
            gap = {f: ro[f]["overlap"] - lk[f]["overlap"] for f in families}
            worst, best = max(families, key=gap.get), min(families, key=gap.get)
            sentence += (" Rollout's gap to LKH (mean overlap, rollout − LKH): "
                         + "; ".join(f"{f} {gap[f]:+.3f} ({ro[f]['overlap']:.3f} against {lk[f]['overlap']:.3f}, "
                                     f"{ro[f]['overlap'] / lk[f]['overlap']:.1f}×)" if lk[f]["overlap"] > 0 else
                                     f"{f} {gap[f]:+.3f} ({ro[f]['overlap']:.3f} against {lk[f]['overlap']:.3f})"
                                     for f in families)
                         + f"; all maps {ro['all']['overlap'] - lk['all']['overlap']:+.3f}. Largest in {worst}, "
                         f"smallest in {best}.")
        lines += ["", sentence]
    lines += ["", "Mean overlap by size band (all families):", "",
              table(["planner"] + bands + ["all"],
                    [[n] + [f"{r['all']['by_band'][b]:.3f}" for b in bands] + [f"{r['all']['overlap']:.3f}"]
                     for n, r in plans.items()]), "",
              f"![planners on structured_eval]({FIGURES['planners_structured']})"]
    return lines


def classical_lines(c: dict) -> tuple[list[str], list[str]]:
    """The planner comparison (Table 6.4) and the multi-agent baselines."""
    cpp, ext, marl = c["cpp_eval"], c["external"], c["marl_eval"]
    planners, maps = list(cpp), list(ext)
    bands = [k for k in next(iter(cpp.values())) if "-" in k]
    starts = sorted({len(v) for per in ext.values() for v in per.values()})
    comparison = [
        f"`cpp_eval`, the first {c['per_size']} maps of each size, mean overlap by size band; "
        f"LKH ({c['lkh_time_limit_s']:.0f} s cap per map) is the near-optimal reference.", "",
        table(["planner"] + bands + ["all", "plan ms/map"],
              [[n] + [f"{cpp[n][b]:.3f}" for b in bands] + [f"{cpp[n]['all']:.3f}", f"{cpp[n]['plan_ms_per_map']:.1f}"]
               for n in planners]), "",
        *([f"{_join(c['filled_in']['planners'])}: from `{c['filled_in']['file']}` (collected on its own, the first "
             f"{c['filled_in']['per_size']} maps of each size and the same MovingAI starts).", ""] if "filled_in" in c else []),
        f"![planners by size]({FIGURES['planners_by_size']})", "",
        f"MovingAI maps (`maps/external`), mean overlap over the {'/'.join(map(str, starts))} reference starts:", "",
        table(["map"] + planners, [[m] + [f"{np.mean(ext[m][n]):.3f}" for n in planners] for m in maps]), "",
        f"![planners on external maps]({FIGURES['planners_external']})"]
    where = (f"sizes {c['marl_sizes'][0]}-{c['marl_sizes'][1]}, every {_ordinal(c['marl_every'])} layout"
             if "marl_sizes" in c and "marl_every" in c else "sizes and layouts not recorded")
    agents = sorted(marl, key=int)
    baselines = [
        f"Baselines on `marl_eval` ({where}), mean time-save factor $t_{{sf}} = T / n_{{poi}}(s_0)$:", "",
        table(["agents", "maps", "greedy (claims)", "partition", "lower bound"],
              [[n, str(marl[n]["maps"]), f"{marl[n]['greedy']:.3f}", f"{marl[n]['partition']:.3f}",
                f"{marl[n]['lower_bound_time_save']:.3f}"] for n in agents]), "",
        f"![multi-agent baselines]({FIGURES['marl_baselines']})"]
    return comparison, baselines


def team_rollout_lines(t: dict | None) -> list[str]:
    """The multiagent rollout planner beside its base and greedy (both with claims) and the lower bound."""
    if t is None:
        return [f"*Not collected:* no `{PARTS['team_rollout']}` here; `python report.py collect --parts team_rollout` "
                "fills it in (the multiagent rollout planner)."]
    rows = [[dataset, n, str(e["maps"]), f"{e['greedy']['time_save']:.3f}", f"{e['greedy-dead-ends']['time_save']:.3f}",
             f"**{e['rollout']['time_save']:.3f}**", f"{e['lower_bound_time_save']:.3f}", f"{e['rollout']['s_per_map']:.1f}",
             str(e["rollout_longer_than_base"])]
            for dataset in ("marl_eval", "structured_eval") for n, e in t[dataset].items()]
    where = f"every {_ordinal(t['marl_every'])} marl_eval layout of sizes 10-30"
    if t["structured_every"]:
        where += f", every {_ordinal(t['structured_every'])} structured_eval map"
    return [f"The multiagent rollout planner (`--planner rollout --agents N`, Bertsekas 2020) beside its base, "
            f"greedy-dead-ends with claims, on {where} (the first N stored starts), mean $t_{{sf}}$:", "",
            table(["dataset", "agents", "maps", "greedy (claims)", "greedy-dead-ends (claims)", "rollout", "lower bound",
                   "rollout s/map", "maps where rollout > base"], rows)]


def sensor_lines(sr: dict | None) -> list[str]:
    """Figs. 6.17-6.22 from the sensors part: the agent beside the frontier baselines under each sensor setting."""
    if sr is None:
        return [NOT_COLLECTED.format(file=PARTS["sensors"], part="sensors", model=MODELS["sensors"],
                                     script=SCRIPTS["sensors"])]
    head = ["setting", "rainbow + heuristic", "completed", "heuristic share", "frontier", "completed",
            "frontier-row-major", "frontier-far-first"]

    def row(label, e):
        a, f, r, ff = (e[p] for p in SENSOR_POLICIES)
        return [label, f"**{a['overlap']:.3f}**", _share(a['completion']), f"{a['heuristic_share']:.2f}",
                f"{f['overlap']:.3f}", _share(f['completion']), f"{r['overlap']:.3f}", f"{ff['overlap']:.3f}"]

    m = sr["model"]
    stages = m.get("args", {}).get("stages") or "the built-in stages"
    lines = [f"The shipped `{MODELS['sensors']}` (trained on `{stages}`) with the heuristic fallback, beside the "
             "exploration baselines of `evaluate.py` on the agent's known map under the same sensor (`frontier`: the "
             "navigation heuristic with dead-ends-first ties, else the nearest frontier; `frontier-row-major`; "
             "`frontier-far-first`, the model's own hint and fallback under the sensor), on the "
             f"same episodes: the first {sr['per_size']} `cpp_eval` maps of each size and {sr['per_band']} "
             "`structured_eval` map(s) per family and size band. Mean overlap; completion and the heuristic's share of "
             "the agent's steps beside it.", ""]
    for name in ("cpp_eval", "structured_eval"):
        e = sr[name]
        lines += [f"**Figs. 6.20-6.21** (`{name}`): camera and LiDAR of range K (they coincide at K = 1, §6.5.3.2):", "",
                  table(head, [row("full information", e["full"])]
                        + [row(f"{sensor} K = {k}", e[f"{sensor.lower()}_r{k}"]) for sensor in ("camera", "LiDAR")
                           for k in SENSOR_RANGES if f"{sensor.lower()}_r{k}" in e]), "",
                  f"**Fig. 6.22** (`{name}`): camera r = {CAMERA_RANGE} with a share of the sensor readings dropped:", "",
                  table(head, [row(f"failure {round(100 * f)}%", e[f"camera_r{CAMERA_RANGE}" if f == 0 else
                                                                 f"camera_r{CAMERA_RANGE}_failure{round(100 * f)}"])
                               for f in (0.0, *SENSOR_FAILURES)]), ""]
    for name, what in (("cpp_eval", "size band"), ("structured_eval", "family")):
        full, camera = sr[name]["full"], sr[name][f"camera_r{CAMERA_RANGE}"]
        lines += [f"**Figs. 6.17-6.19** (`{name}`): camera r = {CAMERA_RANGE} against full information by {what}:", "",
                  table([what, "rainbow, full information", f"rainbow, camera r = {CAMERA_RANGE}", "frontier, camera",
                         "frontier-row-major, camera", "frontier-far-first, camera"],
                        [[k, f"{full['rainbow']['by'][k]['overlap']:.3f}", f"{camera['rainbow']['by'][k]['overlap']:.3f}",
                          f"{camera['frontier']['by'][k]['overlap']:.3f}",
                          f"{camera['frontier-row-major']['by'][k]['overlap']:.3f}",
                          f"{camera['frontier-far-first']['by'][k]['overlap']:.3f}"] for k in camera["rainbow"]["by"]]), ""]
    return lines + [f"![agent and frontier baselines by sensor range]({FIGURES['sensors']})"]


def rainbow_lines(rb: dict, c: dict) -> tuple[list[str], list[str], list[str]]:
    """The chapter-6 agent: full information (Figs. 6.13-6.16), camera (Figs. 6.17-6.22), point-to-point (Fig. 6.23)."""
    sizes = sorted(rb["full"], key=int)
    ext = c["external"]
    m = rb["model"]
    wall = _wall(m)
    first, last = REFERENCE["rainbow_cpp_sizes"]
    target = [z for z in sizes if first <= int(z) <= last]
    goal = REFERENCE["rainbow_cpp_overlap"]
    model = (f"Model `{MODELS['rainbow_cpp']}` (hidden {m['args']['hidden']}): {m['global_step']:,} environment "
             f"steps, last stage {m['stage']}, {recorded(None if wall is None else wall / 3600, '{:.1f} h')} of "
             f"training; flags in `{os.path.splitext(MODELS['rainbow_cpp'])[0]}.json`. {trained_on(m)} "
             "Regenerate these numbers with `python report.py --overwrite`.")
    full = [model, ""]
    if target:
        below = sum(rb["full"][z]["overlap"] < rb["greedy"][z]["overlap"] for z in target)
        worst = max(target, key=lambda z: rb["full"][z]["overlap"])
        full += [f"Targets on sizes {first}-{last} (`report.REFERENCE`: "
                 f"{100 * REFERENCE['rainbow_cpp_completion']:.0f}% completion, mean overlap ≤ {goal} and below "
                 f"the greedy planner at every size): completion "
                 f"{_share(min(rb['full'][z]['completion'] for z in target))} at worst; mean overlap ≤ {goal} at "
                 f"{sum(rb['full'][z]['overlap'] <= goal for z in target)} of {len(target)} sizes (worst "
                 f"{rb['full'][worst]['overlap']:.3f} at {worst}); below greedy at {below} of {len(target)}."
                 + _unreachable(rb, target, goal), ""]
    starts = sorted({len(v) for v in rb["external"].values()})
    bound = "lower_bound" in rb
    full += [
        f"`cpp_eval`, the first {rb['per_size']} maps of each size, mean overlap and "
        "completion; heuristic share = fraction of steps the fallback took"
        + ("; lower bound = the overlap below which no walk goes (`classical_cpp.lower_bound`: every cell once, and "
           "the checkerboard parity of the cells)." if bound else "."), "",
        table(["size", "rainbow + heuristic", "completed", "heuristic share", "rainbow alone (completed maps)",
               "completed", "greedy planner", "greedy-dead-ends planner", "greedy-far-first planner"]
              + ["lower bound"] * bound,
              [[z, f"{rb['full'][z]['overlap']:.3f}", _share(rb['full'][z]['completion']),
                f"{rb['full'][z]['heuristic_share']:.2f}", f"{rb['full_no_heuristic'][z]['overlap_completed']:.3f}",
                _share(rb['full_no_heuristic'][z]['completion']), f"{rb['greedy'][z]['overlap']:.3f}",
                f"{rb['greedy_dead_ends'][z]['overlap']:.3f}", f"{rb['greedy_far_first'][z]['overlap']:.3f}"]
               + ([f"{rb['lower_bound'][z]:.3f}"] if bound else []) for z in sizes]), "",
        f"![rainbow overlap by size]({FIGURES['rainbow_cpp']})", "",
        f"MovingAI maps, mean overlap over the {'/'.join(map(str, starts))} reference starts:", "",
        table(["map", "rainbow + heuristic", "greedy-far-first"]
              + [p for p in MOVINGAI_PLANNERS if p in next(iter(ext.values()))],
              [[name, f"{np.mean(v):.3f}", f"{np.mean(rb['greedy_far_first_external'][name]):.3f}"]
               + [f"{np.mean(ext[name][p]):.3f}" for p in MOVINGAI_PLANNERS if p in ext[name]]
               for name, v in rb["external"].items()])]
    st = c.get("structured_eval")
    if "structured_eval" in rb and st is not None:
        names = [p for p in ("greedy-dead-ends", "wavefront", "rollout", "lkh") if p in st["planners"]]
        full += ["", f"`structured_eval`, the planners' {st['per_band']} maps per family and size band (the section "
                 "below), mean overlap:", "",
                 table(["family", "rainbow + heuristic", "completed", "heuristic share", "greedy-far-first"] + names,
                       [[f, f"**{rb['structured_eval'][f]['overlap']:.3f}**",
                         _share(rb['structured_eval'][f]['completion']),
                         f"{rb['structured_eval'][f]['heuristic_share']:.2f}",
                         f"{rb['greedy_far_first_structured'][f]['overlap']:.3f}"]
                        + [f"{st['planners'][p][f]['overlap']:.3f}" for p in names] for f in rb["structured_eval"]])]
    r = rb.get("camera_range", CAMERA_RANGE)
    camera = rb[f"camera_r{r}"]
    sensor = [f"Camera, range r = {r}, the same model with the heuristic fallback, `cpp_eval` as above:", "",
              table(["size", "overlap", "completed"],
                    [[z, f"{camera[z]['overlap']:.3f}", _share(camera[z]['completion'])] for z in sizes])]
    p = rb["p2p"]
    p2p = [f"The first {p['maps']:,} scenarios of `p2p_eval` (one point of interest), heuristic fallback on: "
           f"{100 * p['optimal']:.1f}% on a shortest path, {100 * p['completion']:.1f}% reached, "
           f"{p['mean_extra_steps']:.2f} steps beyond the shortest path on average."]
    return full, sensor, p2p


def _unreachable(rb: dict, sizes: list[str], goal: float) -> str:
    """The sizes where no walk at all meets the overlap target on these maps (the lower bound is above it)."""
    over = [z for z in sizes if "lower_bound" in rb and rb["lower_bound"][z] > goal]
    return "".join(f" At {z}x{z} no walk meets {goal} on these maps: the lower bound is "
                   f"{rb['lower_bound'][z]:.3f}." for z in over)


def marl_lines(mr: dict, rewards: dict) -> list[str]:
    """The chapter-7 agent (Figs. 7.11-7.12) and the reward structures of §7.5.2."""
    agents = sorted(mr["agents"], key=int)
    m = mr["model"]
    wall = _wall(m)
    sizes = _sizes(mr["agents"][agents[0]]["by_size"])
    met = [f"N = {n}: {mr['agents'][n]['time_save']:.3f} against ≤ {t} "
           f"({'met' if mr['agents'][n]['time_save'] <= t else 'not met'})"
           for n, t in REFERENCE["rainbow_marl_time_save"].items() if n in mr["agents"]]
    several = [n for n in agents if int(n) > 1]
    below = [n for n in several if mr["agents"][n]["time_save"] < min(mr["agents"][n]["greedy"], mr["agents"][n]["partition"])]
    st = mr.get("structured_eval")
    st_by_n = st["agents"] if st else None
    st_below = sum(a["time_save"] < min(a["greedy"], a["partition"]) for a in st_by_n.values()) if st_by_n else 0
    lines = [
        f"Model `{MODELS['rainbow_marl']}` (hidden {m['args']['hidden']}"
        + (f", from `{m['args']['init_from']}`" if m["args"].get("init_from") else "") + "): "
        f"{m['global_step']:,} environment steps, last stage {m['stage']}, "
        f"{recorded(None if wall is None else wall / 60, '{:.0f} min')} of training; flags in "
        f"`{os.path.splitext(MODELS['rainbow_marl'])[0]}.json`. Decentralised execution, noise off, heuristic "
        f"fallback on. {trained_on(m)}", ""]
    if met:
        lines += [f"Targets (`report.REFERENCE`, mean $t_{{sf}}$ on sizes {sizes}): {'; '.join(met)}. Completion "
                  f"{_share(min(mr['agents'][n]['completion'] for n in agents))} at worst."
                  + (f" Below the greedy planner and partition at {len(below)} of the "
                     f"{len(several)} agent counts {several[0]}-{several[-1]}" if several else "")
                  + (f"; on `structured_eval` at {st_below} of {len(st_by_n)}." if st_by_n else "." if several else ""),
                  ""]
    lines += [
        f"`marl_eval` sizes {sizes}, every {_ordinal(mr['every'])} layout, the first N stored starts (the N + 1-agent "
        "episode adds one agent to the N-agent one); heuristic share = fraction of agent-steps the fallback took:", "",
        table(["N", "maps", "rainbow_marl", "greedy (claims)", "greedy-dead-ends (claims)"]
              + ["greedy-far-first (claims)", "partition", "1/N", "completed", "heuristic share"],
              [[n, str(mr["agents"][n]["maps"]), f"{mr['agents'][n]['time_save']:.3f}",
                f"{mr['agents'][n]['greedy']:.3f}", f"{mr['agents'][n]['greedy_dead_ends']:.3f}",
                f"{mr['agents'][n]['greedy_far_first']:.3f}", f"{mr['agents'][n]['partition']:.3f}",
                f"{1 / int(n):.3f}", _share(mr['agents'][n]['completion']), f"{mr['agents'][n]['heuristic_share']:.2f}"]
               for n in agents]), "",
        f"![rainbow_marl time-save factor]({FIGURES['rainbow_marl']})"]
    if st_by_n:
        lines += ["", f"`structured_eval` (rooms, corridors, clutter, maze), every {_ordinal(st['every'])} map "
                  f"({st['maps']} maps), the first N stored starts, mean $t_{{sf}}$:", "",
                  table(["N", "rainbow_marl", "greedy (claims)", "greedy-dead-ends (claims)", "greedy-far-first (claims)",
                         "partition", "1/N", "completed"],
                        [[n, *[f"{a[key]:.3f}" for key in ("time_save", "greedy", "greedy_dead_ends", "greedy_far_first",
                                                          "partition")], f"{1 / int(n):.3f}", _share(a["completion"])]
                         for n, a in st_by_n.items()])]
    if mr["faulty"]:
        def walled(n, f):
            done, rest = f["completion_reachable"], f["time_save_reachable"]
            return [f"{f['walled_off']} of {mr['agents'][n]['maps']}", "—" if done is None else _share(done),
                    "—" if rest is None else f"{rest:.3f}"]

        lines += [
            "", f"Faulty agent (§7.5.3.3, Fig. 7.12): the last agent freezes once "
            f"{100 * mr.get('faulty_at', FAULTY_AT):.0f}% of the points of interest are covered; "
            "mean $t_{sf}$ beside N and N - 1 working agents on the same maps:", "",
            table(["N", "N working", "N, one faulty", "completed (faulty)", "N - 1 working",
                   "maps walled off by the frozen agent", "completed (the others)",
                   "N, one faulty (the others)"],  # a walled-off map covers less: its t_sf is not comparable
                  [[n, f"{mr['agents'][n]['time_save']:.3f}", f"{f['time_save']:.3f}", _share(f["completion"]),
                    f"{mr['agents'][str(int(n) - 1)]['time_save']:.3f}" if str(int(n) - 1) in mr["agents"] else "—"]
                   + walled(n, f) for n, f in mr["faulty"].items()])]
    if rewards:
        lines += [""] + reward_lines(rewards)
    return lines


def reward_lines(rewards: dict) -> list[str]:
    """§7.5.2: the reward structures, each trained from the same model with the same budget over several seeds (a
    run's model.json, written by its trainer, says which), mean t_sf over the seeds with a 95% interval (Student's t
    over the seeds' means), beside the untrained baselines."""
    first = next(iter(rewards.values()))
    arms: dict = {}
    for name, s in rewards.items():
        key = (s["model"]["args"]["reward_structure"], s["model"]["args"]["gain"]) if "model" in s else (name, None)
        arms.setdefault(key, []).append(s)
    rows = []
    for (structure, gain), runs in arms.items():
        t = np.array([r["all"]["time_save"]["mean"] for r in runs])
        half = T_975[len(t) - 1] * t.std(ddof=1) / np.sqrt(len(t)) if len(t) > 1 else None
        no_gain = gain is None or structure == "competitive"  # eq. 7.3 has no K
        rows.append([structure, "—" if no_gain else f"{gain:g}", str(len(t)), str(runs[0]["all"]["episodes"]),
                     f"{t.mean():.3f}", "—" if half is None else f"{t.mean() - half:.3f} – {t.mean() + half:.3f}",
                     _share(min(r['all']['completion_rate'] for r in runs))])
    trained = [s["model"] for s in rewards.values() if "model" in s]
    budget = ""
    if trained:
        a = trained[0]["args"]
        steps = sorted({m["global_step"] for m in trained})
        budget = (f" Each run: {', '.join(f'{n:,}' for n in steps)} environment steps from `{a['init_from']}`, "
                  f"margin loss {a['margin_loss']:g}, learning rate {a['learning_rate']:g}, replay ratio "
                  f"{a['replay_ratio']:g}, random agent counts {'on' if a['random_agents'] else 'off'} (each run's "
                  "`model.json`, written by its trainer, has every flag).")
    return [f"Reward structures (§7.5.2, Figs. 7.7-7.8): `marl_rewards/*/summary.json`, written by `evaluate.py`; "
            f"N = {first['agents']}, `{first['dataset']}` sizes {_sizes(first['by_size'])}, mean $t_{{sf}}$ over the "
            f"runs of each structure with its 95% interval over seeds.{budget}", "",
            table(["reward", "gain K", "runs", "maps", "mean t_sf", "95% interval", "completed"], rows)]


def _fig5_4_runs(runs: dict) -> tuple[dict, list[str]]:
    """The Fig. 5.4 training runs keyed by (algorithm, obstacles, heuristic), and the algorithms with both
    obstacle settings trained with the heuristic."""
    keyed = {(r["args"]["algorithm"], r["args"]["number_obstacles"], r["args"]["heuristic"]): r for r in runs.values()}
    return keyed, [a for a in REFERENCE["table_5_1_seconds"] if (a, 0, True) in keyed and (a, 1, True) in keyed]


def _last(run: dict) -> tuple[float, int]:
    """Mean ρ of the last 10% of training, and how many episodes that is."""
    c = run["curve_rho"]
    k = max(1, len(c) // 10)
    return float(np.mean(c[-k:])), k * run["curve_window"]


def _same(values) -> str:
    return "/".join(str(v) for v in dict.fromkeys(values))


def tabular_lines(fig55: dict | None, runs: dict) -> list[str]:
    """Chapter 5: the training runs of Fig. 5.4 and Table 5.1, and the committed table on ch5_eval (Fig. 5.5)."""
    keyed, algorithms = _fig5_4_runs(runs)
    machines = [r.get("machine") or (r.get("provenance") or {}).get("cpu") for r in runs.values()]
    if fig55 is not None:
        machines.append(fig55["model"].get("machine") or (fig55["model"].get("provenance") or {}).get("cpu"))
    n = 6
    lines = [f"Every number here comes from `tabular_q.py` runs (machine: {recorded(_same(machines) or None)}); "
             "ρ = steps / free cells as gridworld counts it, so a perfect sweep of an obstacle-free N×N map is "
             f"(N² − 1)/N² ({(n * n - 1) / (n * n):.3f} on {n}×{n}), not the {REFERENCE['rho_perfect']} of §5.4.1.", ""]
    if algorithms:
        chosen = [keyed[(a, o, True)] for a in algorithms for o in (0, 1)]
        episodes = _same(f"{r['episodes']:,}" for r in chosen)
        size = _same(r["args"]["size"] for r in chosen)
        starts = _same("corner" if r["args"]["corner_starts"] else "random" for r in chosen)
        window = _same(f"{r['curve_window']:,}" for r in chosen)
        last = {(a, o): _last(keyed[(a, o, True)]) for a in algorithms for o in (0, 1)}
        tail = _same(f"{k // 1000:,}k" if k % 1000 == 0 else f"{k:,}" for _, k in last.values())
        lines += [
            f"**Fig. 5.4** — {episodes} training episodes on {size}×{size} with {starts} starts, heuristic on, "
            f"mean ρ per {window} episodes (`results/tabular/fig5_4/*.json`; commands in docs/tabular.md):", "",
            f"![Fig. 5.4]({FIGURES['fig5_4']})", "",
            table(["algorithm", f"ρ, last {tail} episodes, 0 obstacles", f"ρ, last {tail} episodes, 1 obstacle"],
                  [[a, f"{last[(a, 0)][0]:.4f}", f"{last[(a, 1)][0]:.4f}"] for a in algorithms]), "",
            f"**Table 5.1** — training time (s) of those {episodes} episodes, ours ("
            f"{recorded(_same(r.get('machine') for r in chosen) or None)}, "
            f"{_same(r['args']['num_worlds'] for r in chosen)} worlds stepped together) / the dissertation's "
            f"({REFERENCE['table_5_1_machine']}):", "",
            table(["method", "heuristic, no obstacles", "heuristic, one obstacle", "no heuristic, no obstacles",
                   "no heuristic, one obstacle"],
                  [[a] + [f"{keyed[(a, o, h)]['wall_seconds']:.0f} / {REFERENCE['table_5_1_seconds'][a][k]}"
                          if (a, o, h) in keyed else f"– / {REFERENCE['table_5_1_seconds'][a][k]}"
                          for k, (h, o) in enumerate(((True, 0), (True, 1), (False, 0), (False, 1)))]
                   for a in algorithms]), ""]
    if fig55 is None:
        return lines + [NOT_COLLECTED.format(file=PARTS["tabular"], part="tabular", model=MODELS["tabular"],
                                             script=SCRIPTS["tabular"])]
    m, settings = fig55["model"], fig55["settings"]
    a = m["args"]
    sizes = sorted({s["size"] for s in settings})
    obstacle_counts = sorted({s["obstacles"] for s in settings})
    cell = {(s["size"], s["obstacles"]): s for s in settings}
    wall = _wall(m)
    obstacles = f"0-{a['number_obstacles']}" if a.get("obstacles_random") else str(a["number_obstacles"])
    return lines + [
        f"**Fig. 5.5** — the committed table `{MODELS['tabular']}` ({a['algorithm']}, sizes "
        f"{a['min_size'] if a.get('min_size') is not None else a['size']}-{a['size']}, {obstacles} obstacles, "
        f"{'corner' if a.get('corner_starts') else 'random'} starts): {m['episodes']:,} training episodes in "
        f"{recorded(None if wall is None else wall / 60, '{:.0f} min')} ({m['episodes_per_second']:,.0f} episodes/s, "
        f"{m['states']:,} states) against the dissertation's {REFERENCE['fig_5_5_episodes'] / 1e6:g} M. "
        f"{trained_on(m, torch=False)} Greedy on `{CH5_EVAL}`, {_same(s['maps'] for s in settings)} maps per "
        f"setting (the dissertation used {REFERENCE['fig_5_5_maps']:,}), mean ρ; in brackets the untrained table (a "
        "random move toward an uncovered neighbour, the heuristic at dead ends):", "",
        table(["size \\ obstacles"] + [str(o) for o in obstacle_counts],
              [[str(z)] + [f"{cell[(z, o)]['trained']:.3f} ({cell[(z, o)]['untrained']:.3f})" for o in obstacle_counts]
               for z in sizes]), "",
        f"![Fig. 5.5]({FIGURES['fig5_5']})"]


def headline(results: dict) -> list[str]:
    """The README's results table: mean overlap of the shipped agent beside the planners on the same maps (cpp_eval's
    subset of the planner report, the MovingAI maps from their reference starts), and the team's time-save factor."""
    c, rb, mr = planners(results), results["rainbow_cpp"], results["rainbow_marl"]
    ext = c["external"]
    st = c.get("structured_eval")  # when there: one more column, and rollout's row

    def external(planner):
        return float(np.mean([np.mean(by[planner]) for by in ext.values()]))

    def cpp(key):
        return float(np.mean([v["overlap"] for v in rb[key].values()]))

    def structured(planner):
        return f"{st['planners'][planner]['all']['overlap']:.3f}" if planner in st["planners"] else "—"

    rows = []
    if rb is not None:
        rows.append(["rainbow_cpp (shipped, + heuristic fallback)", f"{cpp('full'):.3f}",
                     f"{float(np.mean([np.mean(v) for v in rb['external'].values()])):.3f}"]
                    + ([] if st is None else [f"{rb['structured_eval']['all']['overlap']:.3f}"
                                              if "structured_eval" in rb else "—"]))
        far_first = bool(rb["model"].get("args", {}).get("heuristic_far_first"))
        if "greedy_far_first" in rb:  # the far-first heuristic, measured beside the model
            rows.append([f"greedy-far-first{' (its teacher)' if far_first else ''}", f"{cpp('greedy_far_first'):.3f}",
                         f"{float(np.mean([np.mean(v) for v in rb['greedy_far_first_external'].values()])):.3f}"]
                        + ([] if st is None else [f"{rb['greedy_far_first_structured']['all']['overlap']:.3f}"]))
        rows.append([f"greedy-dead-ends{'' if far_first else ' (its teacher)'}", f"{cpp('greedy_dead_ends'):.3f}", "—"]
                    + ([] if st is None else [structured("greedy-dead-ends")]))
    names = ["greedy", "wavefront", "boustrophedon", "spiral-stc", "lkh"]
    if st is not None and "rollout" in c["cpp_eval"]:
        names.insert(-1, "rollout")
    rows += [[name, f"{c['cpp_eval'][name]['all']:.3f}", f"{external(name):.3f}"]
             + ([] if st is None else [structured(name)]) for name in names]
    header = ["mean overlap $O_v$ (lower is better)", f"cpp_eval ({c['per_size']} maps a size, 5-30)",
              f"MovingAI ({len(ext)} maps, 3 starts each)"]
    if st is not None:
        header.append(f"structured_eval ({sum(st['maps'].values())} maps, {len(st['maps'])} families)")
    lines = [table(header, rows)]
    if mr is not None:
        team = [n for n in ("2", "5", "10") if n in mr["agents"]]
        far_first = bool(mr["model"].get("args", {}).get("heuristic_far_first"))
        rows = [["rainbow_marl (shipped)", *[f"{mr['agents'][n]['time_save']:.3f}" for n in team]],
                ["greedy with claims", *[f"{mr['agents'][n]['greedy']:.3f}" for n in team]],
                [f"greedy-dead-ends with claims{'' if far_first else ' (its teacher)'}",
                 *[f"{mr['agents'][n]['greedy_dead_ends']:.3f}" for n in team]]]
        if "greedy_far_first" in mr["agents"][team[0]]:
            rows.append([f"greedy-far-first with claims{' (its teacher)' if far_first else ''}",
                         *[f"{mr['agents'][n]['greedy_far_first']:.3f}" for n in team]])
        lines += ["", table(["mean time-save $t_{sf}$, marl_eval sizes 10-30", *[f"N = {n}" for n in team]], rows)]
    return lines


def _lineage_steps(m: dict) -> tuple[int, int]:
    """Environment steps over a model's whole warm-start chain (its JSON's `parent` records), and the runs counted."""
    steps, runs, link = m["global_step"], 1, m.get("parent")
    while isinstance(link, dict) and isinstance(link.get("global_step"), int):
        steps, runs, link = steps + link["global_step"], runs + 1, link.get("parent")
    return steps, runs


def _trained(m: dict, model: str) -> str:
    wall = _wall(m)
    steps, runs = _lineage_steps(m)
    threads = _provenance(m).get("torch_threads", m.get("torch_threads"))
    kind = (m.get("network") or {}).get("network", "fig6.8") if isinstance(m.get("network"), dict) else "fig6.8"
    return (f"`{model}` ({kind} network, hidden {m['args']['hidden']}): its last run took {m['global_step']:,} "
            f"environment steps in {recorded(None if wall is None else wall / 60, '{:.0f} min')} on "
            f"{recorded(threads)} torch thread{'' if threads == 1 else 's'}; {steps:,} steps over the {runs} runs of "
            "its warm-start chain.")


def rainbow_cpp_summary(results: dict) -> list[str]:
    """docs/rainbow_cpp.md's results block: the shipped model against `REFERENCE`'s targets on cpp_eval, and what
    its training cost (from its JSON). A pure function of results/, checked equal to the page by tests/test_docs.py."""
    rb = results["rainbow_cpp"]
    if rb is None:
        return [NOT_COLLECTED.format(file=PARTS["rainbow_cpp"], part="rainbow_cpp", model=MODELS["rainbow_cpp"],
                                     script=SCRIPTS["rainbow_cpp"])]
    first, last = REFERENCE["rainbow_cpp_sizes"]
    goal = REFERENCE["rainbow_cpp_overlap"]
    sizes = [z for z in sorted(rb["full"], key=int) if first <= int(z) <= last]
    full = rb["full"]
    worst = max(sizes, key=lambda z: full[z]["overlap"])
    met = sum(full[z]["overlap"] <= goal for z in sizes)
    below = sum(full[z]["overlap"] < rb["greedy"][z]["overlap"] for z in sizes)
    bound = "".join(f"; no walk meets it at {z}x{z}, whose lower bound is {rb['lower_bound'][z]:.3f}"
                    for z in sizes if "lower_bound" in rb and rb["lower_bound"][z] > goal)
    rows = [[f"completion with the fallback, every size {first}-{last}",
             f"{100 * REFERENCE['rainbow_cpp_completion']:.0f}%",
             f"{_share(min(full[z]['completion'] for z in sizes))} at worst"],
            [f"mean overlap at every size {first}-{last}", f"≤ {goal}",
             f"met at {met} of {len(sizes)} sizes (worst {full[worst]['overlap']:.3f} at {worst}{bound})"],
            [f"below the greedy planner at every size {first}-{last}", "every size", f"{below} of {len(sizes)} sizes"],
            ["mean overlap, all sizes 5-30", "—", f"{np.mean([v['overlap'] for v in full.values()]):.3f} "
             f"(its teacher greedy-far-first {np.mean([v['overlap'] for v in rb['greedy_far_first'].values()]):.3f}, "
             f"greedy {np.mean([v['overlap'] for v in rb['greedy'].values()]):.3f})"]]
    return [table([f"`cpp_eval`, the first {rb['per_size']} maps a size", "target (`report.REFERENCE`)",
                   "shipped model"], rows), "", "Training: " + _trained(rb["model"], MODELS["rainbow_cpp"])]


def rainbow_marl_summary(results: dict) -> list[str]:
    """docs/rainbow_marl.md's results block: the shipped team model against `REFERENCE`'s targets on marl_eval, and
    what its training cost (from its JSON). A pure function of results/, checked equal to the page by tests."""
    mr = results["rainbow_marl"]
    if mr is None:
        return [NOT_COLLECTED.format(file=PARTS["rainbow_marl"], part="rainbow_marl", model=MODELS["rainbow_marl"],
                                     script=SCRIPTS["rainbow_marl"])]
    agents = mr["agents"]
    rows = [[f"mean t_sf, N = {n}", f"≤ {t}", f"{agents[n]['time_save']:.3f} (its teacher greedy-far-first with claims "
             f"{agents[n]['greedy_far_first']:.3f}, greedy with claims {agents[n]['greedy']:.3f})"]
            for n, t in REFERENCE["rainbow_marl_time_save"].items() if n in agents]
    several = [n for n in sorted(agents, key=int) if int(n) > 1]
    below = sum(agents[n]["time_save"] < agents[n]["greedy"] for n in several)
    rows += [["completion, every N", "100%", f"{_share(min(a['completion'] for a in agents.values()))} at worst"],
             ["below greedy with claims", "every N", f"{below} of the {len(several)} agent counts "
              f"{several[0]}-{several[-1]}"]]
    return [table([f"`marl_eval` sizes {_sizes(agents[several[0]]['by_size'])}, every {_ordinal(mr['every'])} layout",
                   "target (`report.REFERENCE`)", "shipped model"], rows), "",
            "Training: " + _trained(mr["model"], MODELS["rainbow_marl"])]


def learning_rate_lines(sweep: dict | None) -> list[str]:
    """benchmarks/learning_rate.py's sweep: per rate, the greedy evaluation (with the fallback) at each evaluation
    beside the heuristic on the same maps, and the last logged mean Q."""
    if sweep is None:
        return [f"*Not collected:* no `{LEARNING_RATE_SWEEP}` here; `python benchmarks/learning_rate.py --out "
                f"results/{LEARNING_RATE_SWEEP}` fills it in (about 10 minutes a rate on one core)."]
    team = sweep.get("trainer") == "rainbow_marl"
    score = "time_save" if team else "overlap"
    rates = dict(sorted(sweep["rates"].items(), key=lambda kv: float(kv[0])))
    steps = [s for s, _ in next(iter(rates.values()))[score]]
    rows = [[rate, *[f"{v:.3f}" for _, v in r[score]], f"{r[f'heuristic_{score}'][-1][1]:.3f}",
             f"{r['heuristic_share'][-1][1]:.2f}", f"{r['q_values'][-1][1]:.2f}" if r["q_values"] else "—"]
            for rate, r in rates.items()]
    network = sweep["flags"][sweep["flags"].index("--network") + 1]
    if team:
        head = (f"Learning rate of the team trainer (`python benchmarks/learning_rate.py --trainer rainbow_marl`), the "
                f"{network} network from scratch: its stages n2_env1-2 (up to two agents) at "
                f"{sweep['stage_steps_scale']:g} of their steps ({sweep['total_steps']:,} steps, seed {sweep['seed']}), "
                "the dissertation's random-tie heuristic; mean time-save factor of the greedy policy with the fallback "
                "on held-out marl_eval maps up to the stage's size, at each evaluation:")
    else:
        head = (f"Learning rate (`python benchmarks/learning_rate.py`), the {network} network: Table 6.2's stages from fi1 "
                f"at {sweep['stage_steps_scale']:g} of their steps ({sweep['total_steps']:,} steps, seed {sweep['seed']}), "
                "the scale run's other flags; mean overlap of the greedy policy with the fallback on held-out cpp_eval "
                "maps up to the stage's size, at each evaluation:")
    return [head, "", table(["learning rate", *[f"{s:,}" for s in steps], "heuristic, last maps",
                             "fallback share, last", "mean Q, last"], rows)]


def scale_lines(scale: dict | None, refs: dict | None) -> list[str]:
    """The scale run (issue 43): its flags, then one row a point of its learning curve, then the references on the
    same maps."""
    if scale is None:
        return [NOT_COLLECTED.format(file=PARTS["rainbow_cpp_scale"], part="rainbow_cpp_scale",
                                     model=MODELS["rainbow_cpp_scale"], script="rainbow_cpp.py")]
    a = scale["args"]
    flags = (f"--network {a['network']} --learning-rate {a['learning_rate']:g} --tau {a['tau']:g} --stage-steps-scale "
             f"{a['stage_steps_scale']:g}" + ("" if a["camera_stages"] else " --no-camera-stages")
             + ("" if a["heuristic_dead_ends"] else " --no-heuristic-dead-ends")
             + (" --heuristic-random-ties" if a["heuristic_random_ties"] else ""))
    lines = [f"`rainbow_cpp.py {flags}` from scratch, Table 6.2's curriculum; the checkpoint `{scale['checkpoint']}` "
             f"(sha256 {scale['sha256'][:12]}) stands at {scale['global_step']:,} steps, stage index {scale['stage']}, "
             f"{scale['wall_seconds'] / 3600:.1f} h of training. Each point: the greedy policy on every 5th cpp_eval map "
             "(520, sizes 5-30) and every 14th structured_eval map (120), with the fallback and without it "
             "(alone: completion and outliers, overlap > 0.5 or truncated, §6.5.2). Steps/s counts every environment "
             "step since the previous point: after a resume the run first refills its replay memory for "
             f"`--learning-starts` ({a['learning_starts']:,} now) steps without updates, many times faster than "
             "learning, so a point whose interval holds a resume or its refill reads fast (steps since a resume "
             "says which).", ""]
    if not scale["curve"]:
        return lines + ["No point of the learning curve yet (the first comes at `--curve-every` steps)."]
    rows = [[f"{p['step']:,}", p["stage"], f"{p['cpp_eval']['overlap']:.3f}", f"{100 * p['cpp_eval']['completion']:.1f}%",
             f"{100 * p['cpp_eval_alone']['completion']:.1f}%", str(p["cpp_eval_alone"]["outliers"]),
             f"{p['structured_eval']['overlap']:.3f}", f"{100 * p['structured_eval_alone']['completion']:.1f}%",
             f"{p['cpp_eval']['fallback_share']:.3f}", str(p["sps"]), str(p["peak_rss_mb"]),
             recorded(p.get("steps_since_resume"), "{:,}")] for p in scale["curve"]]
    lines.append(table(["steps", "stage", "cpp_eval overlap", "completion", "alone: completion", "alone: outliers",
                        "structured overlap", "alone: completion", "fallback share", "steps/s", "peak MiB",
                        "steps since a resume"], rows))
    lines += ["", f"![the scale run's learning curve]({FIGURES['rainbow_cpp_scale']})"]
    if refs is not None:
        names = [*SCALE_REFERENCES, "rainbow"]
        label = {"rainbow": "shipped rainbow_cpp (+ fallback)", "greedy": "greedy (the dissertation's heuristic)"}
        lines += ["", table(["reference, same maps", "cpp_eval overlap", "structured overlap"],
                            [[label.get(n, n), f"{refs['cpp_eval'][n]['overlap']:.3f}",
                              f"{refs['structured_eval'][n]['overlap']:.3f}"] for n in names])]
    return lines


def _outliers(f: dict) -> int:
    return sum(o > REFERENCE["outlier_overlap"] or t for o, t in zip(f["overlap"], f["truncated"]))


def scale_figure_lines(figs: dict | None, rb: dict | None = None) -> list[str]:
    """Figs. 6.13-6.16 of the scale run's model, per size, beside §6.5.2's statements; then its other sets beside the
    shipped model's (`rb`, the rainbow_cpp part)."""
    if figs is None:
        return [NOT_COLLECTED.format(file=PARTS["scale_figures"], part="scale_figures", model=MODELS["scale_figures"],
                                     script="rainbow_cpp.py")]
    m, goal = figs["model"], REFERENCE["fig_6_15_overlap"]
    rows = []
    for z, f in figs["fallback"].items():
        a = figs["alone"][z]
        done = [o for o, c in zip(a["overlap"], a["completed"]) if c]
        rows.append([f"{z}×{z}", f"{np.mean(f['overlap']):.3f}", f"{np.std(f['overlap']):.3f}",
                     f"{np.max(f['overlap']):.3f}", f"{100 * np.mean(f['completed']):.1f}%",
                     f"{np.mean(done):.3f}" if done else "–", f"{100 * np.mean(a['completed']):.1f}%", str(_outliers(a))])
    fallback = [o for f in figs["fallback"].values() for o in f["overlap"]]
    alone = list(figs["alone"].values())
    n = sum(len(a["overlap"]) for a in alone)
    below = sum(np.mean(f["overlap"]) <= goal for f in figs["fallback"].values())
    return [f"The model in `{m['path']}` (sha256 {m['sha256'][:12]}, {m['global_step']:,} steps) on every cpp_eval "
            f"map ({figs['per_size']} a size, {len(fallback):,} episodes), with the fallback (the dissertation's "
            "heuristic, deterministic ties) and without it (alone). Overlap alone is over the completed episodes; "
            f"outliers: overlap > {REFERENCE['outlier_overlap']} or truncated (§6.5.2.3).", "",
            f"- With the fallback: mean overlap ≤ {goal} at {below} of {len(rows)} sizes (§6.5.2: every size), completion "
            f"{100 * np.mean([c for f in figs['fallback'].values() for c in f['completed']]):.1f}% (§6.5.2: 100%), "
            f"{sum(_outliers(f) for f in figs['fallback'].values())} outliers (§6.5.2: none).",
            f"- Without it: completion {100 * np.mean([c for a in alone for c in a['completed']]):.1f}% "
            f"(§6.5.2: {100 * REFERENCE['fig_6_16_completion']:.1f}%), no outlier "
            f"{100 * (1 - sum(map(_outliers, alone)) / max(n, 1)):.1f}% (§6.5.2: "
            f"{100 * REFERENCE['fig_6_16_favourable']:.1f}%).", "",
            table(["size", "overlap", "std", "max", "completion", "alone: overlap", "alone: completion",
                   "alone: outliers"], rows), "", f"![Figs. 6.13-6.16 of the scale run's model]({FIGURES['scale_figures']})",
            *other_set_lines(figs, rb)]


def other_set_lines(figs: dict, rb: dict | None) -> list[str]:
    """The scale run's model with the fallback on structured_eval's subset, MovingAI and p2p_eval, beside the shipped
    model where the rainbow_cpp part has it."""
    if "structured_eval" not in figs:
        return []
    rb = rb or {}

    def movingai(part):
        return f"{np.mean([o for v in part.values() for o in v]):.3f}" if part else "–"

    def pair(key, fmt, get):
        return [fmt.format(get(figs[key])), fmt.format(get(rb[key])) if key in rb else "–"]

    rows = [[f"structured_eval subset: {f}", *pair("structured_eval", "{:.3f}", lambda d, f=f: d[f]["overlap"])]
            for f in figs["structured_eval"]]
    rows += [["MovingAI episodes", movingai(figs["external"]), movingai(rb.get("external"))],
             [f"p2p_eval ({figs['p2p']['maps']:,}): a shortest path", *pair("p2p", "{:.1%}", lambda d: d["optimal"])],
             ["p2p_eval: completion", *pair("p2p", "{:.1%}", lambda d: d["completion"])]]
    return ["", table(["with the fallback: mean overlap, or share", "scale run's model", "shipped model"], rows)]


def same_maps(run: dict, refs: dict | None) -> dict | None:
    """scale_references where they were measured on the maps of `run`'s learning curve, else None."""
    return refs if refs is not None and refs.get("slices") == run["slices"] else None


def _overlap(row: dict) -> str:
    """A mean overlap, with the completion beside it where some episode did not complete."""
    return f"{row['overlap']:.3f}" + ("" if row["completion"] == 1 else f" ({_share(row['completion'])} completed)")


def td_finetune_lines(td: dict | None, refs: dict | None) -> list[str]:
    """The TD fine-tuning of the shipped model: its flags, one row a point of its learning curve, the shipped model and
    greedy-far-first on the same maps; then its committed checkpoint against both on all of structured_eval and on the
    fresh per-family maps, per family, and in how many rows it is below each."""
    if td is None:
        return [NOT_COLLECTED.format(file=PARTS["td_finetune"], part="td_finetune", model=MODELS["td_finetune"],
                                     script=SCRIPTS["td_finetune"])]
    a, parent, shipped = td["args"], td.get("parent") or {}, td["shipped"]
    flags = (f"--stages {a['stages']} --teacher {a['teacher']} --td-weight {a['td_weight']:g} --margin-loss "
             f"{a['margin_loss']:g} --learning-rate {a['learning_rate']:g}"
             + (" --heuristic-far-first" if a["heuristic_far_first"] else ""))
    start = (f"warm-started from `{parent['path']}` (sha256 {parent['sha256'][:12]}, {parent['global_step']:,} steps)"
             if parent.get("sha256") else "its warm start not recorded")
    lines = [f"`rainbow_cpp.py {flags}`, {start}; the checkpoint `{td['checkpoint']}` (sha256 {td['sha256'][:12]}) "
             f"stands at {td['global_step']:,} steps, stage index {td['stage']}, {td['wall_seconds'] / 3600:.1f} h of "
             f"training. Each point: the greedy policy on every {_ordinal(td['slices']['cpp_eval'])} cpp_eval map and "
             f"every {_ordinal(td['slices']['structured_eval'])} structured_eval map (the scale run's), with the "
             "fallback and without it (alone).", ""]
    if td["curve"]:
        rows = [[f"{p['step']:,}", p["stage"], recorded(p.get("learning_rate"), "{:g}"),
                 f"{p['cpp_eval']['overlap']:.3f}", f"{100 * p['cpp_eval_alone']['completion']:.1f}%",
                 str(p["cpp_eval_alone"]["outliers"]), f"{p['structured_eval']['overlap']:.3f}",
                 f"{100 * p['structured_eval_alone']['completion']:.1f}%", f"{p['cpp_eval']['fallback_share']:.4f}",
                 str(p["sps"])] for p in td["curve"]]
        lines += [table(["steps", "stage", "learning rate", "cpp_eval overlap", "alone: completion", "alone: outliers",
                         "structured overlap", "alone: completion", "fallback share", "steps/s"], rows), "",
                  f"![the TD fine-tuning's learning curve]({FIGURES['td_finetune']})"]
    else:
        lines.append("No point of the learning curve yet (the first comes at `--curve-every` steps).")
    refs = same_maps(td, refs)
    if refs is not None:
        label = {"rainbow": "shipped rainbow_cpp (+ fallback)"}
        lines += ["", table(["reference, same maps", "cpp_eval overlap", "structured overlap"],
                            [[label.get(n, n), f"{refs['cpp_eval'][n]['overlap']:.3f}",
                              f"{refs['structured_eval'][n]['overlap']:.3f}"] for n in TD_REFERENCES])]
    r = td["fresh_recipe"]
    rows, better = [], {"shipped": 0, "greedy_far_first": 0, "completion": 0}
    for name in ("structured_eval", "fresh"):
        for family, ft in td[name]["fine_tuned"].items():
            others = {k: td[name][k][family] for k in ("shipped", "greedy_far_first")}
            alone, shipped_alone = td[name]["fine_tuned_alone"][family], td[name]["shipped_alone"][family]
            better["shipped"] += ft["overlap"] < others["shipped"]["overlap"]
            better["greedy_far_first"] += ft["overlap"] < others["greedy_far_first"]["overlap"]
            better["completion"] += alone["completion"] >= shipped_alone["completion"]
            maps = sum(td[name]["maps"].values()) if family == "all" else td[name]["maps"][family]
            rows.append([f"{name}: {family}", f"{maps:,}", _overlap(ft), _overlap(others["shipped"]),
                         _overlap(others["greedy_far_first"]), _share(alone["completion"]),
                         _share(shipped_alone["completion"])])
    n = len(rows)
    return lines + [
        "", f"The checkpoint's greedy network beside the shipped model `{shipped['path']}` (sha256 "
        f"{shipped['sha256'][:12]}) and greedy-far-first, both networks with evaluate.py's fallback (deterministic "
        f"ties) and alone, on all of structured_eval ({sum(td['structured_eval']['maps'].values()):,} maps, each from "
        f"its first stored start) and on the fresh per-family maps ({r['per_size']} a size {r['sizes'][0]}-"
        f"{r['sizes'][1]} a family, {sum(td['fresh']['maps'].values()):,} in all, {r['obstacles']:.0%} of the cells "
        f"obstacles requested; drawn as the experiments log's fresh maps, with seeds from {r['seed']:,} on, which no "
        "dataset or training uses). Mean overlap with the fallback; completion alone.", "",
        table(["set: family", "maps", "fine-tuned", "shipped", "greedy-far-first", "fine-tuned alone: completion",
               "shipped alone: completion"], rows), "",
        f"The fine-tuned model's mean overlap is below the shipped model's in {better['shipped']} of {n} rows and below "
        f"greedy-far-first's in {better['greedy_far_first']} of {n}; its completion alone is at least the shipped "
        f"model's in {better['completion']} of {n}."]


def render(results: dict) -> str:
    """RESULTS.md from `load_results`: a pure function of the JSON, the same files always give the same text."""
    paths = results["paths"]

    def missing(part):
        return [NOT_COLLECTED.format(file=PARTS[part], part=part, model=MODELS[part], script=SCRIPTS[part])]

    classical = planners(results)
    with reading(paths["classical"]):
        comparison, baselines = classical_lines(classical)
    structured = ["*Not collected:* no `structured_eval` in `classical_cpp.json` nor a `planners_structured.json` "
                  "here; `python report.py collect --parts structured` fills it in."]
    if "structured_eval" in classical:
        with reading(paths["classical"] if "structured_eval" in results["classical"] else paths["structured"]):
            structured = structured_lines(classical["structured_eval"])
    full_info = sensor_based = point_to_point = missing("rainbow_cpp")
    if results["rainbow_cpp"] is not None:
        with reading(paths["rainbow_cpp"]):
            full_info, sensor_based, point_to_point = rainbow_lines(results["rainbow_cpp"], classical)
    multi_agent = missing("rainbow_marl")
    if results["rainbow_marl"] is not None:
        with reading(paths["rainbow_marl"]):
            multi_agent = marl_lines(results["rainbow_marl"], results["marl_rewards"])
    with reading(paths["sensors"] or "the sensors results"):
        sensors = sensor_lines(results["sensors"])
    with reading(paths["team_rollout"] or "the team rollout results"):
        team_rollout = team_rollout_lines(results["team_rollout"])
    with reading(paths["tabular"] or paths["fig5_4"] or "the tabular results"):
        tabular = tabular_lines(results["tabular"], results["fig5_4"])
    with reading(paths["rainbow_cpp_scale"] or "the scale run's results"):
        scale = scale_lines(results["rainbow_cpp_scale"], results["scale_references"])
    with reading(paths["scale_figures"] or "the scale run's figures"):
        scale += ["", "### Figs. 6.13-6.16 of the scale run's model", "",
                  *scale_figure_lines(results["scale_figures"], results["rainbow_cpp"])]
    with reading(paths["td_finetune"] or "the TD fine-tuning's results"):
        td_finetune = td_finetune_lines(results["td_finetune"], results["scale_references"])
    with reading(paths["learning_rate"] or "the learning-rate sweep"):
        scale += ["", *learning_rate_lines(results["learning_rate"])]
    for key in ("learning_rate_fig68", "learning_rate_marl"):
        if results[key] is not None:
            with reading(paths[key]):
                scale += ["", *learning_rate_lines(results[key])]
    return "\n".join([
        "# Results", "",
        "Regenerated by `python report.py --overwrite` (`python report.py render` rewrites this file from the JSON beside it "
        "without re-running anything; `python report.py all --reuse` collects only the missing JSON). Every "
        "number is counted by gridworld's environment replaying the planned paths (`classical_cpp.replay`).", "",
        "## Headline", "", *headline(results), "",
        "## Provenance", "", *provenance_lines(results), "",
        "## Single agent, full information (Figs. 6.13-6.16)", "", *full_info, "",
        "## The dissertation's recipe at scale (Table 6.2 from scratch)", "", *scale, "",
        "## TD fine-tuning of the shipped model", "", *td_finetune, "",
        "## Comparison with classical planners (Table 6.4)", "", *comparison, "",
        "## Structured maps (planners)", "", *structured, "",
        "## Sensor-based coverage (Figs. 6.17-6.22)", "", *sensor_based, "", *sensors, "",
        "## Point-to-point (Fig. 6.23)", "", *point_to_point, "",
        "## Multi-agent (Figs. 7.11-7.12)", "", *baselines, "", *team_rollout, "", *multi_agent, "",
        "## Tabular agent (Fig. 5.4, Table 5.1, Fig. 5.5)", "", *tabular, "",
    ])


# ----------------------------------------------------------------------------- plot
def _save(fig, folder: str, key: str) -> str:
    import matplotlib.pyplot as plt
    path = os.path.join(folder, FIGURES[key])
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_classical(c: dict, folder: str) -> list[str]:
    import matplotlib.pyplot as plt
    cpp, ext, marl = c["cpp_eval"], c["external"], c["marl_eval"]
    planners, maps = list(cpp), list(ext)
    bands = [k for k in next(iter(cpp.values())) if "-" in k]
    fig, ax = plt.subplots(figsize=(7, 4))
    for name in planners:
        ax.plot(bands, [cpp[name][b] for b in bands], marker="o", label=name)
    ax.set(xlabel="map size (edge, cells)", ylabel="mean overlap $O_v$",
           title=f"Planners on cpp_eval ({c['per_size']} maps per size)")
    ax.grid(alpha=0.3)
    ax.legend()
    written = [_save(fig, folder, "planners_by_size")]

    fig, ax = plt.subplots(figsize=(9, 4))
    width = 0.8 / len(planners)
    for k, name in enumerate(planners):
        ax.bar(np.arange(len(maps)) + k * width, [np.mean(ext[m][name]) for m in maps], width, label=name)
    ax.set_xticks(np.arange(len(maps)) + 0.4 - width / 2, [m.replace(".map", "") for m in maps], rotation=30, ha="right")
    ax.set(ylabel="mean overlap $O_v$ (per reference start)", title="Planners on the MovingAI maps")
    ax.legend(fontsize=8)
    written.append(_save(fig, folder, "planners_external"))

    agents = sorted(int(n) for n in marl)
    fig, ax = plt.subplots(figsize=(6, 4))
    for name in ("greedy", "partition"):
        ax.plot(agents, [marl[str(n)][name] for n in agents], marker="o", label=name)
    ax.plot(agents, [marl[str(n)]["lower_bound_time_save"] for n in agents], "k--", label="lower bound ≈ 1/N")
    where = f" (sizes {c['marl_sizes'][0]}-{c['marl_sizes'][1]})" if "marl_sizes" in c else ""
    ax.set(xlabel="agents N", ylabel="mean time-save factor $t_{sf}$", title=f"Multi-agent baselines on marl_eval{where}")
    ax.grid(alpha=0.3)
    ax.legend()
    written.append(_save(fig, folder, "marl_baselines"))
    return written


def plot_structured(s: dict, folder: str) -> list[str]:
    """Grouped bars: the planners' mean overlap on structured_eval per family (and over all of them)."""
    import matplotlib.pyplot as plt
    plans = s["planners"]
    groups = [*s["maps"], "all"]
    fig, ax = plt.subplots(figsize=(9, 4))
    width = 0.8 / len(plans)
    for k, (name, r) in enumerate(plans.items()):
        bars = ax.bar(np.arange(len(groups)) + k * width, [r[g]["overlap"] for g in groups], width, label=name)
        for bar, g in zip(bars, groups):
            if r[g]["completion"] < 1:  # an incomplete path: hatched
                bar.set_hatch("//")
    ax.set_xticks(np.arange(len(groups)) + 0.4 - width / 2, groups)
    ax.set(ylabel="mean overlap $O_v$", title=f"Planners on structured_eval ({sum(s['maps'].values())} maps, "
           f"{s['per_band']} per family and size band)")
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=8, ncol=2)
    return [_save(fig, folder, "planners_structured")]


def plot_rainbow(rb: dict, c: dict, folder: str) -> list[str]:
    import matplotlib.pyplot as plt
    sizes = sorted(rb["full"], key=int)
    r = rb.get("camera_range", CAMERA_RANGE)
    args = rb["model"]["args"]
    teacher = ("greedy_far_first" if args.get("heuristic_far_first") else  # the heuristic the model imitated
               "greedy_dead_ends" if args.get("heuristic_dead_ends") else "greedy")
    fig, ax = plt.subplots(figsize=(9.5, 4))
    for key, stat, label in (("full", "overlap", "rainbow + heuristic fallback"),
                             ("full_no_heuristic", "overlap_completed", "rainbow alone (completed maps)"),
                             (f"camera_r{r}", "overlap", f"rainbow, camera r = {r}"),
                             ("greedy", "overlap", "greedy planner"),
                             ("greedy_dead_ends", "overlap", "greedy-dead-ends planner"),
                             ("greedy_far_first", "overlap", "greedy-far-first planner")):
        if key not in rb:
            continue
        label += " (the teacher)" if key == teacher else ""
        ax.plot([int(z) for z in sizes], [rb[key][z][stat] for z in sizes], marker=".", label=label)
    lkh = c["cpp_eval"]["lkh"]
    bands = [b for b in lkh if "-" in b]
    ax.plot([np.mean([int(x) for x in b.split("-")]) for b in bands], [lkh[b] for b in bands], "k*",
            label="LKH (size-band means)")
    if "lower_bound" in rb:
        ax.plot([int(z) for z in sizes], [rb["lower_bound"][z] for z in sizes], "k--", lw=0.8,
                label="lower bound (no walk below)")
    ax.axhline(REFERENCE["rainbow_cpp_overlap"], color="grey", ls=":", label=f"target {REFERENCE['rainbow_cpp_overlap']}")
    ax.set(xlabel="map size (edge, cells)", ylabel="mean overlap $O_v$", yscale="log",
           title=f"rainbow_cpp on cpp_eval ({rb['per_size']} maps per size)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1))  # outside: the curves fill the plot
    return [_save(fig, folder, "rainbow_cpp")]


def plot_marl(mr: dict, c: dict, folder: str) -> list[str]:
    import matplotlib.pyplot as plt
    agents = sorted(mr["agents"], key=int)
    n_axis = [int(n) for n in agents]
    marl = c["marl_eval"]
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4))
    left.plot(n_axis, [mr["agents"][n]["time_save"] for n in agents], marker="o", label="rainbow_marl + heuristic")
    left.plot(n_axis, [mr["agents"][n]["greedy"] for n in agents], marker=".", label="greedy planner (claims)")
    left.plot(n_axis, [mr["agents"][n]["greedy_dead_ends"] for n in agents], marker=".",
              label="greedy-dead-ends planner (claims)")
    base = sorted(marl, key=int)
    left.plot([int(n) for n in base], [marl[n]["partition"] for n in base], "s", label="partition planner")
    left.plot(n_axis, [1 / n for n in n_axis], "k--", label="1/N")
    left.set(xlabel="agents N", ylabel="mean time-save factor $t_{sf}$", yscale="log",
             title=f"marl_eval, sizes {_sizes(mr['agents'][agents[0]]['by_size'])}")
    for n in [n for n in ("2", "5", "10", "15") if n in mr["agents"]]:
        by = mr["agents"][n]["by_size"]
        right.plot([int(z) for z in by], list(by.values()), marker=".", label=f"N = {n}")
    right.set(xlabel="map size (edge, cells)", ylabel="mean $t_{sf}$", yscale="log", title="rainbow_marl by size")
    for ax in (left, right):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    return [_save(fig, folder, "rainbow_marl")]


def plot_tabular(fig55: dict | None, runs: dict, folder: str) -> list[str]:
    import matplotlib.pyplot as plt
    keyed, algorithms = _fig5_4_runs(runs)
    written = []
    if algorithms:
        fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
        for ax, obstacles in zip(axes, (0, 1)):
            for a in algorithms:
                run = keyed[(a, obstacles, True)]
                x = (np.arange(len(run["curve_rho"])) + 1) * run["curve_window"]
                ax.plot(x, run["curve_rho"], label=a)
            args = keyed[(algorithms[0], obstacles, True)]["args"]
            ax.set(xlabel="training episode", title=f"{args['size']}x{args['size']}, "
                   f"{'corner' if args['corner_starts'] else 'random'} starts, {obstacles} obstacle(s)")
            ax.grid(alpha=0.3)
        axes[0].set_ylabel(f"mean ρ per {keyed[(algorithms[0], 0, True)]['curve_window']:,} episodes")
        axes[0].legend()
        written.append(_save(fig, folder, "fig5_4"))
    if fig55 is not None:
        settings, a = fig55["settings"], fig55["model"]["args"]
        fig, ax = plt.subplots(figsize=(7, 4))
        for obstacles in sorted({s["obstacles"] for s in settings}):
            row = [s for s in settings if s["obstacles"] == obstacles]
            ax.plot([s["size"] for s in row], [s["trained"] for s in row], marker="o", label=f"{obstacles} obstacles")
        ax.set(xlabel=f"map size N (trained on {a['min_size'] if a.get('min_size') is not None else a['size']}-{a['size']})",
               ylabel="mean ρ", title=f"{ALGORITHM_NAMES.get(a['algorithm'], a['algorithm'])} table on ch5_eval")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        written.append(_save(fig, folder, "fig5_5"))
    return written


def plot_sensors(sr: dict, folder: str) -> list[str]:
    """Figs. 6.20-6.21: mean overlap against the sensor range, the agent and the frontier baseline, per sensor."""
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for ax, name in zip(axes, ("cpp_eval", "structured_eval")):
        e = sr[name]
        for sensor, colour in (("camera", "tab:blue"), ("lidar", "tab:orange")):
            ks = [k for k in SENSOR_RANGES if f"{sensor}_r{k}" in e]
            for policy, style in (("rainbow", "-o"), ("frontier", "--s")):
                ax.plot(ks, [e[f"{sensor}_r{k}"][policy]["overlap"] for k in ks], style, color=colour,
                        label=f"{policy}, {sensor}")
        ax.axhline(e["full"]["rainbow"]["overlap"], color="grey", lw=1, label="rainbow, full information")
        ax.set(xlabel="sensor range K", title=name, xticks=list(SENSOR_RANGES))
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("mean overlap $O_v$")
    axes[1].legend(fontsize=8)
    return [_save(fig, folder, "sensors")]


def plot_scale(scale: dict, refs: dict | None, folder: str, key: str = "rainbow_cpp_scale", run: str = "scale run",
               references: tuple[str, ...] = (*SCALE_REFERENCES, "rainbow")) -> list[str]:
    """A run's learning curve (the scale run's, or under `key` another's): mean overlap with the fallback on its two
    held-out sets against environment steps, and completion without the fallback; the `references` on the same maps
    as horizontal lines."""
    import matplotlib.pyplot as plt
    if not scale["curve"]:
        return []
    steps = [p["step"] / 1e6 for p in scale["curve"]]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    colours = {"greedy": "tab:red", "greedy-far-first": "tab:orange", "lkh": "tab:green", "rainbow": "tab:purple"}
    label = {"rainbow": "shipped rainbow_cpp", "greedy": "greedy (dissertation's heuristic)"}
    for ax, name in zip(axes, ("cpp_eval", "structured_eval")):
        ax.plot(steps, [p[name]["overlap"] for p in scale["curve"]], "o-", color="black", label=f"{run} (+ fallback)")
        for ref, row in ((refs or {}).get(name) or {}).items():
            if ref in references:
                ax.axhline(row["overlap"], ls="--", color=colours.get(ref, "grey"), label=label.get(ref, ref))
        ax.set(title=f"{name}: mean overlap with the fallback", xlabel="environment steps (M)", ylabel="mean overlap",
               xlim=(0, max(steps) * 1.05), ylim=(0, None))
        ax.legend(fontsize=8)
    for name in ("cpp_eval", "structured_eval"):
        axes[2].plot(steps, [100 * p[f"{name}_alone"]["completion"] for p in scale["curve"]], "o-", label=name)
    axes[2].axhline(100 * REFERENCE["fig_6_16_completion"], ls=":", color="grey",
                    label=f"dissertation: {100 * REFERENCE['fig_6_16_completion']:.1f}%")
    axes[2].set(title="completion without the fallback", xlabel="environment steps (M)", ylabel="% of maps",
                xlim=(0, max(steps) * 1.05), ylim=(0, 101))
    axes[2].legend(fontsize=8)
    return [_save(fig, folder, key)]


def plot_scale_figures(figs: dict, folder: str) -> list[str]:
    """Figs. 6.13-6.16: box plots of the overlap at sizes 5-30 with the fallback and without it (completed episodes),
    the mean, ±2σ and range by size with the fallback, and the outliers by size without it."""
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(2, 2, figsize=(13, 8))
    boxed = [str(z) for z in FIGURES_BOX_SIZES if str(z) in figs["fallback"]]
    for ax, key, title in ((axes[0, 0], "fallback", "Fig. 6.13: with the fallback"),
                           (axes[0, 1], "alone", "Fig. 6.14: without it (completed episodes)")):
        data = [[o for o, c in zip(figs[key][z]["overlap"], figs[key][z]["completed"]) if c] or [np.nan] for z in boxed]
        ax.boxplot(data, whis=1.5)
        ax.set_xticks(range(1, len(boxed) + 1), [f"{z}×{z}" for z in boxed])
        ax.set(title=title, xlabel="map size", ylabel="overlap")
    sizes = [int(z) for z in figs["fallback"]]
    overlaps = [np.array(f["overlap"]) for f in figs["fallback"].values()]
    mean, std = np.array([o.mean() for o in overlaps]), np.array([o.std() for o in overlaps])
    ax = axes[1, 0]
    ax.fill_between(sizes, np.maximum(mean - 2 * std, 0), mean + 2 * std, alpha=0.25, label="±2σ")
    ax.plot(sizes, mean, "o-", label="mean")
    ax.plot(sizes, [o.max() for o in overlaps], "v:", label="max")
    ax.plot(sizes, [o.min() for o in overlaps], "^:", label="min")
    ax.axhline(REFERENCE["fig_6_15_overlap"], ls="--", color="grey", label="§6.5.2: mean below this")
    ax.set(title="Fig. 6.15: overlap by size, with the fallback", xlabel="map size", ylabel="overlap", ylim=(0, None))
    ax.legend(fontsize=8)
    ax = axes[1, 1]
    ax.bar(sizes, [_outliers(a) for a in figs["alone"].values()], color="tab:red")
    ax.set(title=f"Fig. 6.16: outliers without the fallback (overlap > {REFERENCE['outlier_overlap']} or truncated)",
           xlabel="map size", ylabel=f"episodes of {figs['per_size']}")
    fig.suptitle(f"The scale run's model at {figs['model']['global_step']:,} steps on cpp_eval")
    return [_save(fig, folder, "scale_figures")]


def plot(results: dict, folder: str) -> list[str]:
    """Every figure the results allow, written into `folder`; the paths written."""
    import matplotlib
    matplotlib.use("Agg")
    paths = results["paths"]
    classical = planners(results)
    with reading(paths["classical"]):
        written = plot_classical(classical, folder)
    if "structured_eval" in classical:
        with reading(paths["classical"] if "structured_eval" in results["classical"] else paths["structured"]):
            written += plot_structured(classical["structured_eval"], folder)
    if results["rainbow_cpp"] is not None:
        with reading(paths["rainbow_cpp"]):
            written += plot_rainbow(results["rainbow_cpp"], results["classical"], folder)
    if results["sensors"] is not None:
        with reading(paths["sensors"]):
            written += plot_sensors(results["sensors"], folder)
    if results["rainbow_marl"] is not None:
        with reading(paths["rainbow_marl"]):
            written += plot_marl(results["rainbow_marl"], results["classical"], folder)
    with reading(paths["tabular"] or paths["fig5_4"] or "the tabular results"):
        written += plot_tabular(results["tabular"], results["fig5_4"], folder)
    if results["rainbow_cpp_scale"] is not None:
        with reading(paths["rainbow_cpp_scale"]):
            written += plot_scale(results["rainbow_cpp_scale"], results["scale_references"], folder)
    if results["td_finetune"] is not None:
        with reading(paths["td_finetune"]):
            td = results["td_finetune"]
            written += plot_scale(td, same_maps(td, results["scale_references"]), folder, "td_finetune", "TD fine-tuning",
                                  TD_REFERENCES)
    if results["scale_figures"] is not None:
        with reading(paths["scale_figures"]):
            written += plot_scale_figures(results["scale_figures"], folder)
    return written


# ----------------------------------------------------------------------------- command line
@dataclass
class Collect:
    """Run the experiments and write their JSON under --out (every part: ~55 min of planners, then the agents)."""
    out: str = RESULTS
    """folder for the results JSON"""
    parts: tuple[str, ...] = tuple(PARTS)
    """results to collect: classical (the planners, structured_eval and rollout included), structured (the planners
    on structured_eval alone), rollout (the rollout planner alone on classical's cpp_eval and MovingAI maps),
    team_rollout (the multiagent rollout planner on marl_eval at N = 2, 5, 10 and structured_eval at N = 5: ~45 min on
    one core), sensors (rainbow_cpp's model beside the frontier baselines under camera and LiDAR of range 1-5 and
    sensor failures, Figs. 6.17-6.22), rainbow_cpp, rainbow_marl, tabular, scale_references (the planners and the
    shipped model on the scale run's held-out maps: ~20 min on one core, most of it LKH), rainbow_cpp_scale (the scale
    run's learning curve, read from its committed checkpoint: seconds), scale_figures (Figs. 6.13-6.16 of the scale run's
    model on all of cpp_eval), td_finetune (the TD fine-tuning's curve from its committed checkpoint, and its model
    beside the shipped one and greedy-far-first on all of structured_eval and the fresh per-family maps: ~30 min on one
    core)"""
    reuse: bool = False
    """collect only the parts whose JSON is missing under --out"""
    overwrite: bool = False
    """replace a part's JSON already under --out (the committed results/ by default); without it, or --reuse, such a
    part is an error and nothing runs"""
    per_size: int = 20
    """maps per cpp_eval size for the planner comparison (LKH takes seconds per map) and rainbow_cpp"""
    p2p_maps: int = 1000
    """p2p_eval scenarios for the point-to-point evaluation (of 10,000)"""
    structured_per_band: int = classical_cpp.STRUCTURED_PER_BAND
    """structured_eval maps per family and size band for the planners (classical, structured)"""
    quiet: bool = False
    """no progress bars"""


@dataclass
class All(Collect):
    """Collect (every part, or with --reuse the missing ones), then render RESULTS.md and plot the figures."""


@dataclass
class Render:
    """RESULTS.md from the JSON under --out; nothing is re-run."""
    out: str = RESULTS
    """folder of the results JSON; RESULTS.md is written there"""


@dataclass
class Plot:
    """The PNG figures from the JSON under --out; nothing is re-run."""
    out: str = RESULTS
    """folder of the results JSON; the figures are written there"""


Command = (Annotated[All, tyro.conf.subcommand("all", default=All())]
           | Annotated[Collect, tyro.conf.subcommand("collect", default=Collect())]
           | Annotated[Render, tyro.conf.subcommand("render", default=Render())]
           | Annotated[Plot, tyro.conf.subcommand("plot", default=Plot())])


CLI_CONFIG = (tyro.conf.CascadeSubcommandArgs,)  # the default subcommand's flags select it: no subcommand name needed


def cli(args: list[str] | None = None) -> Collect | Render | Plot:
    """`python report.py [all|collect|render|plot] ...`; no subcommand is `all`."""
    return gridworld.cli(Command, default=All(), args=args, description=__doc__, config=CLI_CONFIG)


def main(command: Collect | Render | Plot) -> list[str]:
    """Run a report command; every file is written under a staging folder and moved under --out at the end."""
    with staged(command.out, getattr(command, "overwrite", False)) as tmp:
        if isinstance(command, Collect):
            collect(command, tmp)
        if isinstance(command, (All, Render)):
            with open(os.path.join(tmp, "RESULTS.md"), "w") as f:
                f.write(render(load_results(tmp, command.out)))
        if isinstance(command, (All, Plot)):
            plot(load_results(tmp, command.out), tmp)
        written = sorted(os.path.relpath(os.path.join(d, n), tmp) for d, _, files in os.walk(tmp) for n in files)
    print(f"wrote {', '.join(written) or 'nothing'} into {command.out}")
    return written


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, lambda *_: sys.exit("error: stopped by SIGTERM; --out is as it was"))  # staging removed
    try:
        main(cli())
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
