"""Environment steps per second of rainbow_cpp's batched trainer against a plain single-env loop.

    python benchmarks/rainbow_sps.py                      # Table 6.1 settings, hidden 512
    python benchmarks/rainbow_sps.py --hidden 256 --replay-ratio 2
    python benchmarks/rainbow_sps.py --trainer-batch-size 128   # the same samples in fewer, larger updates

The plain loop is the usual per-step DQN: one Gymnasium env, one forward pass per step, frame
stacks kept in a deque and stored whole in the replay memory, and every 4 steps one double-DQN
update of the same network, batch, prioritized sampling and (fused) optimizer as rainbow_cpp.
Both are timed over the same number of environment steps after learning starts; the script
prints one JSON line per trainer and the speed-up.
"""
from __future__ import annotations

import collections
import contextlib
import json
import os
import sys
import tempfile
import time
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import gridworld  # noqa: E402
import rainbow_cpp  # noqa: E402


@dataclass
class Args:
    steps: int = 1000
    """environment steps timed after learning starts"""
    learning_starts: int = 500
    """environment steps collected (by the heuristic) before timing"""
    hidden: int = 512
    """width of the dueling streams' hidden layers"""
    replay_ratio: float = 8.0
    """sampled transitions per environment step (Table 6.1: batch 32 every 4 steps)"""
    batch_size: int = 32
    """transitions per gradient step"""
    trainer_batch_size: int = 0
    """rainbow_cpp's batch alone (0: batch_size), at the same replay ratio: 16 worlds add 16
    transitions a step, so one update of 128 can stand for four of 32"""
    num_envs: int = 16
    """worlds acted in together by rainbow_cpp"""
    size: int = 20
    """map edge of the training worlds"""


def plain_loop(args: Args) -> float:
    """Env steps/s of the per-step loop, timed after `learning_starts` steps."""
    env = gridworld.GridWorldEnv(size=args.size, number_obstacles=args.size, obstacles_random=True)
    V, k = rainbow_cpp.VIEW, 3
    q = rainbow_cpp.QNetwork(k, V, args.hidden, 0.5)
    target = rainbow_cpp.QNetwork(k, V, args.hidden, 0.5)
    target.load_state_dict(q.state_dict())
    optimizer = torch.optim.Adam(q.parameters(), lr=5e-5, eps=1.56e-4, fused=True)
    capacity = args.learning_starts + args.steps + 1
    maps = np.zeros((capacity, rainbow_cpp.CHANNELS * k, V, V), np.uint8)
    next_maps = np.zeros_like(maps)
    extras = np.zeros((capacity, 1 + rainbow_cpp.EXTRAS * k), np.float32)
    next_extras = np.zeros_like(extras)
    actions, rewards, dones = np.zeros(capacity, np.int64), np.zeros(capacity, np.float32), np.zeros(capacity, bool)
    tree = rainbow_cpp.SumTree(capacity)
    rng = np.random.default_rng(0)
    frames = collections.deque(maxlen=k)

    def stacked(obs, new_episode):
        extra = np.concatenate([obs["last_action"], obs["out_of_bounds"].ravel() / rainbow_cpp.OUT_OF_BOUNDS_SCALE])
        for _ in range(k if new_episode else 1):
            frames.append((obs["map"], extra))
        return (np.concatenate([f[0] for f in frames]),
                np.concatenate([obs["battery"], *[f[1] for f in frames]]).astype(np.float32))

    obs, _ = env.reset(seed=0)
    m, e = stacked(obs, True)
    updates_due = 0.0
    for t in range(args.learning_starts + args.steps):
        if t == args.learning_starts:
            t0 = time.perf_counter()
        if t < args.learning_starts:
            action = env.heuristic_action()
        else:
            with torch.no_grad():
                action = int(q(torch.from_numpy(m[None]), torch.from_numpy(e[None])).argmax(1))
        obs, reward, terminated, truncated, _ = env.step(action)
        maps[t], extras[t], actions[t], rewards[t], dones[t] = m, e, action, reward, terminated
        if terminated or truncated:
            obs, _ = env.reset()
        m, e = stacked(obs, terminated or truncated)
        next_maps[t], next_extras[t] = m, e
        tree.update(np.array([t]), np.ones(1))
        if t < args.learning_starts:
            continue
        updates_due += args.replay_ratio / args.batch_size
        while updates_due >= 1:
            updates_due -= 1
            idx = tree.sample(args.batch_size, rng)
            s, se, ns, nse = (torch.from_numpy(x[idx]) for x in (maps, extras, next_maps, next_extras))
            with torch.no_grad():
                best = q(ns, nse).argmax(1, keepdim=True)
                y = torch.from_numpy(rewards[idx]) + 0.999 * torch.from_numpy(~dones[idx]) * target(ns, nse).gather(1, best)[:, 0]
            q_sa = q(s, se).gather(1, torch.from_numpy(actions[idx])[:, None])[:, 0]
            loss = F.smooth_l1_loss(q_sa, y)
            optimizer.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(q.parameters(), 2.5)
            optimizer.step()
            tree.update(idx, np.abs((y - q_sa).detach().numpy()) ** 0.5 + 1e-6)
            with torch.no_grad():
                for p, tp in zip(q.parameters(), target.parameters()):
                    tp.lerp_(p, 0.04)
            q.reset_noise()
            target.reset_noise()
    return args.steps / (time.perf_counter() - t0)


