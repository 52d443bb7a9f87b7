"""Modified Rainbow DQN for single-agent robotic navigation (dissertation chapter 6).

    python rainbow_cpp.py                                  # Tables 6.2 then 6.3 (31 M steps each)
    python rainbow_cpp.py --stage-steps-scale 0.01 --hidden 256 --num-envs 16    # a short run
    python rainbow_cpp.py --resume --run-name NAME         # continue an interrupted run
    python rainbow_cpp.py --export models/rainbow_cpp.pt   # ship the model (the only way to write models/)

Double DQN, prioritized replay, dueling noisy streams, n-step returns, soft target updates (Table 6.1) and the
training features of §6.4.2, acting in `num_envs` worlds of one batched gridworld core. Everything a run writes
goes under runs/RUN_NAME/ (CleanRL's TensorBoard tags): checkpoint.pt, the deployable rainbow_cpp.pt with its
JSON (flags, steps, provenance, the parent model) and, with --capture-video, videos/step_N.mp4.
"""
from __future__ import annotations

import importlib.util
import math
import os
import random
import time
from dataclasses import asdict, dataclass, replace
from typing import Literal

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

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
    exp_name: str = os.path.basename(__file__)[: -len(".py")]
    """the name of this experiment (the start of the default run name)"""
    seed: int = 1
    """seed of numpy, torch and the environment"""
    run_name: str | None = None
    """folder under runs/ for everything the run writes (default: {exp_name}__{seed}__{unix time}); needed by --resume"""
    threads: int = 0
    """torch CPU threads (0: torch's default); the docs' figures are for one"""
    cuda: bool = True
    """train and act on the GPU when there is one (as CleanRL); --no-cuda keeps everything on the CPU"""
    track: bool = False
    """mirror the TensorBoard logs to Weights & Biases (as CleanRL; needs `pip install wandb`)"""
    wandb_project_name: str = "gridworld-rl"
    """the Weights & Biases project of --track"""
    wandb_entity: str | None = None
    """the Weights & Biases team of --track (default: your own account)"""
    torch_deterministic: bool = True
    """torch.backends.cudnn.deterministic (as CleanRL); no effect on the CPU"""
    quiet: bool = False
    """no progress bar or periodic step lines (evaluations and the end are still printed)"""
    capture_video: bool = False
    """at each evaluation, write runs/RUN/videos/step_N.mp4 of its first episode"""
    stages: str | None = None
    """YAML file of named environments (Table 4.1 keys, `base_steps` each); default: Tables 6.2 then 6.3"""
    camera_stages: bool = True
    """with the default curriculum, continue with the camera stages of Table 6.3"""
    stage_steps_scale: float = 1.0
    """multiply every stage's base_steps (Tables 6.2 and 6.3 are 31 M steps each)"""
    total_steps: int = 0
    """stop after this many environment steps (0: the whole schedule; past it, its last stage goes on)"""
    time_limit: float = 0.0
    """stop after this many minutes of training wall time, resumed time included (0: no limit)"""
    num_envs: int = 16
    """worlds acted in together (one forward pass for all)"""
    buffer_size: int = 1_000_000
    """replay memory in transitions (Table 6.1)"""
    learning_rate: float | None = None
    """Adam learning rate (default: Table 6.1's 5e-5, or a resumed run's own); with --resume it replaces the run's"""
    adam_eps: float = 1.56e-4
    """Adam epsilon (0.005 / batch size)"""
    gamma: float = 0.999
    """discount factor"""
    tau: float = 0.04
    """soft target update factor (eq. 6.19)"""
    batch_size: int = 32
    """transitions per gradient step"""
    learning_starts: int = 5000
    """environment steps before learning, acted by the heuristic (§6.4.2.4 condition 1); on --resume the agent refills as long"""
    demonstration_steps: int = 0
    """environment steps acted by the heuristic alone, past learning_starts (DQfD-like pre-training; 0: none)"""
    replay_ratio: float = 8.0
    """sampled transitions per environment step (Table 6.1: batch 32 every K = 4 steps)"""
    n_step: int = 1
    """multi-step return length n"""
    frame_stack: int | None = None
    """stacked frames (§6.3.2.7); default: the model loaded by --init-from or --resume, else 3"""
    alpha: float = 0.5
    """priority exponent"""
    beta_start: float = 0.4
    """importance-sampling correction, annealed linearly to 1 over the run"""
    max_grad_norm: float = 2.5
    """gradient L2 norm clip"""
    sigma0: float = 0.5
    """noisy layers' initial standard deviation"""
    hidden: int | None = None
    """width of each dueling stream's hidden layers; default: the model loaded, else 512 (Fig. 6.8), 256 (compact)"""
    network: Literal["fig6.8", "compact"] | None = None
    """fig6.8 (Fig. 6.8, deep observation) or compact (multiscale, not in the dissertation); default: the model's"""
    conv_width: int | None = None
    """compact network: convolution channels per scale; default: the model loaded, else 32"""
    scales: int | None = None
    """compact network: scales of the multiscale observation; default: the model loaded, else 3"""
    scale_factor: int | None = None
    """compact network: each scale's blocks are this many times wider than the last; default: the model loaded, else 3"""
    scale_view: int | None = None
    """compact network: blocks across every scale's window (odd); default: the model loaded, else 11"""
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
    """weight of DQfD's large-margin loss toward the teacher's label at every replayed state (DAgger-like; 0: off)"""
    margin: float = 0.8
    """the margin by which the teacher's action must beat every other action"""
    td_weight: float = 1.0
    """weight of the TD loss (0: imitation alone); priorities still follow the TD errors"""
    hint: bool = False
    """give the network the deterministic heuristic's move as an input (not in the dissertation; a model keeps it)"""
    heuristic_random_ties: bool = False
    """the heuristic breaks ties at random (§6.3.1) instead of by the first cell"""
    heuristic_dead_ends: bool = True
    """the heuristic takes equally near targets with the fewest uncovered neighbours first (not in the dissertation)"""
    heuristic_far_first: bool = False
    """the heuristic takes equally near targets farthest from the start first (classical_cpp's greedy-far-first)"""
    teacher: Literal["heuristic", "rollout"] = "heuristic"
    """who acts under §6.4.2.4's conditions and labels for --margin-loss: heuristic, or rollout (its one-step rollout)"""
    eval_every: int = 25_000
    """environment steps between evaluations on held-out cpp_eval maps (0: none)"""
    eval_maps: int = 32
    """held-out maps per evaluation (cpp_eval sizes up to the current stage's)"""
    save_every: int = 25_000
    """environment steps between checkpoints (0: only at the end)"""
    curve_every: int = 0
    """environment steps between learning-curve points on fixed held-out maps, in runs/RUN/curve.json (0: none)"""
    resume: bool = False
    """continue runs/RUN/checkpoint.pt (needs --run-name; the replay memory restarts empty)"""
    init_from: str | None = None
    """start from these weights (a checkpoint or an export such as models/rainbow_cpp.pt)"""
    export: str | None = None
    """deployable weights and their JSON, written at each checkpoint (default: runs/RUN/rainbow_cpp.pt)"""
    overwrite: bool = False
    """let --export replace a model (or its JSON) that was there before this run"""


