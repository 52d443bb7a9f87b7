"""Are the rollout's choices between neighbouring points of interest local? A probe of issue 17's bottleneck.

    python benchmarks/tie_features.py                      # ~5 min on one core

Greedy-far-first walks fresh maps of every family (sizes --min-size..--size). At each state where the agent has two
or more uncovered 4-neighbours, the one-step rollout of greedy-far-first (GridWorldCore.rollout_actions,
costs=True) gives each of those moves its steps to cover the map; states where they all cost the same are dropped.
Every candidate cell is described by local features (below). A linear ranking of the features (softmax over the
candidates, cross-entropy toward the cheapest) is fitted on the maps of even index and tested on the others, once
without and once with greedy-far-first's own choice among the features.

Prints, for greedy-far-first's rule and both fits, on the training and held-out states: how often the pick is a
cheapest move, and its mean extra steps over the cheapest; the fitted weights; one JSON line with every number.
If a ranking of local features cannot beat the heuristic here, the rollout's gains rest on what lies beyond the
cell's surroundings. numpy and torch run on one thread pinned to --cpu.
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

FAMILIES = ("random", *gw.STRUCTURED_FAMILIES)
FEATURES = ("uncovered neighbours", "hole", "steps from the start, change", "pieces of the uncovered ring",
            "blocked neighbours", "uncovered diagonals", "uncovered in the 5x5 window", "uncovered run ahead",
            "same move as the last", "steps from the start / farthest")
RUN_CAP = 8  # the run of uncovered cells ahead is counted up to this many


@dataclass
class Args:
    worlds: int = 40
    """maps walked at once, per family"""
    batches: int = 2
    """batches per family (each a fresh draw of --worlds maps)"""
    size: int = 24
    """largest map side"""
    min_size: int = 8
    """smallest map side"""
    seed: int = 700_000
    """maps (no dataset uses these seeds)"""
    iterations: int = 600
    """Adam steps of the fit (full batch)"""
    cpu: int = 0
    """the CPU to pin to (-1: no pinning)"""
    symmetries: int = 1
    """a move's cost is its mean over this many mirrored or turned copies of the world (1, 2, 4, 8:
    GridWorldCore.rollout_actions): the label without the heuristic's arbitrary row-major last tie"""


def shift(a: np.ndarray, dy: int, dx: int, fill) -> np.ndarray:
    """a[:, y + dy, x + dx] at every (y, x), `fill` outside the map."""
    out = np.full_like(a, fill)
    H, W = a.shape[1:]
    out[:, max(-dy, 0):H - max(dy, 0), max(-dx, 0):W - max(dx, 0)] = a[:, max(dy, 0):H + min(dy, 0),
                                                                     max(dx, 0):W + min(dx, 0)]
    return out


def cell_features(todo: np.ndarray, free: np.ndarray, from_start: np.ndarray) -> list[np.ndarray]:
    """Per-cell feature maps (B, H, W) of the points of interest `todo`, in FEATURES order (the move-dependent ones,
    the change of steps, the run ahead and the same move, are filled in by `candidates`)."""
    ring = [shift(todo, dy, dx, False) for dy, dx in ((-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1), (0, -1),
                                                      (-1, -1))]
    degree = sum(ring[0::2]).astype(float)
    pieces = sum(ring[2 * k] & ~(ring[2 * k + 1] & ring[(2 * k + 2) % 8]) for k in range(4)).astype(float)
    blocked = sum(~shift(free, dy, dx, False) for dy, dx in gw.ACTION_DELTAS[:4]).astype(float)
    window = sum(shift(todo, dy, dx, False) for dy in range(-2, 3) for dx in range(-2, 3)).astype(float)
    farthest = np.maximum(from_start.reshape(len(todo), -1).max(1), 1)[:, None, None]
    return [degree, (degree == 0).astype(float), None, pieces, blocked, sum(ring[1::2]).astype(float), window, None,
            None, from_start / farthest]


