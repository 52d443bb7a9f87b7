"""Modified Rainbow DQN for single-agent robotic navigation (dissertation chapter 6).

    python rainbow_cpp.py                                  # Tables 6.2 then 6.3 (31 M steps each)
    python rainbow_cpp.py --stage-steps-scale 0.01 --hidden 256 --num-envs 16    # a short run
    python rainbow_cpp.py --resume --run-name NAME         # continue an interrupted run

Double DQN target, prioritized replay (sum tree), dueling streams of factorised-Gaussian noisy
layers, n-step returns (n = 1 by default), soft target updates every learning period K, and
the training features of §6.4.2: partial episode bootstrapping, partial resetting, the
challenging-episode buffer, imitation of the navigation heuristic and uncommon patterns. Acting
is batched over `num_envs` worlds of one gridworld core; the replay buffer keeps one compact
frame per step in a segment per world and rebuilds frame stacks and next states when sampled.
TensorBoard logs go to runs/RUN (CleanRL's tags), checkpoints to runs/RUN/checkpoint.pt and the
deployable weights (mean weights, fp16) to models/ with a JSON of how they were trained.
"""
from __future__ import annotations

import json
import os
import random
import signal
import time
from dataclasses import asdict, dataclass

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F
import tyro

import gridworld

# Tables 6.2 (full information) and 6.3 (camera): the default curriculum
STAGES = [dict(name=f"{kind}{i + 1}", base_steps=steps, size=size, min_size=min_size, random_size=True,
               number_obstacles=obstacles, obstacles_random=True, random_coverage=kind == "fi",
               sensor="full" if kind == "fi" else "camera", sensor_range=sensor_range)
          for kind, ranges in (("fi", (3,) * 6), ("camera", (3, 3, 3, 4, 4, 3)))
          for i, (steps, size, min_size, obstacles, sensor_range) in enumerate(zip(
              (1_000_000, 2_000_000, 3_000_000, 5_000_000, 10_000_000, 10_000_000),
              (5, 10, 15, 20, 25, 30), (4, 5, 10, 10, 15, 5), (5, 10, 20, 30, 40, 50), ranges))]


@dataclass
class Args:
    run_name: str = "rainbow_cpp"
    """folder under runs/ for TensorBoard logs and the checkpoint"""
    seed: int = 1
    """seed of numpy, torch and the environment"""
    stages: str | None = None
    """YAML file of named environments (Table 4.1 keys, `base_steps` each); default: Tables 6.2
    then 6.3"""
    camera_stages: bool = True
    """with the default curriculum, continue with the camera stages of Table 6.3"""
    stage_steps_scale: float = 1.0
    """multiply every stage's base_steps (Tables 6.2 and 6.3 are 31 M steps each)"""
    total_steps: int = 0
    """stop after this many environment steps (0: the whole schedule)"""
    num_envs: int = 16
    """worlds acted in together (one forward pass for all)"""
    buffer_size: int = 1_000_000
    """replay memory in transitions (Table 6.1)"""
    learning_rate: float = 5e-5
    """Adam learning rate"""
    adam_eps: float = 1.56e-4
    """Adam epsilon (0.005 / batch size)"""
    gamma: float = 0.999
    """discount factor"""
    tau: float = 0.04
    """soft target update factor (eq. 6.19)"""
    batch_size: int = 32
    """transitions per gradient step"""
    learning_starts: int = 5000
    """environment steps before learning (filled by the heuristic, §6.4.2.4 condition 1)"""
    demonstration_steps: int = 0
    """environment steps acted by the heuristic alone (§6.4.2.4 condition 1, extended past
    learning_starts): updates before then learn from its demonstrations, as DQfD's
    pre-training; 0: until learning_starts"""
    replay_ratio: float = 8.0
    """sampled transitions per environment step: Table 6.1's batch 32 every K = 4 steps is 8; the
    noise is resampled and the target soft-updated at every gradient step"""
    n_step: int = 1
    """multi-step return length n"""
    frame_stack: int = 3
    """stacked frames of map, last action and out-of-bounds (§6.3.2.7)"""
    alpha: float = 0.5
    """priority exponent"""
    beta_start: float = 0.4
    """importance-sampling correction, annealed linearly to 1 over the run"""
    max_grad_norm: float = 2.5
    """gradient L2 norm clip"""
    sigma0: float = 0.5
    """noisy layers' initial standard deviation"""
    hidden: int = 512
    """width of the two hidden layers of each dueling stream"""
    peb: bool = True
    """partial episode bootstrapping: truncation is not termination (§6.4.2.1)"""
    partial_reset: bool = True
    """continue a truncated episode, completed by the heuristic (§6.4.2.2)"""
    challenging: float = 0.5
    """chance a new episode replays one the agent failed (§6.4.2.3; 0 disables)"""
    challenging_size: int = 1000
    """most failed episodes kept"""
    imitation: float = 0.9
    """chance the heuristic acts when a §6.4.2.4 condition holds (0 disables)"""
    uncommon_patterns: float = 0.5
    """chance an episode starts with up to `uncommon_max` of its cells covered (§6.4.2.5)"""
    uncommon_max: float = 2 / 3
    """largest pre-covered fraction of an uncommon-pattern episode"""
    margin_loss: float = 0.0
    """weight of a DQfD large-margin loss (Hester et al. 2018) pulling Q toward the heuristic's
    action at every replayed state: the heuristic labels each state the agent visits, so the
    imitation is on-policy (DAgger-like); 0 keeps the dissertation's recipe"""
    margin: float = 0.8
    """the margin l(a_E, a) by which the heuristic's action must beat every other action"""
    heuristic_random_ties: bool = False
    """the heuristic breaks ties at random (§6.3.1) instead of by the first cell; the random walk
    overlaps ~4x more (README), so it makes a poorer teacher"""
    heuristic_dead_ends: bool = True
    """of equally near targets the heuristic takes the one with the fewest uncovered neighbours
    first (Warnsdorff's rule, not in the dissertation): half greedy's overlap on cpp_eval, so a
    better teacher and fallback; --no-heuristic-dead-ends for the dissertation's heuristic"""
    eval_every: int = 25_000
    """environment steps between evaluations on held-out cpp_eval maps"""
    eval_maps: int = 32
    """held-out maps per evaluation (cpp_eval sizes up to the current stage's)"""
    save_every: int = 25_000
    """environment steps between checkpoints"""
    resume: bool = False
    """continue runs/RUN/checkpoint.pt (the replay memory restarts empty)"""
    init_from: str | None = None
    """start from these weights (a checkpoint or a models/*.pt export)"""
    export: str = "models/rainbow_cpp.pt"
    """deployable weights written at the end and at each checkpoint"""