LEARNING_RATE = 5e-5  # Table 6.1: --learning-rate when a run sets none

# ============================================================================= shared by the two trainers
# From here to "end of the shared code" rainbow_cpp.py and rainbow_marl.py are the same, character for
# character: each script stays self-contained, and tests/test_trainers_shared.py fails on any drift.
SCRIPT = os.path.splitext(os.path.basename(__file__))[0]
HERE = os.path.dirname(os.path.abspath(__file__))
DEEP = {"view_size": gridworld.VIEW_SIZE}  # the deep observation's settings (EnvConfig fields): change it here
OBSERVATION = gridworld.agent_observation_space(gridworld.EnvConfig(**DEEP))  # one agent's deep observation (§6.3.2)
VIEW = OBSERVATION["map"].shape[-1]  # edge of the map window centred on the agent
CHANNELS = OBSERVATION["map"].shape[0]  # points of interest, covered, obstacles, agents
LAST_ACTIONS = OBSERVATION["last_action"].shape[0]  # one-hot, WAIT included
OUT_OF_BOUNDS = OBSERVATION["out_of_bounds"].shape  # [N, S, W, E] x [rows/cols beyond, points of interest beyond]
EXTRAS = LAST_ACTIONS + math.prod(OUT_OF_BOUNDS)  # the vector inputs of one frame, beside the map
OUT_OF_BOUNDS_SCALE = gridworld.OUT_OF_BOUNDS_SCALE  # the out-of-bounds counts (eq. 6.5) enter the network scaled
MOVES = gridworld.WAIT  # the learned actions are the four moves; WAIT is "no action" (§6.3.1)
DISSERTATION = {"hidden": 512, "frame_stack": 3}  # Fig. 6.8's stream width and §6.3.2.7's frames
NETWORKS = ("fig6.8", "compact")  # --network: Fig. 6.8 over the deep observation, or the compact one over the multiscale
SCALE_KEYS = ("scales", "scale_factor", "scale_view")  # the multiscale observation's settings (EnvConfig fields)
HINTS = LAST_ACTIONS  # --hint: the heuristic's proposed move, one-hot with WAIT (no target) as in the last action
COMPACT = {"hidden": 256, "frame_stack": 3, "conv_width": 32,
           **{k: getattr(gridworld.EnvConfig(), k) for k in SCALE_KEYS}}  # the compact network's defaults


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
            self.eps_in.copy_(self._f(torch.randn(self.n_in, device=self.eps_in.device)))
            self.eps_out.copy_(self._f(torch.randn(self.n_out, device=self.eps_out.device)))
        else:
            self.eps_in.zero_()
            self.eps_out.zero_()

    def forward(self, x):
        weight = self.weight_mu + self.weight_sigma * torch.outer(self.eps_out, self.eps_in)
        return F.linear(x, weight, self.bias_mu + self.bias_sigma * self.eps_out)


class Dueling(nn.Module):
    """Fig. 6.8's head: value and advantage streams of noisy layers over the features (eq. 6.17)."""

    def add_streams(self, n_in: int, hidden: int, sigma0: float) -> None:
        for name, n_out in (("value", 1), ("advantage", MOVES)):
            setattr(self, name, nn.ModuleList([NoisyLinear(n_in, hidden, sigma0), NoisyLinear(hidden, hidden, sigma0),
                                               NoisyLinear(hidden, n_out, sigma0)]))

    def reset_noise(self, on: bool = True):
        for m in self.modules():
            if isinstance(m, NoisyLinear):
                m.reset_noise(on)

    def head(self, x: torch.Tensor) -> torch.Tensor:
        def stream(layers):
            h = x
            for layer in layers[:-1]:
                h = F.relu(layer(h))
            return layers[-1](h)

        a = stream(self.advantage)
        return stream(self.value) + a - a.mean(1, keepdim=True)


class QNetwork(Dueling):
    """Fig. 6.8: three convolutions over the stacked maps, then dueling noisy streams."""

    def __init__(self, frames: int, view: int, hidden: int, sigma0: float, hint: bool = False):
        super().__init__()
        self.frames, self.view, self.hidden, self.hint = frames, view, hidden, hint
        self.far_first = False  # the hint's heuristic takes far-first ties (build_network sets it from the spec)
        self.conv = nn.Sequential(
            nn.Conv2d(CHANNELS * frames, 32, 3, 1, 1), nn.ReLU(),
            nn.Conv2d(32, 64, 3, 2), nn.ReLU(),
            nn.Conv2d(64, 64, 3, 2), nn.ReLU(), nn.Flatten())
        with torch.no_grad():
            n_conv = self.conv(torch.zeros(1, CHANNELS * frames, view, view)).shape[1]
        self.add_streams(n_conv + 1 + frames * EXTRAS + HINTS * hint, hidden, sigma0)  # battery, extras, hint

    def network(self) -> dict:
        """What a saved copy needs to be rebuilt and fed (hint: it takes the heuristic's move; far_first: its ties)."""
        return {"network": "fig6.8", "frames": self.frames, "hidden": self.hidden, "view": self.view,
                "extras": EXTRAS, "observation": "deep", "hint": self.hint, "far_first": self.far_first}

    def forward(self, maps, extras):
        return self.head(torch.cat([self.conv(maps.float() / 255), extras], 1))