def candidates(core: gw.GridWorldCore, from_start: np.ndarray, last: np.ndarray, move: np.ndarray):
    """The worlds whose agent has >= 2 uncovered 4-neighbours, and for each its (4, features) rows and a mask of
    the moves onto points of interest; also greedy-far-first's move as a one-hot (4,)."""
    c, H, W = core.c, core.H, core.W
    inner = (slice(None), slice(c, c + H), slice(c, c + W))
    free = ~core.obstacle[inner]
    todo = free & ~core.covered[inner]
    maps = cell_features(todo, free, from_start)
    yx = core.agent_cells()[:, 0]
    ny, nx = yx[:, :1] + gw.ACTION_DELTAS[:4, 0], yx[:, 1:] + gw.ACTION_DELTAS[:4, 1]  # (B, 4)
    inside = (ny >= 0) & (ny < H) & (nx >= 0) & (nx < W)
    ny, nx = np.clip(ny, 0, H - 1), np.clip(nx, 0, W - 1)
    b = np.arange(core.B)[:, None]
    ok = inside & todo[b, ny, nx]
    rows = np.zeros((core.B, 4, len(FEATURES)))
    for f, m in enumerate(maps):
        if m is not None:
            rows[..., f] = m[b, ny, nx]
    rows[..., 2] = from_start[b, ny, nx] - from_start[b[:, 0], yx[:, 0], yx[:, 1]][:, None]
    for a, (dy, dx) in enumerate(gw.ACTION_DELTAS[:4]):
        run, ahead = np.zeros(core.B), np.ones(core.B, bool)
        for k in range(2, RUN_CAP + 2):
            y, x = yx[:, 0] + k * dy, yx[:, 1] + k * dx
            ahead &= (y >= 0) & (y < H) & (x >= 0) & (x < W)
            ahead &= todo[np.arange(core.B), np.clip(y, 0, H - 1), np.clip(x, 0, W - 1)]
            run += ahead
        rows[:, a, 7] = run
    rows[..., 8] = np.arange(4) == last[:, None]
    pick = np.flatnonzero((ok.sum(1) >= 2) & (core.remaining > 0))
    return pick, rows[pick], ok[pick], np.eye(4)[move[pick]]


def collect(args: Args) -> dict[str, np.ndarray]:
    """The labelled states of every family's batches: features (S, 4, F), mask (S, 4), costs (S, 4), the
    heuristic's one-hot (S, 4) and each state's map index (S,)."""
    out = {k: [] for k in ("x", "mask", "cost", "hint", "map")}
    for i, family in enumerate(FAMILIES):
        for batch in range(args.batches):
            config = gw.EnvConfig(size=args.size, min_size=args.min_size, random_size=True, map_family=family,
                                  number_obstacles=int(0.15 * args.size ** 2), obstacles_random=True,
                                  battery_factor=1e6)
            core = gw.GridWorldCore(config, args.worlds, seed=args.seed + 1_000 * i + batch)
            core.reset()
            c, H, W = core.c, core.H, core.W
            from_start = gw._distance_from(~core.obstacle[:, c:c + H, c:c + W], core.start[:, c:c + H, c:c + W])
            last = np.full(core.B, -1)
            first_map = (i * args.batches + batch) * args.worlds
            while (core.remaining > 0).any():
                move = core.heuristic_actions(random_ties=False, dead_ends_first=True, far_first=True)[:, 0]
                pick, x, ok, hint = candidates(core, from_start, last, move)
                if len(pick):
                    _, cost = core.rollout_actions(worlds=pick, far_first=True, costs=True,
                                                  symmetries=args.symmetries)
                    cost = np.where(ok, cost, 0).astype(float)
                    cheapest = np.where(ok, cost, np.inf).min(1)
                    differ = np.where(ok, cost, cheapest[:, None]).max(1) > cheapest
                    for k, v in zip(out, (x, ok, cost, hint, first_map + pick)):
                        out[k].append(v[differ])
                live = core.remaining > 0
                core.step(np.where(live, move, gw.WAIT)[:, None])
                last = np.where(live, move, last)
    return {k: np.concatenate(v) for k, v in out.items()}