# ----------------------------------------------------------------------------- the network
class NoisyLinear(nn.Module):
    """Factorised-Gaussian noisy layer (Fortunato et al.); eq. 6.18. noise(False) zeroes it."""

    def __init__(self, n_in: int, n_out: int, sigma0: float):
        super().__init__()
        self.n_in, self.n_out = n_in, n_out
        bound = 1 / np.sqrt(n_in)
        self.weight_mu = nn.Parameter(torch.empty(n_out, n_in).uniform_(-bound, bound))
        self.bias_mu = nn.Parameter(torch.empty(n_out).uniform_(-bound, bound))
        self.weight_sigma = nn.Parameter(torch.full((n_out, n_in), sigma0 * bound))
        self.bias_sigma = nn.Parameter(torch.full((n_out,), sigma0 * bound))
        self.register_buffer("eps_in", torch.zeros(n_in))
        self.register_buffer("eps_out", torch.zeros(n_out))

    @staticmethod
    def _f(x):
        return x.sign() * x.abs().sqrt()

    def reset_noise(self, on: bool = True):
        if on:
            self.eps_in.copy_(self._f(torch.randn(self.n_in)))
            self.eps_out.copy_(self._f(torch.randn(self.n_out)))
        else:
            self.eps_in.zero_()
            self.eps_out.zero_()

    def forward(self, x):
        weight = self.weight_mu + self.weight_sigma * torch.outer(self.eps_out, self.eps_in)
        return F.linear(x, weight, self.bias_mu + self.bias_sigma * self.eps_out)


class QNetwork(nn.Module):
    """Fig. 6.8: three convolutions over the stacked maps, then dueling noisy streams."""

    def __init__(self, frames: int, view: int, hidden: int, sigma0: float):
        super().__init__()
        self.conv = nn.Sequential(
            nn.Conv2d(4 * frames, 32, 3, 1, 1), nn.ReLU(),
            nn.Conv2d(32, 64, 3, 2), nn.ReLU(),
            nn.Conv2d(64, 64, 3, 2), nn.ReLU(), nn.Flatten())
        with torch.no_grad():
            n_conv = self.conv(torch.zeros(1, 4 * frames, view, view)).shape[1]
        n_in = n_conv + 1 + frames * (5 + 8)  # battery, last actions, out-of-bounds
        self.value = nn.ModuleList([NoisyLinear(n_in, hidden, sigma0), NoisyLinear(hidden, hidden, sigma0),
                                    NoisyLinear(hidden, 1, sigma0)])
        self.advantage = nn.ModuleList([NoisyLinear(n_in, hidden, sigma0), NoisyLinear(hidden, hidden, sigma0),
                                        NoisyLinear(hidden, 4, sigma0)])

    def reset_noise(self, on: bool = True):
        for m in self.modules():
            if isinstance(m, NoisyLinear):
                m.reset_noise(on)

    def forward(self, maps, extras):
        x = torch.cat([self.conv(maps.float() / 255), extras], 1)

        def stream(layers):
            h = x
            for layer in layers[:-1]:
                h = F.relu(layer(h))
            return layers[-1](h)

        advantage = stream(self.advantage)
        return stream(self.value) + advantage - advantage.mean(1, keepdim=True)  # eq. 6.17


