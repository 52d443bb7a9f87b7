"""Can the student learn the rollout's departures? An offline probe of issue 17's bottleneck.

    python benchmarks/departures.py --data runs/departures.npz          # collect (~20 min), then train and test
    python benchmarks/departures.py --data runs/departures.npz --epochs 12 --margins 0 1 --check   # reuse the states

Collect: a rainbow_cpp export (--model, with the heuristic fallback, as evaluate.py runs it) walks fresh maps of each
family in turn (sizes --min-size..--size), and every state it visits is labelled with the one-step rollout of
greedy-dead-ends (GridWorldCore.rollout_actions, full view): the DAgger states of the `rollout` teacher. A departure is
a state whose label differs from the hint (the heuristic's own move, which the hinted network sees). The states, with
their frame stacks, are saved to --data (reused when the file exists).

Train: a copy of the model is trained on the first maps' states by cross-entropy of its Q values toward the labels
(departures weighted --departure-weight), --epochs passes, and tested on the held-out maps' states.

Prints, for the model before and after: agreement with the labels, departure recall (the label taken where the label
is a departure), false departures (a move other than the hint where the hint is the label), precision (the label
taken where the student leaves the hint), and per family; the same for the trained copy gated at each --margins; with
--check the gated copies' mean overlap on every 7th structured_eval map; one JSON line with every number. numpy and
torch run on one thread pinned to --cpu.
"""
from __future__ import annotations

import os

from cpu import pin  # sets one BLAS thread: imported before numpy

# isort: split

import copy  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from dataclasses import dataclass  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402
import torch.nn.functional as F  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import evaluate  # noqa: E402
import gridworld as gw  # noqa: E402
import rainbow_cpp as rc  # noqa: E402

FAMILIES = ("random", *gw.STRUCTURED_FAMILIES)


@dataclass
class Args:
    model: str = os.path.join(ROOT, "models", "rainbow_cpp.pt")
    """the hinted rainbow_cpp export that walks the maps and is trained"""
    data: str = "runs/departures.npz"
    """where the labelled states are saved, or read from when the file exists"""
    states: int = 100_000
    """labelled states to collect"""
    worlds: int = 32
    """maps walked at once (one family per batch, in turn)"""
    size: int = 20
    """largest map side"""
    min_size: int = 5
    """smallest map side"""
    test_share: float = 0.2
    """the share of the maps (the last ones walked) held out for the test"""
    fit_share: float = 1.0
    """the share of the other maps trained on (a learning curve: the test maps stay the same)"""
    epochs: int = 6
    """training passes over the training states"""
    departure_weight: float = 2.0
    """the cross-entropy weight of a departure state"""
    min_gain: int = 1
    """train toward departures that save at least this many steps; the others are labelled with the hint"""
    target: str = "labels"
    """"labels": cross-entropy toward the rollout's move; "costs": regress the Q values' differences onto minus
    each move's steps to the end (the rollout's costs, capped at --cost-cap more than the best; a blocked move
    counts as the cap)"""
    cost_cap: float = 10.0
    """--target costs: the largest extra cost a move is given"""
    learning_rate: float = 1e-4
    """Adam's step size"""
    batch_size: int = 256
    """states per update"""
    seed: int = 0
    """maps and shuffling"""
    cpu: int = 0
    """the CPU to pin to (-1: no pinning)"""
    network: str = "model"
    """the student: "model" (a copy of --model, which walks the maps) or "fig6.8" (a fresh hinted Fig. 6.8
    network over the deep observation, the 41x41 window at full resolution; the heuristic walks the maps)"""
    hidden: int = 256
    """--network fig6.8: the streams' width"""
    margins: tuple[float, ...] = (0.0,)
    """test the trained copy gated at each margin: it leaves the hint only where its best Q value beats the hint's
    by more than the margin"""
    check: bool = False
    """also run the trained copy, gated at each margin, on every 7th structured_eval map with the heuristic fallback
    (rainbow_cpp.evaluate_policy, as evaluate.py does) and print the mean overlap"""
    export: str | None = None
    """save the trained copy here (rainbow_cpp.export: weights and a JSON) for evaluate.py --checkpoint; never over
    an existing file"""