def judge(score: np.ndarray, mask: np.ndarray, cost: np.ndarray) -> dict[str, float]:
    """How often the highest-scoring move is a cheapest one, and its mean extra steps."""
    pick = np.where(mask, score, -np.inf).argmax(1)
    cheapest = np.where(mask, cost, np.inf).min(1)
    extra = cost[np.arange(len(pick)), pick] - cheapest
    return {"best": float((extra == 0).mean()), "extra_steps": float(extra.mean())}


def fit(x: np.ndarray, mask: np.ndarray, cost: np.ndarray, iterations: int) -> np.ndarray:
    """Linear weights (on standardised features) of a softmax over the candidates toward the cheapest moves."""
    mu, sd = x[mask].mean(0), x[mask].std(0) + 1e-6
    xs = torch.tensor((x - mu) / sd, dtype=torch.float32)
    m = torch.tensor(mask)
    best = torch.tensor(mask & (cost == np.where(mask, cost, np.inf).min(1, keepdims=True)), dtype=torch.float32)
    target = best / best.sum(1, keepdim=True)
    w = torch.zeros(x.shape[-1], requires_grad=True)
    opt = torch.optim.Adam([w], lr=0.05)
    for _ in range(iterations):
        logits = (xs @ w).masked_fill(~m, -1e9)
        loss = -(target * torch.log_softmax(logits, 1)).sum(1).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return np.concatenate([w.detach().numpy() / sd, [-(w.detach().numpy() / sd) @ mu]])


def main(args: Args) -> None:
    for flag, value in (("--worlds", args.worlds), ("--batches", args.batches), ("--iterations", args.iterations)):
        if value < 1:
            raise ValueError(f"{flag} must be >= 1, got {value}")
    if not 2 <= args.min_size <= args.size <= gw.MAX_MAP_SIDE:
        raise ValueError(f"need 2 <= --min-size <= --size <= {gw.MAX_MAP_SIDE}, got {args.min_size} and {args.size}")
    if args.symmetries not in (1, 2, 4, 8):
        raise ValueError(f"--symmetries must be 1, 2, 4 or 8, got {args.symmetries}")
    pin(args.cpu)
    torch.set_num_threads(1)
    torch.manual_seed(0)
    tick = time.perf_counter()
    d = collect(args)
    train, test = d["map"] % 2 == 0, d["map"] % 2 == 1
    print(f"{len(d['map']):,} states with a choice between neighbours ({train.sum():,} train, {test.sum():,} held "
          f"out), {time.perf_counter() - tick:.0f} s")
    result = {"states": int(len(d["map"])), "heuristic": {}, "linear": {}, "linear_with_hint": {},
              "features": list(FEATURES)}
    for split, rows in (("train", train), ("test", test)):
        result["heuristic"][split] = judge(d["hint"][rows], d["mask"][rows], d["cost"][rows])
    for name, x in (("linear", d["x"]), ("linear_with_hint", np.concatenate([d["x"], d["hint"][..., None]], -1))):
        w = fit(x[train], d["mask"][train], d["cost"][train], args.iterations)
        for split, rows in (("train", train), ("test", test)):
            result[name][split] = judge(x[rows] @ w[:-1], d["mask"][rows], d["cost"][rows])
        result[name]["weights"] = [round(float(v), 4) for v in w[:-1]]
    for name in ("heuristic", "linear", "linear_with_hint"):
        r = result[name]
        print(f"{name:17s} cheapest move taken {r['train']['best']:.3f} / {r['test']['best']:.3f} (train / held out),"
              f" extra steps {r['train']['extra_steps']:.3f} / {r['test']['extra_steps']:.3f}")
    for f, w in zip(FEATURES + ("greedy-far-first's move",), result["linear_with_hint"]["weights"]):
        print(f"  {f:32s} {w:+.3f}")
    result["seconds"] = round(time.perf_counter() - tick, 1)
    print(json.dumps(result))


if __name__ == "__main__":
    with gw.cli_errors():  # a bad flag or Ctrl-C: one line, no traceback
        main(gw.cli(Args))