class CompactQNetwork(Dueling):
    """The compact network (not in the dissertation) over the multiscale observation: per scale three 3x3
    convolutions of `conv_width` channels (the first of stride 2: 11 -> 5 -> 3 -> 1 blocks at scale_view 11),
    run as grouped convolutions (a group per scale, so scales do not mix before the streams), then Fig. 6.8's
    dueling noisy streams over the features, the battery and every frame's extras. Stacked frames come
    frame-major (each frame's scales * 5 channels) and are regrouped scale-major here."""

    def __init__(self, frames: int, hidden: int, sigma0: float, conv_width: int = COMPACT["conv_width"],
                 scales: int = COMPACT["scales"], scale_factor: int = COMPACT["scale_factor"],
                 scale_view: int = COMPACT["scale_view"], hint: bool = False):
        super().__init__()
        self.frames, self.hidden, self.conv_width, self.hint = frames, hidden, conv_width, hint
        self.far_first = False  # the hint's heuristic takes far-first ties (build_network sets it from the spec)
        self.scales, self.scale_factor, self.scale_view = scales, scale_factor, scale_view
        self.view = scale_view
        channels, _ = gridworld.frame_shape({"observation": "multiscale", "scales": scales, "scale_factor": scale_factor,
                                   "scale_view": scale_view})
        self.per_scale = channels // scales
        layers, n_in, size = [], channels * frames, scale_view
        for i in range(3):  # stride 2 first while the window allows; no padding while a 3x3 fits
            stride = 2 if i == 0 and size >= 7 else 1
            pad = 0 if size >= 3 else 1
            layers += [nn.Conv2d(n_in, scales * conv_width, 3, stride, pad, groups=scales), nn.ReLU()]
            n_in, size = scales * conv_width, (size + 2 * pad - 3) // stride + 1
        self.conv = nn.Sequential(*layers, nn.Flatten())
        self.add_streams(scales * conv_width * size * size + 1 + frames * EXTRAS + HINTS * hint, hidden, sigma0)
        order = torch.arange(channels * frames).reshape(frames, scales, self.per_scale).transpose(0, 1).reshape(-1)
        self.register_buffer("scale_major", order, persistent=False)  # frame-major channels -> scale-major

    def network(self) -> dict:
        """QNetwork.network's record plus the conv width and the multiscale settings."""
        return {"network": "compact", "frames": self.frames, "hidden": self.hidden, "conv_width": self.conv_width,
                "view": self.view, "extras": EXTRAS, "observation": "multiscale", "scales": self.scales,
                "scale_factor": self.scale_factor, "scale_view": self.scale_view, "hint": self.hint,
                "far_first": self.far_first}

    def forward(self, maps, extras):
        # scale-major channels, laid out channels-last: oneDNN's grouped convolutions run ~1.7x faster on it on the CPU
        x = maps.permute(0, 2, 3, 1).index_select(3, self.scale_major).float() / 255
        return self.head(torch.cat([self.conv(x.permute(0, 3, 1, 2)), extras], 1))


def build_network(spec: dict, sigma0: float) -> nn.Module:
    """The network a spec describes (network_of's, or a network() record): Fig. 6.8's or the compact one."""
    if spec.get("network", "fig6.8") == "fig6.8":
        q = QNetwork(spec["frames"], spec["view"], spec["hidden"], sigma0, bool(spec.get("hint")))
    else:
        q = CompactQNetwork(spec["frames"], spec["hidden"], sigma0, spec["conv_width"],
                            *(spec[k] for k in SCALE_KEYS), bool(spec.get("hint")))
    q.far_first = bool(spec.get("far_first"))
    return q


def observation_settings(spec: dict) -> dict:
    """The EnvConfig fields of the observation a network's spec (network(), network_of's, or flags) needs."""
    if spec.get("network", "fig6.8") == "fig6.8":
        return {"observation": "deep", **DEEP}
    return {"observation": "multiscale", **{k: spec[k] for k in SCALE_KEYS}}