def collect(args: Args, q: torch.nn.Module, spec: dict) -> dict:
    """Walk fresh maps with q and the fallback (or with the heuristic where q is None), label every visited state
    with the rollout."""
    observation, frames = rc.observation_settings(spec), spec["frames"]
    channels, view = rc.frame_shape(observation)
    out = {k: [] for k in ("maps", "extras", "label", "cost", "hint", "family", "map")}
    n_states, batch, tick = 0, 0, time.perf_counter()
    while n_states < args.states:
        family = FAMILIES[batch % len(FAMILIES)]
        config = gw.EnvConfig(size=args.size, min_size=args.min_size, random_size=True, map_family=family,
                              number_obstacles=int(0.1 * args.size ** 2), obstacles_random=True, **observation)
        core = gw.GridWorldCore(config, args.worlds, seed=args.seed * 100_003 + batch)
        core.reset()
        n = args.worlds
        stack = rc.Stacker(n, frames, view, channels, hint=True)
        stack.push(rc.observe(core, True), np.ones(n, bool))
        fallback = rc.Fallback(core)
        done = np.zeros(n, bool)
        with torch.no_grad():
            while not done.all():
                live = np.flatnonzero(~done)
                maps, extras = stack.get()
                action = stack.hint.copy()
                if q is not None:
                    action[live] = q(*rc.to_torch(maps[live], extras[live])).argmax(1).numpy()
                out["maps"].append(maps[live])
                out["extras"].append(extras[live])
                label, cost = core.rollout_actions(live, costs=True)
                out["label"].append(label)
                out["cost"].append(cost)
                out["hint"].append(stack.hint[live])
                out["family"].append(np.full(len(live), batch % len(FAMILIES)))
                out["map"].append(batch * n + live)
                n_states += len(live)
                action, _ = fallback.act(core, action, done)
                ev = core.step(np.where(done, gw.WAIT, action)[:, None])
                fallback.stepped(core, ev["new"][:, 0])
                done |= ev["terminated"] | ev["truncated"]
                stack.push(rc.observe(core, True), np.zeros(n, bool))
        batch += 1
        print(f"  {n_states:,} states from {batch * n} maps, {n_states / (time.perf_counter() - tick):.0f} labels/s",
              flush=True)
    return {k: np.concatenate(v) for k, v in out.items()}


def gains(data: dict) -> np.ndarray:
    """The steps the rollout's move saves over the hint's (0 where they agree or nothing was tried)."""
    rows, cost = np.arange(len(data["label"])), data["cost"]
    hint = np.minimum(data["hint"], 3)
    return np.where(data["label"] != data["hint"], cost[rows, hint] - cost[rows, data["label"]], 0).clip(0)


class Gated(torch.nn.Module):
    """A hinted network whose hint move gets `margin` added to its Q value: it leaves the hint only where another
    move's value beats the hint's by more than the margin."""

    def __init__(self, q: torch.nn.Module, margin: float):
        super().__init__()
        self.q, self.margin = q, margin

    def network(self) -> dict:
        return self.q.network()

    def reset_noise(self, on: bool = True):
        self.q.reset_noise(on)

    def forward(self, maps, extras):
        return self.q(maps, extras) + self.margin * extras[:, -rc.HINTS:-1]  # the hint's one-hot, WAIT dropped