def batched_trainer(args: Args, workdir: str) -> float:
    """Env steps/s of rainbow_cpp.main over `steps` steps after learning starts: two runs, the
    second `steps` longer, so start-up and the heuristic's prefill cancel out."""
    stage = os.path.join(workdir, "stage.yaml")
    with open(stage, "w") as f:
        f.write(f"bench:\n  size: {args.size}\n  number_obstacles: {args.size}\n  obstacles_random: true\n"
                f"  base_steps: {10 * (args.learning_starts + args.steps)}\n")
    wall = []
    for total in (args.learning_starts, args.learning_starts + args.steps):
        run = rainbow_cpp.Args(stages=stage, total_steps=total, learning_starts=args.learning_starts,
                               hidden=args.hidden, replay_ratio=args.replay_ratio,
                               batch_size=args.trainer_batch_size or args.batch_size, num_envs=args.num_envs,
                               buffer_size=64 * args.num_envs * 64, eval_every=0, save_every=0,
                               run_name=f"bench_{total}", quiet=True,  # a folder name: runs/ under workdir
                               export=os.path.join(workdir, f"model_{total}.pt"))
        t0 = time.perf_counter()
        with contextlib.chdir(workdir):  # the trainer writes runs/RUN_NAME under the working folder
            rainbow_cpp.main(run)
        wall.append(time.perf_counter() - t0)
    return args.steps / (wall[1] - wall[0])


if __name__ == "__main__":
    with gridworld.cli_errors():  # a ValueError (a trainer's flag check) or Ctrl-C: one line, no traceback
        args = gridworld.cli(Args)
        torch.manual_seed(0)
        with tempfile.TemporaryDirectory() as workdir:
            batched = batched_trainer(args, workdir)
        plain = plain_loop(args)
    common = dict(hidden=args.hidden, replay_ratio=args.replay_ratio, batch_size=args.batch_size,
                  size=args.size, steps=args.steps, torch_threads=torch.get_num_threads())
    print(json.dumps({"trainer": "plain single-env loop", "env_steps_per_s": round(plain, 1), **common}))
    print(json.dumps({"trainer": "rainbow_cpp", "num_envs": args.num_envs, "env_steps_per_s": round(batched, 1),
                      **common, "batch_size": args.trainer_batch_size or args.batch_size}))
    print(json.dumps({"speedup": round(batched / plain, 2)}))