# ----------------------------------------------------------------------------- replay memory
class SumTree:
    """Priorities in a binary tree: sampling proportional to priority and updates in O(log n)."""

    def __init__(self, capacity: int):
        self.size = 1 << max(1, (capacity - 1).bit_length())
        self.tree = np.zeros(2 * self.size)

    def update(self, idx: np.ndarray, priority: np.ndarray) -> None:
        node = np.asarray(idx, np.int64) + self.size
        if node.size == 0:
            return
        self.tree[node] = priority
        node = np.unique(node // 2)
        while node[0] >= 1:
            self.tree[node] = self.tree[2 * node] + self.tree[2 * node + 1]
            if node[0] == 1:
                break
            node = np.unique(node // 2)

    def total(self) -> float:
        return float(self.tree[1])

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """n leaves, one from each of n equal slices of the total mass (stratified)."""
        u = (np.arange(n) + rng.random(n)) * self.total() / n
        node = np.ones(n, np.int64)
        while node[0] < self.size:
            left = self.tree[2 * node]
            right = u > left
            u = np.where(right, u - left, u)
            node = 2 * node + right
        return np.minimum(node - self.size, self.size - 1)


class Replay:
    """One compact frame per step in a ring segment per world, so stacks and next states are
    neighbouring slots of the same world. A frame: the map bit-packed (841 bytes for 4x41x41)
    plus the four compressed edge lines raw, out-of-bounds, last action and battery."""

    def __init__(self, capacity: int, worlds: int, view: int, frames: int, n_step: int, gamma: float,
                 alpha: float):
        self.cap, self.worlds, self.V, self.k = capacity // worlds, worlds, view, frames
        self.n_step, self.gamma, self.alpha = n_step, gamma, alpha
        size = self.cap * worlds
        self.bits = np.zeros((size, (4 * view * view + 7) // 8), np.uint8)
        self.edges = np.zeros((size, 4, 4, view), np.uint8)  # rows 1, V-2 and cols 1, V-2
        self.oob = np.zeros((size, 4, 2), np.float16)
        self.last = np.zeros(size, np.int8)
        self.battery = np.zeros(size, np.float16)
        self.action = np.zeros(size, np.int8)
        self.label = np.full(size, -1, np.int8)  # the heuristic's action here (-1: none)
        self.reward = np.zeros(size, np.float32)
        self.terminal = np.zeros(size, bool)  # the transition from this slot terminates
        self.final = np.zeros(size, bool)  # the frame ends its episode (no action taken here)
        self.age = np.zeros(size, np.int64)  # steps since the episode's first frame
        self.pointer = np.zeros(worlds, np.int64)
        self.filled = np.zeros(worlds, np.int64)
        self.tree = SumTree(size)
        self.max_priority = 1.0

    def bytes_per_transition(self) -> int:
        return sum(a.itemsize * int(np.prod(a.shape[1:])) for a in
                   (self.bits, self.edges, self.oob, self.last, self.battery, self.action, self.label,
                    self.reward, self.terminal, self.final, self.age)) + 16  # + sum-tree leaf

    def add_frames(self, worlds: np.ndarray, obs: dict, age: np.ndarray, final: np.ndarray) -> np.ndarray:
        """Write the current frame of each world; returns the slots written."""
        slot = worlds * self.cap + self.pointer[worlds]
        maps = obs["map"]
        self.bits[slot] = np.packbits((maps > 0).reshape(len(slot), -1), axis=1)
        V = self.V
        self.edges[slot, :, 0] = maps[:, :, 1]
        self.edges[slot, :, 1] = maps[:, :, V - 2]
        self.edges[slot, :, 2] = maps[:, :, :, 1]
        self.edges[slot, :, 3] = maps[:, :, :, V - 2]
        self.oob[slot] = obs["out_of_bounds"]
        self.last[slot] = obs["last_action"].argmax(1)
        self.battery[slot] = obs["battery"][:, 0]
        self.age[slot], self.final[slot] = age, final
        self.tree.update(slot, np.zeros(len(slot)))  # no successor yet
        ahead = worlds * self.cap + (self.pointer[worlds] + np.arange(1, self.k)[:, None]) % self.cap
        self.tree.update(ahead.ravel(), np.zeros(ahead.size))  # their history was just overwritten
        prev = worlds * self.cap + (self.pointer[worlds] - 1) % self.cap
        done_prev = (self.filled[worlds] > 0) & ~self.final[prev] & (age > 0)
        if done_prev.any():  # the previous frame's transition is complete now
            self.tree.update(prev[done_prev], np.full(done_prev.sum(), self.max_priority ** self.alpha))
        self.pointer[worlds] = (self.pointer[worlds] + 1) % self.cap
        self.filled[worlds] = np.minimum(self.filled[worlds] + 1, self.cap)
        return slot

    def set_transition(self, slot: np.ndarray, action: np.ndarray, reward: np.ndarray, terminal: np.ndarray,
                       label: np.ndarray | None = None):
        self.action[slot], self.reward[slot], self.terminal[slot] = action, reward, terminal
        self.label[slot] = -1 if label is None else np.where(label < 4, label, -1)  # WAIT is no move to learn

    def _frames(self, slot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Stacked maps (n, 4k, V, V) uint8 and extras (n, 1 + 13k) for frames ending at slot."""
        V, k = self.V, self.k
        base, pos = slot // self.cap * self.cap, slot % self.cap
        back = np.minimum(self.age[slot][:, None], np.arange(k - 1, -1, -1))  # stay in the episode
        frames = base[:, None] + (pos[:, None] - back) % self.cap  # (n, k) oldest first
        flat = frames.ravel()
        maps = np.unpackbits(self.bits[flat], axis=1, count=4 * V * V).reshape(-1, 4, V, V) * np.uint8(255)
        maps[:, :, 1], maps[:, :, V - 2] = self.edges[flat, :, 0], self.edges[flat, :, 1]
        maps[:, :, :, 1], maps[:, :, :, V - 2] = self.edges[flat, :, 2], self.edges[flat, :, 3]
        last = np.eye(5, dtype=np.float32)[self.last[flat]]
        oob = self.oob[flat].astype(np.float32).reshape(-1, 8) / 100  # counts, scaled
        extras = np.concatenate([self.battery[slot].astype(np.float32)[:, None],
                                 np.concatenate([last, oob], 1).reshape(len(slot), -1)], 1)
        return maps.reshape(len(slot), 4 * k, V, V), extras

    def sample(self, n: int, beta: float, rng: np.random.Generator):
        slot = self.tree.sample(n, rng)
        probs = self.tree.tree[slot + self.tree.size] / self.tree.total()
        valid = (self.tree.tree[self.tree.size:] > 0).sum()
        weights = (valid * np.maximum(probs, 1e-12)) ** -beta
        ret = np.zeros(n, np.float32)
        discount = np.ones(n, np.float32)
        cur = slot.copy()
        alive = np.ones(n, bool)
        for i in range(self.n_step):  # n-step return, stopping at the episode's end
            ret += alive * discount * self.reward[cur]
            discount *= np.where(alive, self.gamma, 1.0)
            alive &= ~self.terminal[cur]
            if i == self.n_step - 1:  # `cur` is the last transition in the return
                break
            nxt = cur // self.cap * self.cap + (cur % self.cap + 1) % self.cap
            stop = alive & (self.final[nxt] | (self.tree.tree[nxt + self.tree.size] == 0))
            cur = np.where(alive & ~stop, nxt, cur)
            alive &= ~stop
            if not alive.any():
                break
        nxt = cur // self.cap * self.cap + (cur % self.cap + 1) % self.cap
        bootstrap = (~self.terminal[cur]).astype(np.float32) * discount
        obs = self._frames(slot)
        next_obs = self._frames(nxt)
        return slot, obs, self.action[slot].astype(np.int64), ret, next_obs, bootstrap, weights / weights.max()

    def update_priorities(self, slot: np.ndarray, td: np.ndarray) -> None:
        priority = np.abs(td) + 1e-6
        self.max_priority = max(self.max_priority, float(priority.max()))
        self.tree.update(slot, priority ** self.alpha)


# ----------------------------------------------------------------------------- helpers
def load_stages(args: Args) -> list[gridworld.EnvConfig]:
    if args.stages:
        stages = list(gridworld.load_config(args.stages).values())
    else:
        stages = [gridworld.EnvConfig.from_dict(s) for s in STAGES if args.camera_stages or s["sensor"] == "full"]
    for s in stages:
        if s.number_agents != 1:
            raise ValueError(f"stage {s.name}: rainbow_cpp is single-agent (number_agents: 1)")
        if s.base_steps <= 0:
            raise ValueError(f"stage {s.name}: base_steps must be > 0")
    return stages


def stage_config(stage: gridworld.EnvConfig, args: Args) -> gridworld.EnvConfig:
    """The stage's settings plus the uncommon-pattern episodes of §6.4.2.5 and a 2-h*w battery
    top-up for partial resets (gridworld.GridWorldCore.recharge)."""
    if stage.random_coverage and args.uncommon_patterns > 0:
        return stage.replace(random_coverage_prob=args.uncommon_patterns, random_coverage_max=args.uncommon_max)
    return stage


def to_torch(maps: np.ndarray, extras: np.ndarray):
    return torch.from_numpy(np.ascontiguousarray(maps)), torch.from_numpy(extras)


class Stacker:
    """The last k frames of every world, for acting (the replay rebuilds its own)."""

    def __init__(self, worlds: int, k: int, view: int):
        self.maps = np.zeros((worlds, k, 4, view, view), np.uint8)
        self.extra = np.zeros((worlds, k, 13), np.float32)
        self.battery = np.zeros((worlds, 1), np.float32)

    def push(self, obs: dict, restart: np.ndarray) -> None:
        extra = np.concatenate([obs["last_action"], obs["out_of_bounds"].reshape(-1, 8) / 100], 1)
        self.maps[:, :-1], self.extra[:, :-1] = self.maps[:, 1:], self.extra[:, 1:]
        self.maps[:, -1], self.extra[:, -1] = obs["map"], extra
        self.maps[restart] = obs["map"][restart][:, None]  # a new episode repeats its first frame
        self.extra[restart] = extra[restart][:, None]
        self.battery = obs["battery"]

    def get(self):
        n = len(self.maps)
        return (self.maps.reshape(n, -1, *self.maps.shape[-2:]),
                np.concatenate([self.battery, self.extra.reshape(n, -1)], 1))


def observe(core: gridworld.GridWorldCore) -> dict:
    return {k: v[:, 0] for k, v in core.observe().items()}


def stuck(since_new: np.ndarray, moved: np.ndarray, size: np.ndarray) -> np.ndarray:
    """§6.4.2.4 conditions 3-4: no new cell in more than M steps (M = map edge), or none and at
    most two cells of displacement in the last five steps."""
    return (since_new > size) | ((since_new >= 5) & (moved <= 2))


def large_margin_loss(q_all: torch.Tensor, label: torch.Tensor, margin: float) -> torch.Tensor:
    """DQfD's J_E = max_a [Q(s, a) + l(a_E, a)] - Q(s, a_E), l = margin except at a_E, averaged
    over the states with a label (label -1: none)."""
    has = label >= 0
    a_e = label.clamp(min=0)
    beaten = (q_all + margin * (1 - F.one_hot(a_e, q_all.shape[1]))).max(1).values
    return ((beaten - q_all.gather(1, a_e[:, None])[:, 0]) * has).sum() / has.sum().clamp(min=1)


def evaluate_policy(q: QNetwork, scenarios: list, frames: int, sensor: str = "full", sensor_range: int = 3,
                    sensor_failure: float = 0.0, heuristic: bool = True, random_ties: bool = False,
                    dead_ends_first: bool = True) -> dict:
    """Run the deterministic policy (noise off) once on each scenario, all at once; with
    `heuristic` the navigation heuristic takes over when the agent is stuck (§6.5.2.1, the
    conditions of §6.4.2.4) and keeps control for as many new cells as the agent has been stuck
    in this episode, so a policy that keeps falling into loops still finishes the map.
    Returns per-episode arrays: gridworld's metrics, `truncated` and `heuristic_steps`."""
    core = gridworld.GridWorldCore(gridworld.EnvConfig(load_state=True, load_random=False, sensor=sensor,
                                                       sensor_range=sensor_range, sensor_failure=sensor_failure),
                                   len(scenarios))
    core.configure(scenarios=scenarios)
    core.reset()
    n = len(scenarios)
    stack = Stacker(n, frames, core.V)
    stack.push(observe(core), np.ones(n, bool))
    done, truncated = np.zeros(n, bool), np.zeros(n, bool)
    since_new, used = np.zeros(n, np.int64), np.zeros(n, np.int64)
    times_stuck, owed = np.zeros(n, np.int64), np.zeros(n, np.int64)  # owed: new cells left to the heuristic
    steps = np.zeros(n, np.int64)  # each world's own, not counting the waits after its end
    history = [core.agent_cells()[:, 0]] * 6  # cells at t-5 .. t
    q.reset_noise(False)
    with torch.no_grad():
        while not done.all():
            active = np.flatnonzero(~done)  # finished worlds cost no forward pass
            maps, extras = stack.get()
            action = np.full(n, gridworld.WAIT)
            action[active] = q(*to_torch(maps[active], extras[active])).argmax(1).numpy()
            if heuristic:
                moved = np.abs(core.agent_cells()[:, 0] - history[0]).sum(1)
                now_stuck = stuck(since_new, moved, core.hw.max(1)) & ~done & (owed == 0)
                times_stuck += now_stuck
                owed = np.where(now_stuck, times_stuck, owed)
                fallback = (owed > 0) & ~done
                if fallback.any():
                    action = np.where(fallback, core.heuristic_actions(random_ties, dead_ends_first)[:, 0], action)
                used += fallback
            ev = core.step(np.where(done, gridworld.WAIT, action)[:, None])
            steps += ~done
            since_new = np.where(ev["new"][:, 0], 0, since_new + 1)
            owed = np.maximum(owed - ev["new"][:, 0], 0)
            history = history[1:] + [core.agent_cells()[:, 0]]
            truncated |= ev["truncated"] & ~done
            done |= ev["terminated"] | ev["truncated"]
            stack.push(observe(core), np.zeros(n, bool))
    q.reset_noise(True)
    m = core.metrics()
    return {**m, "steps": steps, "time_save": steps / np.maximum(m["n_poi_start"], 1),
            "rho": steps / np.maximum(core.n_free, 1),
            "truncated": truncated, "heuristic_steps": used}


def save_checkpoint(path: str, state: dict) -> None:
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    tmp = path + ".tmp"
    torch.save(state, tmp)
    os.replace(tmp, path)  # atomic: a crash never leaves half a checkpoint


def export(q: QNetwork, args: Args, info: dict) -> None:
    """Deployable weights: the noisy layers' means only, fp16, plus how they were trained."""
    weights = {k: v.half() for k, v in q.state_dict().items() if "sigma" not in k and "eps" not in k}
    os.makedirs(os.path.dirname(args.export) or ".", exist_ok=True)
    save_checkpoint(args.export, {"weights": weights, "frames": args.frame_stack, "hidden": args.hidden})
    with open(os.path.splitext(args.export)[0] + ".json", "w") as f:
        json.dump({"args": asdict(args), **info}, f, indent=1)


def load_policy(path: str) -> QNetwork:
    """A deployable export (or a training checkpoint) as a network with noise off."""
    if not os.path.exists(path):
        raise ValueError(f"{path}: no such checkpoint")
    try:
        blob = torch.load(path, map_location="cpu", weights_only=False)
        if not isinstance(blob, dict):
            raise TypeError(f"a {type(blob).__name__}, not a dict")
        frames = blob.get("frames") or blob["args"]["frame_stack"]
        hidden = blob.get("hidden") or blob["args"]["hidden"]
        weights = blob.get("weights") or blob["model"]
        q = QNetwork(frames, 41, hidden, 0.0)
        missing, unexpected = q.load_state_dict({k: v.float() for k, v in weights.items()}, strict=False)
    except Exception as e:  # any unreadable file is a one-line error
        raise ValueError(f"{path}: not a rainbow_cpp model "
                         f"({(str(e).splitlines() or [type(e).__name__])[0]})") from None
    if unexpected or any("sigma" not in k and "eps" not in k for k in missing):
        raise ValueError(f"{path}: weights do not match this network")
    q.reset_noise(False)
    return q.eval()


# ----------------------------------------------------------------------------- training
def main(args: Args) -> None:
    stages = load_stages(args)
    if args.num_envs < 1 or args.buffer_size < 64 * args.num_envs:
        raise ValueError("need num_envs >= 1 and buffer_size >= 64 * num_envs")
    random.seed(args.seed)
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    run_dir = os.path.join("runs", args.run_name)
    checkpoint = os.path.join(run_dir, "checkpoint.pt")
    q = QNetwork(args.frame_stack, 41, args.hidden, args.sigma0)
    target = QNetwork(args.frame_stack, 41, args.hidden, args.sigma0)
    optimizer = torch.optim.Adam(q.parameters(), lr=args.learning_rate, eps=args.adam_eps,
                                 fused=True)  # fused: ~7x faster than the per-tensor loop on CPU
    global_step, stage_index, wall = 0, 0, 0.0
    if args.resume:
        if not os.path.exists(checkpoint):
            raise ValueError(f"{checkpoint}: nothing to resume")
        state = torch.load(checkpoint, map_location="cpu", weights_only=False)
        q.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        global_step, stage_index, wall = state["global_step"], state["stage"], state["wall"]
        rng.bit_generator.state = state["numpy_rng"]
        torch.set_rng_state(state["torch_rng"])
    elif args.init_from:
        q.load_state_dict(load_policy(args.init_from).state_dict() | {
            k: v for k, v in q.state_dict().items() if "sigma" in k or "eps" in k})
    target.load_state_dict(q.state_dict())
    ends = np.cumsum([max(1, int(s.base_steps * args.stage_steps_scale)) for s in stages])
    total = int(min(ends[-1], args.total_steps or ends[-1]))
    core = gridworld.GridWorldCore(stage_config(stages[stage_index], args), args.num_envs, seed=args.seed + global_step)
    B = args.num_envs
    replay = Replay(args.buffer_size, B, core.V, args.frame_stack, args.n_step, args.gamma, args.alpha)
    print(f"replay: {replay.bytes_per_transition()} bytes per transition, "
          f"{replay.bytes_per_transition() * args.buffer_size / 2**30:.2f} GiB for {args.buffer_size:,}")
    from torch.utils.tensorboard import SummaryWriter
    writer = SummaryWriter(run_dir)
    writer.add_text("hyperparameters", "|param|value|\n|-|-|\n" + "\n".join(f"|{k}|{v}|" for k, v in asdict(args).items()))
    eval_set = gridworld.load_dataset(os.path.join(os.path.dirname(os.path.abspath(__file__)), "maps", "cpp_eval.npz"))

    every = np.arange(B)
    core.reset()
    obs = observe(core)
    stack = Stacker(B, args.frame_stack, core.V)
    stack.push(obs, np.ones(B, bool))
    slot = replay.add_frames(every, obs, np.zeros(B, np.int64), np.zeros(B, bool))
    age = np.zeros(B, np.int64)
    since_new = np.zeros(B, np.int64)
    history = [core.agent_cells()[:, 0]] * 6  # cells at t-5 .. t
    demonstrations_end = max(args.learning_starts, args.demonstration_steps)
    teacher = np.full(B, global_step < demonstrations_end)  # §6.4.2.4 condition 1
    continued = np.zeros(B, bool)  # truncated and continued by the heuristic (condition 2)
    returns = np.zeros(B)
    starts = core.snapshot()
    challenging: list = []
    updates_due, last_log, t0 = 0.0, global_step, time.time() - wall
    stop = {"now": False}
    previous_handler = signal.signal(signal.SIGINT, lambda *_: stop.update(now=True))  # Ctrl-C: save, exit

    def save():
        save_checkpoint(checkpoint, {"model": q.state_dict(), "optimizer": optimizer.state_dict(),
                                     "global_step": global_step, "stage": stage_index, "wall": time.time() - t0,
                                     "args": asdict(args), "numpy_rng": rng.bit_generator.state,
                                     "torch_rng": torch.get_rng_state()})
        export(q, args, {"global_step": global_step, "stage": stages[stage_index].name,
                         "wall_seconds": round(time.time() - t0),
                         "machine": f"{os.cpu_count()}-core CPU, {torch.get_num_threads()} torch thread(s)"})

    while global_step < total and not stop["now"]:
        if global_step >= ends[stage_index]:  # the next curriculum stage, at each world's next reset
            stage_index += 1
            core.configure(stage_config(stages[stage_index], args))
        with torch.no_grad():
            action = q(*to_torch(*stack.get())).argmax(1).numpy()
        moved = np.abs(core.agent_cells()[:, 0] - history[0]).sum(1)
        teach = (teacher | continued | stuck(since_new, moved, core.hw.max(1))) & (rng.random(B) < args.imitation)
        label = (core.heuristic_actions(args.heuristic_random_ties, args.heuristic_dead_ends)[:, 0]
                 if teach.any() or args.margin_loss else None)
        if teach.any():
            action = np.where(teach, label, action)
        ev = core.step(action[:, None])
        terminated, truncated = ev["terminated"], ev["truncated"]
        replay.set_transition(slot, action, ev["reward"][:, 0], terminated | (truncated & ~args.peb),
                              label if args.margin_loss else None)
        returns += ev["reward"][:, 0]
        since_new = np.where(ev["new"][:, 0], 0, since_new + 1)
        history = history[1:] + [core.agent_cells()[:, 0]]
        global_step += B
        carry_on = truncated & args.partial_reset
        if carry_on.any():  # §6.4.2.2: a new battery, the heuristic finishes the episode
            core.recharge(np.flatnonzero(carry_on))
            continued |= carry_on
        ended = terminated | (truncated & ~args.partial_reset)
        obs = observe(core)
        slot = replay.add_frames(every, obs, age + 1, ended)
        age += 1
        if ended.any():
            w = np.flatnonzero(ended)
            m = core.metrics()
            for i in w:
                writer.add_scalar("charts/episodic_return", returns[i], global_step)
                writer.add_scalar("charts/episodic_length", m["steps"][i], global_step)
                writer.add_scalar("charts/overlap", m["overlap"][i], global_step)
                writer.add_scalar("charts/solved_alone", float(not continued[i] and not teacher[i]), global_step)
                if continued[i] and args.challenging > 0:  # §6.4.2.3: keep what the agent failed
                    challenging = (challenging + [starts[i]])[-args.challenging_size:]
            replay_old = w[rng.random(len(w)) < args.challenging] if challenging else w[:0]
            picks = [challenging.pop(int(rng.integers(len(challenging)))) for _ in replay_old[:len(challenging)]]
            replay_old = replay_old[:len(picks)]
            fresh = np.setdiff1d(w, replay_old)
            if len(picks):
                core.reset(replay_old, scenarios=picks)
            core.reset(fresh)
            for i, s in zip(w, core.snapshot(w)):
                starts[i] = s
            obs = observe(core)
            slot[w] = replay.add_frames(w, {k: v[w] for k, v in obs.items()}, np.zeros(len(w), np.int64),
                                        np.zeros(len(w), bool))
            age[w] = since_new[w] = returns[w] = 0
            continued[w] = False
            teacher[w] = global_step < demonstrations_end
            for h in history:
                h[w] = core.agent_cells()[w, 0]
        stack.push(obs, ended)

        if global_step > args.learning_starts:
            updates_due += B * args.replay_ratio / args.batch_size
        while updates_due >= 1:
            updates_due -= 1
            beta = args.beta_start + (1 - args.beta_start) * min(1.0, global_step / total)
            idx, (m_, e_), a_, ret, (nm, ne), boot, weight = replay.sample(args.batch_size, beta, rng)
            m_, e_, nm, ne = (torch.from_numpy(np.ascontiguousarray(x)) for x in (m_, e_, nm, ne))
            with torch.no_grad():  # double DQN: the online net picks, the target net values
                best = q(nm, ne).argmax(1, keepdim=True)
                y = torch.from_numpy(ret) + torch.from_numpy(boot) * target(nm, ne).gather(1, best)[:, 0]
            q_all = q(m_, e_)
            q_sa = q_all.gather(1, torch.from_numpy(a_)[:, None])[:, 0]
            loss = (torch.from_numpy(weight.astype(np.float32)) * F.smooth_l1_loss(q_sa, y, reduction="none")).mean()
            if args.margin_loss:
                margin_loss = large_margin_loss(q_all, torch.from_numpy(replay.label[idx].astype(np.int64)),
                                                args.margin)
                loss = loss + args.margin_loss * margin_loss
            optimizer.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(q.parameters(), args.max_grad_norm)
            optimizer.step()
            replay.update_priorities(idx, (y - q_sa).detach().numpy())
            with torch.no_grad():  # eq. 6.19
                for p, tp in zip(q.parameters(), target.parameters()):
                    tp.lerp_(p, args.tau)
            q.reset_noise()
            target.reset_noise()
            if global_step - last_log >= 1000:
                writer.add_scalar("losses/td_loss", loss.item(), global_step)
                writer.add_scalar("losses/q_values", q_sa.mean().item(), global_step)
                if args.margin_loss:
                    writer.add_scalar("losses/margin_loss", margin_loss.item(), global_step)
        if global_step - last_log >= 1000:
            sps = int(global_step / max(time.time() - t0, 1e-9))
            writer.add_scalar("charts/SPS", sps, global_step)
            print(f"step {global_step:,}/{total:,} stage {stages[stage_index].name} SPS {sps}", flush=True)
            last_log = global_step
        if args.eval_every and global_step % args.eval_every < B:
            stage = stages[stage_index]
            pool = [s for s in eval_set if s.obstacles.shape[0] <= max(stage.size, 5)]  # cpp_eval starts at 5
            m = evaluate_policy(q, pool[::max(1, len(pool) // args.eval_maps)][:args.eval_maps], args.frame_stack,
                                stage.sensor, stage.sensor_range, random_ties=args.heuristic_random_ties,
                                dead_ends_first=args.heuristic_dead_ends)
            result = dict(overlap=float(m["overlap"].mean()), completion=float(m["completed"].mean()),
                          heuristic_share=float((m["heuristic_steps"] / np.maximum(m["steps"], 1)).mean()))
            for k, v in result.items():
                writer.add_scalar(f"eval/{k}", v, global_step)
            print(f"eval at {global_step:,}: {result}", flush=True)
        if args.save_every and global_step % args.save_every < B:
            save()
    save()
    writer.close()
    signal.signal(signal.SIGINT, previous_handler)
    print(f"saved {checkpoint} and {args.export} at step {global_step:,}")


if __name__ == "__main__":
    try:
        main(tyro.cli(Args))
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