def scores(q: torch.nn.Module, data: dict, rows: np.ndarray, margin: float = 0.0) -> dict:
    """Agreement with the labels, departure recall, false departures and the precision of the departures taken over
    `rows`, overall and per family, of q gated at `margin`."""
    gated = Gated(q, margin)
    q.reset_noise(False)
    with torch.no_grad():
        pick = np.concatenate([gated(*rc.to_torch(data["maps"][r], data["extras"][r])).argmax(1).numpy()
                               for r in np.array_split(rows, max(1, len(rows) // 2048))])
    q.reset_noise(True)
    label, hint, family = data["label"][rows], data["hint"][rows], data["family"][rows]
    departure = label != hint

    gain = gains(data)[rows] if "cost" in data else None

    def of(mask):
        dep, kept = mask & departure, mask & ~departure
        saved = {} if gain is None or not dep.any() else {  # the share of the departures' steps the student takes
            "saving_recall": float(gain[dep & (pick == label)].sum() / max(gain[dep].sum(), 1))}
        took = mask & (pick != hint)
        return {"states": int(mask.sum()), "departures": int(dep.sum()), **saved,
                "precision": float((pick == label)[took].mean()) if took.any() else None,
                "agreement": float((pick == label)[mask].mean()) if mask.any() else None,
                "departure_recall": float((pick == label)[dep].mean()) if dep.any() else None,
                "false_departures": float((pick != hint)[kept].mean()) if kept.any() else None}

    return {"all": of(np.ones(len(rows), bool)), **{f: of(family == i) for i, f in enumerate(FAMILIES)}}


def train(q: torch.nn.Module, data: dict, rows: np.ndarray, args: Args, rng: np.random.Generator) -> float:
    """Cross-entropy of q's values toward the labels, departures weighted; returns the seconds it took."""
    optimizer = torch.optim.Adam(q.parameters(), lr=args.learning_rate)
    q.reset_noise(False)  # a supervised fit of the mean weights, which evaluation uses
    label = np.where(gains(data) >= args.min_gain, data["label"], data["hint"]) if "cost" in data else data["label"]
    weight = np.where(label != data["hint"], args.departure_weight, 1.0).astype(np.float32)
    if args.target == "costs":  # minus the extra steps of each move over the best, capped; nothing for untried worlds
        cost = data["cost"].astype(np.float32)
        tried = cost >= 0
        best = np.where(tried, cost, np.inf).min(1, keepdims=True)
        value = -np.minimum(np.where(tried, cost - best, args.cost_cap), args.cost_cap).astype(np.float32)
        value[~tried.any(1)] = np.nan
    tick = time.perf_counter()
    for epoch in range(args.epochs):
        order = rng.permutation(rows)
        total = 0.0
        for i in range(0, len(order), args.batch_size):
            r = np.sort(order[i:i + args.batch_size])
            logits = q(*rc.to_torch(data["maps"][r], data["extras"][r]))
            if args.target == "costs":
                target = torch.from_numpy(value[r])
                ok = ~target[:, 0].isnan()
                centred = logits[ok] - logits[ok].mean(1, keepdim=True)
                loss = (F.smooth_l1_loss(centred, target[ok] - target[ok].mean(1, keepdim=True), reduction="none")
                        .sum(1) * torch.from_numpy(weight[r])[ok]).mean()
            else:
                loss = (F.cross_entropy(logits, torch.from_numpy(label[r]), reduction="none")
                        * torch.from_numpy(weight[r])).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            total += loss.item() * len(r)
        print(f"  epoch {epoch + 1}: loss {total / len(order):.4f} ({time.perf_counter() - tick:.0f} s)", flush=True)
    q.reset_noise(True)
    return time.perf_counter() - tick


def line(name: str, s: dict) -> str:
    def num(value, digits: int) -> str:  # None where a share has no states (a test set without departures): "-"
        return "-" if value is None else f"{value:.{digits}f}"

    a = s["all"]
    fam = " ".join(f"{f} {num(s[f]['departure_recall'], 2)}/{num(s[f]['false_departures'], 3)}" for f in FAMILIES
                   if s[f]["departures"])
    saved = f", saving recall {num(a['saving_recall'], 3)}" if "saving_recall" in a else ""
    return (f"{name}: agreement {num(a['agreement'], 4)}, departure recall {num(a['departure_recall'], 3)}{saved}, "
            f"false departures {num(a['false_departures'], 4)}, precision {num(a['precision'], 3)}  (per family "
            f"recall/false: {fam})")


def main(args: Args) -> None:
    pin(args.cpu)
    torch.set_num_threads(1)
    torch.manual_seed(args.seed)
    if args.target not in ("labels", "costs"):
        raise ValueError(f"--target must be labels or costs, got {args.target!r}")
    if args.network not in ("model", "fig6.8"):
        raise ValueError(f"--network must be model or fig6.8, got {args.network!r}")
    q = rc.load_policy(args.model)
    if not q.network().get("hint"):
        raise ValueError(f"{args.model}: not a hinted network (--hint)")
    walker, spec = q, q.network()
    if args.network == "fig6.8":
        spec = {"network": "fig6.8", "frames": 3, "view": rc.VIEW, "hidden": args.hidden, "hint": True}
        q, walker = rc.build_network(spec, 0.0), None
    if args.export and os.path.exists(args.export):
        raise ValueError(f"--export {args.export}: the file exists")
    if os.path.exists(args.data):
        data = dict(np.load(args.data))
        print(f"{args.data}: {len(data['label']):,} states")
    else:
        print(f"collecting {args.states:,} states with {args.model}")
        data = collect(args, walker, spec)
        with gw.staged_output(args.data, "result", flag="--data") as tmp:  # whole or absent: it is read back
            np.savez(tmp, **data)
    maps = np.unique(data["map"])
    test_maps = maps[int(len(maps) * (1 - args.test_share)):]
    test = np.flatnonzero(np.isin(data["map"], test_maps))
    fit_maps = maps[:int(len(maps) * (1 - args.test_share) * args.fit_share)]
    fit = np.flatnonzero(np.isin(data["map"], fit_maps))
    dep = data["label"] != data["hint"]
    print(f"{len(fit):,} training states ({dep[fit].mean():.2%} departures), {len(test):,} test states "
          f"({dep[test].mean():.2%} departures)")
    before = scores(q, data, test) if walker is not None else None
    if before:
        print(line("before", before))
    student = copy.deepcopy(q)
    seconds = train(student, data, fit, args, np.random.default_rng(args.seed))
    after, after_fit = scores(student, data, test), scores(student, data, fit)
    print(line("after (test)", after))
    print(line("after (train)", after_fit))
    gated, overlap = {}, {}
    for margin in args.margins:
        gated[margin] = scores(student, data, test, margin)
        print(line(f"after (test, margin {margin:g})", gated[margin]))
    if args.check:
        scenarios = [s for _, s in evaluate.scenarios_from(  # evaluate.py's episodes: each map's starts, seeded
            evaluate.Args(dataset=os.path.join(ROOT, "maps", "structured_eval.npz"), every=7))]
        for margin in args.margins:
            run = rc.evaluate_policy(Gated(student, margin), scenarios, spec["frames"])
            overlap[margin] = float(run["overlap"].mean())
            print(f"every 7th structured_eval map (240), margin {margin:g}: overlap {overlap[margin]:.3f}, "
                  f"fallback {run['heuristic_steps'].sum() / run['steps'].sum():.1%}")
    if args.export:
        rc.export(student, args, {"probe": "benchmarks/departures.py", "states": len(data["label"]),
                                  "train_seconds": round(seconds), "parent": rc.lineage(args.model)})
    print(json.dumps({"args": vars(args), "states": len(data["label"]), "train_seconds": round(seconds),
                      "before": before, "after": after, "after_train": after_fit, "gated": gated,
                      "structured_overlap": overlap}))


if __name__ == "__main__":
    with gw.cli_errors():  # a ValueError or Ctrl-C: one line, no traceback
        try:
            main(gw.cli(Args))
        except OSError as e:
            sys.exit(f"error: {e}")