# ----------------------------------------------------------------------------- replay memory
class SumTree:
    """Priorities in a binary tree: sampling proportional to priority and updates in O(log n); `valid` counts
    the leaves above zero (kept as they change: counting them is O(capacity))."""

    def __init__(self, capacity: int):
        self.size = 1 << max(1, (capacity - 1).bit_length())
        self.tree = np.zeros(2 * self.size)
        self.valid = 0

    def update(self, idx: np.ndarray, priority: np.ndarray) -> None:
        node = np.asarray(idx, np.int64) + self.size
        if node.size == 0:
            return
        leaves = np.unique(node)  # an index given twice counts once (its last priority is kept)
        before = np.count_nonzero(self.tree[leaves] > 0)
        self.tree[node] = priority
        self.valid += np.count_nonzero(self.tree[leaves] > 0) - before
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
    """One compact frame per step in a ring segment per stream (a world, or one agent of a world), so stacks and next
    states are neighbouring slots of the same stream: a deep map as gridworld.pack_frames (1,497 bytes for 4x41x41),
    with `channels` (the multiscale observation, whose block means are not binary) the map as it is (1,815 bytes for
    15x11x11); its out-of-bounds, last action and battery; with `hint` the heuristic's move."""

    def __init__(self, capacity: int, worlds: int, view: int, frames: int, n_step: int, gamma: float,
                 alpha: float, channels: int | None = None, hint: bool = False):
        gridworld.fits_in_memory(capacity * self.transition_bytes(view, channels, hint),  # zero pages until filled, hours on
                       f"--buffer-size {capacity:,}: the replay memory")
        self.cap, self.worlds, self.V, self.k = capacity // worlds, worlds, view, frames
        self.n_step, self.gamma, self.alpha = n_step, gamma, alpha
        self.C, self.packed = channels or CHANNELS, channels is None
        size = self.cap * worlds
        frame = gridworld.packed_frame_bytes(CHANNELS, view) if self.packed else channels * view * view
        self.frames = np.zeros((size, frame), np.uint8)
        self.oob = np.zeros((size, *OUT_OF_BOUNDS), np.float16)
        self.last = np.zeros(size, np.int8)
        self.battery = np.zeros(size, np.float16)
        self.action = np.zeros(size, np.int8)
        self.label = np.full(size, -1, np.int8)  # the teacher's action here (-1: none)
        self.hint = np.full(size, MOVES, np.int8) if hint else None  # the heuristic's move here (--hint)
        self.reward = np.zeros(size, np.float32)
        self.terminal = np.zeros(size, bool)  # the transition from this slot terminates
        self.final = np.zeros(size, bool)  # the frame ends its episode (no action taken here)
        self.age = np.zeros(size, np.int64)  # steps since the episode's first frame
        self.pointer = np.zeros(worlds, np.int64)
        self.filled = np.zeros(worlds, np.int64)
        self.tree = SumTree(size)
        self.max_priority = 1.0

    @staticmethod
    def transition_bytes(view: int, channels: int | None = None, hint: bool = False) -> int:
        """Bytes a transition takes (frame, scalars, sum-tree leaf), known before anything is allocated."""
        frame = gridworld.packed_frame_bytes(CHANNELS, view) if channels is None else channels * view * view
        scalars = 2 * int(np.prod(OUT_OF_BOUNDS)) + 1 + 2 + 1 + 1 + 4 + 1 + 1 + 8  # oob .. age, as __init__ has them
        return frame + scalars + 16 + hint  # + the sum-tree's float64 leaf and its parent's share

    def bytes_per_transition(self) -> int:
        return self.transition_bytes(self.V, None if self.packed else self.C, self.hint is not None)

    def add_frames(self, worlds: np.ndarray, obs: dict, age: np.ndarray, final: np.ndarray) -> np.ndarray:
        """Write the current frame of each stream; returns the slots written."""
        slot = worlds * self.cap + self.pointer[worlds]
        maps = obs["map"]
        self.frames[slot] = gridworld.pack_frames(maps) if self.packed else maps.reshape(len(slot), -1)
        self.oob[slot] = obs["out_of_bounds"]
        self.last[slot] = obs["last_action"].argmax(1)
        self.battery[slot] = obs["battery"][:, 0]
        if self.hint is not None:
            self.hint[slot] = obs["hint"]
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
        self.label[slot] = -1 if label is None else np.where(label < MOVES, label, -1)  # WAIT is no move to learn

    def _frames(self, slot: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Stacked maps (n, Ck, V, V) uint8 (C = 4 channels a deep frame) and extras (n, 1 + 13k, + 5 with the
        hint of the last frame) for frames ending at slot."""
        V, k = self.V, self.k
        base, pos = slot // self.cap * self.cap, slot % self.cap
        back = np.minimum(self.age[slot][:, None], np.arange(k - 1, -1, -1))  # stay in the episode
        frames = base[:, None] + (pos[:, None] - back) % self.cap  # (n, k) oldest first
        flat = frames.ravel()
        maps = (gridworld.unpack_frames(self.frames[flat], CHANNELS, V) if self.packed
                else self.frames[flat].reshape(-1, self.C, V, V))
        last = np.eye(LAST_ACTIONS, dtype=np.float32)[self.last[flat]]
        oob = self.oob[flat].astype(np.float32).reshape(len(flat), -1) / OUT_OF_BOUNDS_SCALE
        extras = [self.battery[slot].astype(np.float32)[:, None], np.concatenate([last, oob], 1).reshape(len(slot), -1)]
        if self.hint is not None:
            extras.append(np.eye(HINTS, dtype=np.float32)[self.hint[slot]])
        return maps.reshape(len(slot), self.C * k, V, V), np.concatenate(extras, 1)

    def sample(self, n: int, beta: float, rng: np.random.Generator):
        slot = self.tree.sample(n, rng)
        probs = self.tree.tree[slot + self.tree.size] / self.tree.total()
        valid = self.tree.valid
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

    def batch(self, n: int, beta: float, rng: np.random.Generator, device: torch.device,
              labels: bool = False) -> tuple[np.ndarray, list[torch.Tensor]]:
        """sample() as tensors on `device`: the slots, then [maps, extras, next maps, next extras, actions, returns,
        bootstrap factors, importance weights] and with `labels` the teacher's actions (-1: none)."""
        slot, (m, e), a, ret, (nm, ne), boot, weight = self.sample(n, beta, rng)
        arrays = [m, e, nm, ne, a, ret, boot, weight.astype(np.float32)] + [self.label[slot].astype(np.int64)] * labels
        return slot, [torch.from_numpy(np.ascontiguousarray(x)).to(device, non_blocking=True) for x in arrays]

    def update_priorities(self, slot: np.ndarray, td: np.ndarray) -> None:
        priority = np.abs(td) + 1e-6
        self.max_priority = max(self.max_priority, float(priority.max()))
        self.tree.update(slot, priority ** self.alpha)


# ----------------------------------------------------------------------------- acting and learning
class Stacker:
    """The last k frames of every stream (a world, or one agent of a world), for acting."""

    def __init__(self, streams: int, k: int, view: int, channels: int = CHANNELS, hint: bool = False):
        self.maps = np.zeros((streams, k, channels, view, view), np.uint8)
        self.extra = np.zeros((streams, k, EXTRAS), np.float32)
        self.battery = np.zeros((streams, 1), np.float32)
        self.hint = np.full(streams, MOVES) if hint else None  # the heuristic's move now (--hint)

    def push(self, obs: dict, restart: np.ndarray) -> None:
        oob = obs["out_of_bounds"]
        extra = np.concatenate([obs["last_action"], oob.reshape(len(oob), -1) / OUT_OF_BOUNDS_SCALE], 1)
        self.maps[:, :-1], self.extra[:, :-1] = self.maps[:, 1:], self.extra[:, 1:]
        self.maps[:, -1], self.extra[:, -1] = obs["map"], extra
        self.maps[restart] = obs["map"][restart][:, None]  # a new episode repeats its first frame
        self.extra[restart] = extra[restart][:, None]
        self.battery = obs["battery"]
        if self.hint is not None:
            self.hint = obs["hint"]

    def get(self):
        n = len(self.maps)
        extras = [self.battery, self.extra.reshape(n, -1)]
        if self.hint is not None:
            extras.append(np.eye(HINTS, dtype=np.float32)[self.hint])
        return self.maps.reshape(n, -1, *self.maps.shape[-2:]), np.concatenate(extras, 1)


def large_margin_loss(q_all: torch.Tensor, label: torch.Tensor, margin: float) -> torch.Tensor:
    """DQfD's J_E = max_a [Q(s, a) + l(a_E, a)] - Q(s, a_E), l = margin except at a_E, averaged
    over the states with a label (label -1: none)."""
    has = (label >= 0).float()
    a_e = label.clamp(min=0)
    beaten = (q_all + margin * (1 - F.one_hot(a_e, q_all.shape[1]))).max(1).values
    return ((beaten - q_all.gather(1, a_e[:, None])[:, 0]) * has).sum() / has.sum().clamp(min=1e-9)


def learn(q: QNetwork, target: QNetwork, optimizer: torch.optim.Optimizer, replay: Replay, args: Args,
          beta: float, rng: np.random.Generator, diagnose: bool = False) -> dict[str, float] | None:
    """One gradient step on a prioritized batch: the double-DQN TD loss (plus --margin-loss times the margin loss),
    new priorities, the soft target update (eq. 6.19) and fresh noise; with `diagnose` the TensorBoard scalars of the
    losses and diagnostics_of."""
    device = gridworld.device_of(q)
    idx, (m_, e_, nm, ne, a_, ret, boot, weight, *label) = replay.batch(args.batch_size, beta, rng, device,
                                                                        labels=bool(args.margin_loss))
    with torch.no_grad():  # double DQN: the online net picks, the target net values
        best = q(nm, ne).argmax(1, keepdim=True)
        y = ret + boot * target(nm, ne).gather(1, best)[:, 0]
    q_all = q(m_, e_)
    q_sa = q_all.gather(1, a_[:, None])[:, 0]
    td_loss = (weight * F.smooth_l1_loss(q_sa, y, reduction="none")).mean()
    loss, margin_loss = args.td_weight * td_loss, None
    if label:
        margin_loss = large_margin_loss(q_all, label[0], args.margin)
        loss = loss + args.margin_loss * margin_loss
    optimizer.zero_grad()
    loss.backward()
    grad_norm = nn.utils.clip_grad_norm_(q.parameters(), args.max_grad_norm)
    optimizer.step()
    replay.update_priorities(idx, (y - q_sa).detach().cpu().numpy())
    logs = diagnostics_of(q, m_, e_, q_all.detach(), (y - q_sa).detach(), weight, grad_norm, {
        "td_loss": td_loss, "q_values": q_sa.mean(), "margin_loss": margin_loss}) if diagnose else None  # before new noise
    with torch.no_grad():  # eq. 6.19, one call for every tensor
        torch._foreach_lerp_(list(target.parameters()), list(q.parameters()), args.tau)
    q.reset_noise()
    target.reset_noise()
    return logs


def diagnostics_of(q: nn.Module, maps: torch.Tensor, extras: torch.Tensor, q_all: torch.Tensor, td_error: torch.Tensor,
                   weight: torch.Tensor, grad_norm: torch.Tensor, losses: dict) -> dict[str, float]:
    """TensorBoard's scalars of an update: the `losses` (losses/*, None: not computed) and what a DQN practitioner
    watches (diagnostics/*): Q's spread and action gap, |TD error|, the smallest importance weight, the gradient
    norm, the noisy sigma and the dead units of each stream's first layer."""
    first = {"value": [], "advantage": []}
    hooks = [getattr(q, k)[0].register_forward_hook(lambda _, __, out, seen=seen: seen.append(out))
             for k, seen in first.items()]
    with torch.no_grad():
        q(maps, extras)
    for hook in hooks:
        hook.remove()
    best_two = q_all.topk(2, 1).values
    sigma = torch.stack([m.weight_sigma.abs().mean() for m in q.modules() if isinstance(m, NoisyLinear)])
    watched = {"q_spread": (q_all.max(1).values - q_all.min(1).values).mean().item(),
               "action_gap": (best_two[:, 0] - best_two[:, 1]).mean().item(), "td_error": td_error.abs().mean().item(),
               "importance_weight_min": weight.min().item(), "grad_norm": float(grad_norm),
               "noisy_sigma": sigma.mean().item(),
               **{f"dead_units_{k}": (seen[0] <= 0).all(0).float().mean().item() for k, seen in first.items()}}
    return ({f"losses/{k}": v.item() for k, v in losses.items() if v is not None}
            | {f"diagnostics/{k}": v for k, v in watched.items()})


# ----------------------------------------------------------------------------- files
def network_of(blob: dict, path: str) -> dict:
    """The network a saved file needs (its network() record, else its flags), checked against gridworld's observation."""
    flags = blob["args"] if isinstance(blob.get("args"), dict) else {}
    kind = blob.get("network", flags.get("network") or "fig6.8")
    if kind not in NETWORKS:
        raise ValueError(f"{path}: a {kind!r} network; the trainers build {' and '.join(NETWORKS)}")
    spec = {"network": kind, "frames": blob.get("frames", flags.get("frame_stack")),
            "hidden": blob.get("hidden", flags.get("hidden")), "extras": blob.get("extras", EXTRAS),
            "hint": bool(blob.get("hint", flags.get("hint", False))),
            "far_first": bool(blob.get("far_first", flags.get("heuristic_far_first", False)))}
    if kind == "compact":
        spec |= {k: blob.get(k, flags.get(k)) for k in ("conv_width", *SCALE_KEYS)}
        spec |= {"view": blob.get("view", spec["scale_view"]), "observation": blob.get("observation", "multiscale")}
    else:
        spec |= {"view": blob.get("view", VIEW), "observation": blob.get("observation", "deep")}
    if not all(isinstance(v, int) and v >= 1 for k, v in spec.items()
               if k not in ("network", "observation", "hint", "far_first")):
        raise ValueError(f"{path}: not a rainbow_cpp / rainbow_marl model (no frame count or hidden width)")
    expected = ("deep", VIEW) if kind == "fig6.8" else ("multiscale", spec["scale_view"])
    if (spec["observation"], spec["view"], spec["extras"]) != (*expected, EXTRAS):
        raise ValueError(f"{path}: a {kind} network for the {spec['observation']} observation, view {spec['view']}, "
                         f"{spec['extras']} extras a frame; {SCRIPT}.py gives it {expected[0]}, view {expected[1]}, "
                         f"{EXTRAS} extras (a changed copy's model: evaluate.py --trainer COPY.py)")
    return spec


def policy_from(blob: dict, path: str) -> QNetwork:
    """The network of a file read by read_model, with its mean weights and noise off."""
    return gridworld.load_mean_weights(build_network(network_of(blob, path), 0.0), blob, path, SCRIPT)


def load_policy(path: str) -> QNetwork:
    """A deployable export (or a training checkpoint) as a network with noise off."""
    return policy_from(gridworld.read_model(path), path)


# ----------------------------------------------------------------------------- the run
def check_flags(args: Args) -> None:
    """The flags both trainers share: a count or a chance out of range, a number that is not finite, a choice not
    offered, more threads than cores or an export outside models/ and runs/ is a one-line error."""
    gridworld.check_ranges(args, {"seed": 0, "total_steps": 0, "num_envs": 1, "buffer_size": 1, "batch_size": 1,
                                  "learning_starts": 0, "demonstration_steps": 0, "n_step": 1, "challenging_size": 1,
                                  "eval_every": 0, "eval_maps": 1, "save_every": 0, "threads": 0, "hidden": 1,
                                  "frame_stack": 1, "conv_width": 1, **{k: 1 for k in SCALE_KEYS}},
                           unit=("challenging", "imitation", "gamma", "tau", "beta_start"),
                           positive=("stage_steps_scale", "learning_rate", "adam_eps"),
                           nonnegative=("replay_ratio", "alpha", "sigma0", "margin_loss", "margin", "max_grad_norm",
                                        "time_limit", "td_weight"))
    if args.threads > (os.cpu_count() or 1):
        raise ValueError(f"--threads {args.threads}: this machine has {os.cpu_count()} cores")
    if args.track and importlib.util.find_spec("wandb") is None:
        raise ValueError("--track needs Weights & Biases: pip install wandb")
    gridworld.check_choices(args)
    if args.export:  # before training, not at the first save
        gridworld.check_export(args.export, f"{SCRIPT}.py")


def settle_flags(args: Args) -> Args:
    """The flags a run trains with: on --resume the run's own (gridworld.resumed_flags), but for those the command
    line may change (gridworld.RESUME_FLAGS: rate, refill, seed, τ); a rate set nowhere is LEARNING_RATE."""
    if args.resume:
        path = os.path.join("runs", gridworld.run_folder(args.run_name, args.exp_name, args.seed, True), "checkpoint.pt")
        saved = gridworld.load_checkpoint(path, SCRIPT).get("args") or {}
        args = replace(args, **gridworld.resumed_flags(args, saved, path, gridworld.RUN_FLAGS, gridworld.RESUME_FLAGS))
    return args if args.learning_rate is not None else replace(args, learning_rate=LEARNING_RATE)


def with_network(args: Args, model: dict | None, source: str | None) -> Args:
    """The network's flags (--network, --hidden, --frame-stack, --conv-width, the scales, --hint): from the model loaded
    (a flag that contradicts it is an error), else as given, else DISSERTATION's or COMPACT's defaults."""
    def pick(flag, key, default=None):
        given, loaded = getattr(args, flag), None if model is None else model.get(key, default)
        if given is not None and loaded is not None and given != loaded:
            raise ValueError(f"--{flag.replace('_', '-')} {given} contradicts {source} ({flag.replace('_', ' ')} {loaded})")
        return loaded if loaded is not None else given

    network = pick("network", "network", "fig6.8") or "fig6.8"
    defaults = DISSERTATION if network == "fig6.8" else COMPACT
    stray = [k for k in ("conv_width", *SCALE_KEYS) if k not in defaults and getattr(args, k) is not None]
    if stray:
        raise ValueError(f"--{stray[0].replace('_', '-')} is for --network compact, not {network}")
    chosen = {"network": network}
    for flag in defaults:
        value = pick(flag, "frames" if flag == "frame_stack" else flag)
        chosen[flag] = defaults[flag] if value is None else value
    if network == "compact":
        gridworld.EnvConfig(**observation_settings(chosen)).validate()
    chosen["hint"] = bool(args.hint or (model or {}).get("hint"))
    return replace(args, **chosen)


def observed(stages: list[gridworld.EnvConfig], args: Args) -> list[gridworld.EnvConfig]:
    """The stages observed as the run's network needs; a stage that asks for another observation is an error."""
    want, out = observation_settings(asdict(args)), []
    for s in stages:
        have = {k: getattr(s, k) for k in want}
        if have != want and s.observation != "deep":
            raise ValueError(f"stage {s.name}: observation {have} but the {args.network} network needs {want}")
        out.append(s if have == want else s.replace(**want))
    return out


def start_run(args: Args, n_stages: int) -> tuple:
    """Seeding, the run folder, the networks and the optimizer, from the checkpoint resumed or the model warm started
    from; only reads, so every bad file or flag is a ValueError before anything is written."""
    random.seed(args.seed)  # CleanRL's seeding
    torch.manual_seed(args.seed)
    torch.backends.cudnn.deterministic = args.torch_deterministic
    if args.threads:
        torch.set_num_threads(args.threads)
    rng = np.random.default_rng(args.seed)
    run_name = gridworld.run_folder(args.run_name, args.exp_name, args.seed, args.resume)
    run_dir = os.path.join("runs", run_name)
    checkpoint = os.path.join(run_dir, "checkpoint.pt")
    state = gridworld.load_checkpoint(checkpoint, SCRIPT) if args.resume else None
    warm = gridworld.read_model(args.init_from) if args.init_from and not args.resume else None
    if state is not None:
        args = with_network(args, network_of(state, checkpoint), checkpoint)
        if args.hint and not network_of(state, checkpoint)["hint"]:
            raise ValueError(f"--hint contradicts {checkpoint} (no hint input); warm-start with --init-from instead")
    else:
        args = with_network(args, None if warm is None else network_of(warm, args.init_from), args.init_from)
    own = args.resume and gridworld.exported_by(args.export, run_name)  # a resumed run's own export is its own to rewrite
    for path in (args.export, os.path.splitext(args.export)[0] + ".json") if args.export else ():
        gridworld.check_output(path, "model", args.overwrite or own, "--export")
    args = replace(args, run_name=run_name, export=args.export or os.path.join(run_dir, f"{SCRIPT}.pt"))
    device = torch.device("cuda" if args.cuda and torch.cuda.is_available() else "cpu")
    spec = {**asdict(args), "frames": args.frame_stack, "view": VIEW, "far_first": args.heuristic_far_first}
    gridworld.check_network_size(lambda: build_network(spec, args.sigma0), "--hidden, --conv-width, --frame-stack")
    q, target = (build_network(spec, args.sigma0).to(device) for _ in range(2))
    optimizer = torch.optim.Adam(q.parameters(), lr=args.learning_rate, eps=args.adam_eps,
                                 fused=True)  # fused: ~7x faster than the per-tensor loop on CPU
    progress, parent = (0, 0, 0.0, []), None  # a fresh run
    if state is not None:
        if not (isinstance(state["stage"], int) and 0 <= state["stage"] < n_stages):
            raise ValueError(f"{checkpoint}: stage {state['stage']} of a curriculum of {n_stages} stages")
        gridworld.restore_run(state, checkpoint, q, target, optimizer, rng, args.learning_rate, args.seed)
        progress = (state["global_step"], state["stage"], state["wall"], list(state.get("curve", [])))
        parent = state.get("parent")
    else:
        if warm is not None:  # transfer (§7.4.2.2): the mean weights, fresh noise
            fresh = q.state_dict()
            q.load_state_dict({k: hinted(v, fresh[k]) for k, v in policy_from(warm, args.init_from).state_dict().items()}
                              | {k: v for k, v in fresh.items() if "sigma" in k or "eps" in k})
            parent = gridworld.lineage(args.init_from)
        target.load_state_dict(q.state_dict())
    return args, run_dir, q, target, optimizer, rng, progress, parent


def hinted(weight: torch.Tensor, fresh: torch.Tensor) -> torch.Tensor:
    """A warm start's weight where the network adds the hint's inputs: zero weights on them, so it starts as the parent."""
    if weight.shape == fresh.shape or weight.dim() != 2 or fresh.shape[1] != weight.shape[1] + HINTS:
        return weight
    return torch.cat([weight, torch.zeros(weight.shape[0], HINTS, dtype=weight.dtype)], 1)


# ============================================================================= end of the shared code
def rollout_labels(core: gridworld.GridWorldCore, label: np.ndarray, teach: np.ndarray,
                   args: Args) -> tuple[np.ndarray, np.ndarray]:
    """--teacher rollout: the heuristic's labels with the rollout's in the worlds the teacher acts in and, with a
    margin loss, in every world, one batched call; returns the labels and the worlds the rollout labelled."""
    w = np.flatnonzero(teach | bool(args.margin_loss))
    label = label.copy()
    label[w] = gridworld.rollout_actions(core, w, args.heuristic_dead_ends, far_first=args.heuristic_far_first)
    return label, w


def load_stages(args: Args) -> list[gridworld.EnvConfig]:
    gridworld.check_ranges(args, {"curve_every": 0}, unit=("uncommon_patterns",))
    if not 0.0 <= args.uncommon_max < 1.0:
        raise ValueError(f"--uncommon-max must be in [0, 1), got {args.uncommon_max}")
    return gridworld.curriculum(args.stages, [s for s in STAGES if args.camera_stages or s["sensor"] == "full"], True)


def stage_config(stage: gridworld.EnvConfig, args: Args) -> gridworld.EnvConfig:
    """The stage's settings plus the uncommon-pattern episodes of §6.4.2.5."""
    if stage.random_coverage and args.uncommon_patterns > 0:
        return stage.replace(random_coverage_prob=args.uncommon_patterns, random_coverage_max=args.uncommon_max)
    return stage


def evaluate_policy(q: QNetwork, scenarios: list, frames: int, sensor: str = "full", sensor_range: int = 3,
                    sensor_failure: float = 0.0, heuristic: bool = True, random_ties: bool = False,
                    dead_ends_first: bool = True, trajectories: list | None = None, seed: int = 0) -> dict:
    """The deterministic policy (noise off) once on each scenario, all at once, with the heuristic fallback of §6.5.2.1
    unless `heuristic` is False (gridworld.greedy_episodes: its per-episode arrays; `trajectories`, a list, gets each
    episode's (T + 1, 1, 2) cells; `seed` draws the sensor failures). The observation and frames are the network's."""
    spec = q.network() if hasattr(q, "network") else {"frames": frames}
    observation, device, hint = observation_settings(spec), gridworld.device_of(q), bool(spec.get("hint"))
    stack = Stacker(len(scenarios), spec["frames"], *gridworld.frame_shape(observation)[::-1], hint=hint)

    def act(obs, restart, acting):
        stack.push(obs, restart)
        maps, extras = stack.get()
        return q(*gridworld.to_torch(maps[acting], extras[acting], device)).float().cpu().numpy().argmax(1)

    q.reset_noise(False)
    with torch.no_grad():
        m = gridworld.greedy_episodes(gridworld.replay_config(scenarios, sensor, sensor_range, sensor_failure, observation),
                                      scenarios, act, hint, heuristic, random_ties, dead_ends_first,
                                      bool(spec.get("far_first")), trajectories=trajectories, seed=seed)
    q.reset_noise(True)
    return m


# ----------------------------------------------------------------------------- training
def main(args: Args) -> None:
    # TRY NOT TO MODIFY: flags, files read and seeding; nothing is written before all of them check out
    args = settle_flags(args)
    check_flags(args)
    stages = load_stages(args)
    if args.buffer_size < 64 * args.num_envs:
        raise ValueError(f"--buffer-size {args.buffer_size}: need buffer_size >= 64 * num_envs")
    eval_set = gridworld.load_dataset(os.path.join(HERE, "maps", "cpp_eval.npz"))
    held_out = gridworld.curve_maps() if args.curve_every else {}
    args, run_dir, q, target, optimizer, rng, (global_step, stage_index, wall, curve), parent = start_run(args, len(stages))
    stages, device = observed(stages, args), gridworld.device_of(q)  # the stages observed as the network needs
    observation = observation_settings(asdict(args))
    channels, view = gridworld.frame_shape(observation)
    machine = gridworld.provenance(f"{SCRIPT}.py") | {"torch_version": torch.__version__}
    ends = np.cumsum([max(1, int(s.base_steps * args.stage_steps_scale)) for s in stages])
    total = int(args.total_steps or ends[-1])  # past the curriculum's end its last stage goes on

    # env setup
    core = gridworld.GridWorldCore(stage_config(stages[stage_index], args), args.num_envs, seed=args.seed + global_step)
    B = args.num_envs
    replay = Replay(args.buffer_size, B, view, args.frame_stack, args.n_step, args.gamma, args.alpha,
                    None if observation["observation"] == "deep" else channels, args.hint)
    print(f"{run_dir}: {args.network} network on {device}, replay {replay.bytes_per_transition()} bytes per transition, "
          f"{replay.bytes_per_transition() * args.buffer_size / 2**30:.2f} GiB for {args.buffer_size:,}")
    lock = gridworld.lock_run(run_dir)  # held until this run ends
    writer = gridworld.summary_writer(args, run_dir)  # CleanRL's TensorBoard; --track mirrors it to W&B

    # TRY NOT TO MODIFY: start the game
    every = np.arange(B)
    core.reset()
    obs = gridworld.observe(core, args.hint, args.heuristic_dead_ends, args.heuristic_far_first)
    stack = Stacker(B, args.frame_stack, view, channels, args.hint)
    stack.push(obs, np.ones(B, bool))
    slot = replay.add_frames(every, obs, np.zeros(B, np.int64), np.zeros(B, bool))
    age = np.zeros(B, np.int64)
    watch = gridworld.StuckWatch(core)  # §6.4.2.4 conditions 3-4
    demonstrations_end = max(args.learning_starts, args.demonstration_steps)
    teacher = np.full(B, global_step < demonstrations_end)  # §6.4.2.4 condition 1
    continued = np.zeros(B, bool)  # truncated and continued by the heuristic (condition 2)
    returns = np.zeros(B)
    starts = core.snapshot()
    challenging: list = []
    yardstick: dict = {}  # stage index -> the heuristic alone on that stage's evaluation maps
    updates_due, last_log, last_loss_log, t0 = 0.0, global_step, global_step, time.time() - wall
    replay_born = global_step  # a new (or resumed) memory refills for learning_starts steps before learning
    curve_clock = (global_step, time.time())  # steps/s between curve points leaves out their evaluation
    latest = ""
    stop, previous_handlers = gridworld.stop_signals()
    bar = gridworld.progress_bar(total, global_step, args.quiet)

    def save():
        gridworld.save_run(run_dir, SCRIPT, q, target, optimizer, args, rng, global_step, stage_index,
                           stages[stage_index].name, time.time() - t0, parent, machine, curve)

    while global_step < total and not stop["signal"] and not (args.time_limit and time.time() - t0 >= 60 * args.time_limit):
        if stage_index + 1 < len(stages) and global_step >= ends[stage_index]:  # the next stage, at each world's reset
            stage_index += 1
            core.configure(stage_config(stages[stage_index], args))
        # ALGO LOGIC: put action logic here
        with torch.no_grad():
            action = q(*gridworld.to_torch(*stack.get(), device)).argmax(1).cpu().numpy()
        teach = (teacher | continued | watch.stuck(core)[:, 0]) & (rng.random(B) < args.imitation)
        label = None
        if teach.any() or args.margin_loss:  # the hint is this heuristic's move when ties are not random
            label = (obs["hint"] if args.hint and not args.heuristic_random_ties else
                     gridworld.heuristic_actions(core, args.heuristic_random_ties, args.heuristic_dead_ends,
                                            args.heuristic_far_first)[:, 0])
        if args.teacher != "heuristic" and label is not None:
            label, _ = rollout_labels(core, label, teach, args)
        if teach.any():  # a heuristic without a target (WAIT) leaves the agent its own move
            action = np.where(teach & (label < gridworld.WAIT), label, action)

        # TRY NOT TO MODIFY: execute the game and log data.
        ev = core.step(action[:, None])
        terminated, truncated = ev["terminated"], ev["truncated"]
        replay.set_transition(slot, action, ev["reward"][:, 0], terminated | (truncated & ~args.peb),
                              label if args.margin_loss else None)
        returns += ev["reward"][:, 0]
        watch.step(core, ev["new"])
        global_step += B
        bar.update(B)
        carry_on = truncated & args.partial_reset
        if carry_on.any():  # §6.4.2.2: a new battery, the heuristic finishes the episode
            core.recharge(np.flatnonzero(carry_on))
            continued |= carry_on
        ended = terminated | (truncated & ~args.partial_reset)

        # TRY NOT TO MODIFY: save data to replay buffer; handle final_observation
        obs = gridworld.observe(core, args.hint, args.heuristic_dead_ends, args.heuristic_far_first)
        slot = replay.add_frames(every, obs, age + 1, ended)
        age += 1
        if ended.any():
            w = np.flatnonzero(ended)
            m = core.metrics()
            # TRY NOT TO MODIFY: record rewards for plotting purposes
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
            obs = gridworld.observe(core, args.hint, args.heuristic_dead_ends, args.heuristic_far_first)
            slot[w] = replay.add_frames(w, {k: v[w] for k, v in obs.items()}, np.zeros(len(w), np.int64),
                                        np.zeros(len(w), bool))
            age[w] = returns[w] = 0
            continued[w] = False
            teacher[w] = global_step < demonstrations_end
            watch.restart(core, w)
        # TRY NOT TO MODIFY: CRUCIAL step easy to overlook
        stack.push(obs, ended)

        # ALGO LOGIC: training.
        if global_step - replay_born > args.learning_starts:
            updates_due += B * args.replay_ratio / args.batch_size
        while updates_due >= 1:
            updates_due -= 1
            beta = args.beta_start + (1 - args.beta_start) * min(1.0, global_step / min(total, ends[-1]))
            if diagnose := global_step - last_loss_log >= 1000:  # the first update after each 1000 steps
                last_loss_log = global_step
            for tag, value in (learn(q, target, optimizer, replay, args, beta, rng, diagnose) or {}).items():
                writer.add_scalar(tag, value, global_step)
        if global_step - last_log >= 1000:
            sps = int(global_step / max(time.time() - t0, 1e-9))
            writer.add_scalar("charts/SPS", sps, global_step)
            bar.set_postfix_str(f"{stages[stage_index].name}, SPS {sps}{latest}", refresh=False)
            if bar.disable and not args.quiet:
                print(f"step {global_step:,}/{total:,} stage {stages[stage_index].name} SPS {sps}", flush=True)
            last_log = global_step
        if args.eval_every and global_step % args.eval_every < B:
            stage = stages[stage_index]
            pool = [s for s in eval_set if s.obstacles.shape[0] <= max(stage.size, 5)]  # cpp_eval starts at 5
            pool = pool[::max(1, len(pool) // args.eval_maps)][:args.eval_maps]
            if stage_index not in yardstick:
                config = gridworld.replay_config(pool, stage.sensor, stage.sensor_range)
                yardstick[stage_index] = gridworld.heuristic_walk(config, pool, args.heuristic_random_ties,
                                                                  args.heuristic_dead_ends, args.heuristic_far_first)
            paths = [] if args.capture_video else None
            m = evaluate_policy(q, pool, args.frame_stack, stage.sensor, stage.sensor_range,
                                random_ties=args.heuristic_random_ties, dead_ends_first=args.heuristic_dead_ends,
                                trajectories=paths)
            result = dict(overlap=float(m["overlap"].mean()), completion=float(m["completed"].mean()),
                          heuristic_share=float((m["heuristic_steps"] / np.maximum(m["steps"], 1)).mean()),
                          heuristic_overlap=float(yardstick[stage_index]["overlap"].mean()))
            for k, v in result.items():
                writer.add_scalar(f"eval/{k}", v, global_step)
            latest = f", eval overlap {result['overlap']:.3f}"
            bar.write(f"step {global_step:,}  eval overlap {result['overlap']:.3f} (heuristic "
                      f"{result['heuristic_overlap']:.3f} on the same maps), completed {100 * result['completion']:.0f}%, "
                      f"heuristic share {result['heuristic_share']:.2f}")
            if paths:
                gridworld.write_episode_video(pool[0], paths[0], os.path.join(run_dir, "videos", f"step_{global_step}.mp4"),
                                              stage.sensor, stage.sensor_range)
        if args.curve_every and global_step % args.curve_every < B:
            tick = time.time()
            point = {"step": global_step, "stage": stages[stage_index].name, "wall_seconds": round(tick - t0),
                     "sps": round((global_step - curve_clock[0]) / max(tick - curve_clock[1], 1e-9)),
                     "steps_since_resume": global_step - replay_born,  # the replay memory restarted then
                     "peak_rss_mb": gridworld.peak_memory_mb(), "learning_rate": args.learning_rate, "tau": args.tau}
            point |= gridworld.curve_point(held_out, lambda maps, fallback: evaluate_policy(
                q, maps, args.frame_stack, heuristic=fallback, dead_ends_first=args.heuristic_dead_ends))
            curve.append(point | {"eval_seconds": round(time.time() - tick)})
            gridworld.write_json(os.path.join(run_dir, "curve.json"), {"args": asdict(args), "curve": curve}, "run",
                                 overwrite=True, flag="curve")
            for k in ("cpp_eval", "structured_eval"):
                writer.add_scalar(f"curve/{k}_overlap", point[k]["overlap"], global_step)
                writer.add_scalar(f"curve/{k}_alone_completion", point[f"{k}_alone"]["completion"], global_step)
            bar.write(f"step {global_step:,}  curve: overlap cpp_eval {point['cpp_eval']['overlap']:.3f}, structured "
                      f"{point['structured_eval']['overlap']:.3f}; without the fallback completed "
                      f"{100 * point['cpp_eval_alone']['completion']:.1f}% / "
                      f"{100 * point['structured_eval_alone']['completion']:.1f}%, {point['sps']} steps/s")
            curve_clock = (global_step, time.time())
            save()  # the point is kept with the checkpoint, and a copy of it to roll back to if the run diverges
            kept = os.path.join(run_dir, f"checkpoint_{global_step}.pt")
            if not os.path.exists(kept):  # a hard link: the next save replaces checkpoint.pt, this file stays
                os.link(os.path.join(run_dir, "checkpoint.pt"), kept)
        # TRY NOT TO MODIFY: checkpoint and export
        if args.save_every and global_step % args.save_every < B:
            save()
    save()
    bar.close()
    gridworld.close_writer(writer, args.track)
    gridworld.restore_signals(previous_handlers)
    lock.close()
    print(f"saved {os.path.join(run_dir, 'checkpoint.pt')} and {args.export} at step {global_step:,}")
    if stop["signal"]:  # interrupted: the shell's convention, 130 for Ctrl-C and 143 for SIGTERM
        raise SystemExit(128 + stop["signal"])


if __name__ == "__main__":
    try:
        main(gridworld.cli(Args))
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
