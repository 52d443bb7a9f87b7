"""Training speed of rainbow_cpp's networks (GitHub issue 16, item 4), in one run.

    taskset -c 1 python benchmarks/train_speed.py --threads 1 --json runs/train_speed.json   # the docs' figures
    python benchmarks/train_speed.py                      # 1 and 2 torch threads (and CUDA when there is one)
    python benchmarks/train_speed.py --quick              # fewer steps and repeats, a smoke test

Per network (Fig. 6.8 with hidden 512, Fig. 6.8 with hidden 256, the compact network over the multiscale
observation), on each device and number of torch threads:

- ms per update: rainbow_cpp.learn (prioritized sampling from a replay memory of real frames, the hand-over
  to the device, the double-DQN step, priorities, soft target update, fresh noise) at batch 32 and 128;
- env steps/s of the real training loop (rainbow_cpp.main, every training feature on, 16 worlds) at replay
  ratio 4 and 8, timed as two runs of different length so that start-up and the heuristic's prefill cancel;
- the yardstick: Stable-Baselines3's DQN (benchmarks/requirements.txt) on GridWorld-v0 with the same network
  as a custom policy (its Q-network replaced by ours, the same frame stack, batch and train frequency, a soft
  target update every gradient step, no epsilon so that every step acts through the network), env steps/s
  against ours at the same replay ratio; skipped with a message when SB3 is not installed.

Prints a table and the issue's targets; --json PATH writes one row per measurement with the keys network,
hidden, batch_size, threads, device, replay_ratio, ms_per_update, env_steps_per_s (null where a row does not
measure it) plus trainer ("rainbow_cpp" or "sb3_dqn").
"""
from __future__ import annotations

import collections
import contextlib
import os
import sys
import tempfile
import time
import warnings
from dataclasses import asdict, dataclass, field

import gymnasium as gym
import numpy as np
import torch

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
import gridworld  # noqa: E402
import rainbow_cpp as rc  # noqa: E402

NETWORKS = [("fig6.8", 512), ("fig6.8", 256), ("compact", 256)]  # (network, hidden); compact: COMPACT widths


@dataclass
class Args:
    threads: list[int] = field(default_factory=lambda: [1, 2])
    """torch threads to measure on the CPU (CUDA runs with one)"""
    cuda: bool = True
    """also measure on the GPU when there is one"""
    batch_sizes: list[int] = field(default_factory=lambda: [32, 128])
    """batches of the ms-per-update measurements"""
    replay_ratios: list[float] = field(default_factory=lambda: [4.0, 8.0])
    """replay ratios of the env-steps/s measurements (batch 32)"""
    steps: int = 2000
    """env steps timed after learning starts, compact network (fig6.8: a fifth of it, at least 400)"""
    learning_starts: int = 400
    """env steps of heuristic prefill before learning (as the external check's runs)"""
    repeats: int = 20
    """timed updates per ms-per-update measurement (fig6.8: a quarter, at least 4), after 3 untimed"""
    size: int = 0
    """map edge of a stage of size x size maps with as many obstacles; 0: the default curriculum's first stage
    (what a plain `rainbow_cpp.py --total-steps N` trains on)"""
    sb3: bool = True
    """the Stable-Baselines3 DQN yardstick (compact network, replay ratio 4, batch 32, one thread)"""
    sb3_steps: int = 2000
    """env steps of SB3 timed after its learning starts"""
    quick: bool = False
    """a smoke test: at most 320 steps (fig6.8 too) and 3 repeats; smaller --steps, --sb3-steps, --repeats stay"""
    json: str | None = None
    """write the rows here"""
    overwrite: bool = False
    """let --json replace a file that is there already"""


def stage(args: Args) -> gridworld.EnvConfig:
    if args.size:
        return gridworld.EnvConfig(name="bench", size=args.size, number_obstacles=args.size, obstacles_random=True,
                                   base_steps=10 ** 9)
    return gridworld.EnvConfig.from_dict(rc.STAGES[0])


def write_stage(config: gridworld.EnvConfig, path: str) -> str:
    fields = {k: v for k, v in asdict(config).items() if k in ("size", "min_size", "random_size", "number_obstacles",
                                                               "obstacles_random", "random_coverage", "sensor",
                                                               "sensor_range")}
    with open(path, "w") as f:
        f.write("bench:\n" + "".join(f"  {k}: {str(v).lower() if isinstance(v, bool) else v}\n"
                                     for k, v in fields.items()) + "  base_steps: 1000000000\n")
    return path


def spec_of(network: str, hidden: int) -> rc.Args:
    return rc.settle_flags(rc.with_network(rc.Args(network=network, hidden=hidden), None, None))


def row(network, hidden, batch_size, threads, device, replay_ratio=None, ms_per_update=None, env_steps_per_s=None,
        trainer="rainbow_cpp") -> dict:
    return dict(network=network, hidden=hidden, batch_size=batch_size, threads=threads, device=device,
                replay_ratio=replay_ratio, ms_per_update=None if ms_per_update is None else round(ms_per_update, 2),
                env_steps_per_s=None if env_steps_per_s is None else round(env_steps_per_s, 1), trainer=trainer)


# ----------------------------------------------------------------------------- ms per update
def filled_replay(run: rc.Args, config: gridworld.EnvConfig, worlds: int = 16, steps: int = 160) -> rc.Replay:
    """A replay memory of real frames: `worlds` worlds of the stage, the heuristic acting for `steps` steps."""
    observation = rc.observation_settings(asdict(run))
    channels, view = gridworld.frame_shape(observation)
    core = gridworld.GridWorldCore(config.replace(**observation), worlds, seed=0)
    core.reset()
    replay = rc.Replay(worlds * 256, worlds, view, run.frame_stack, 1, 0.999, 0.5,
                       None if observation["observation"] == "deep" else channels)
    every, age = np.arange(worlds), np.zeros(worlds, np.int64)
    slot = replay.add_frames(every, gridworld.observe(core), age, np.zeros(worlds, bool))
    for _ in range(steps):
        action = gridworld.heuristic_actions(core, False, True)[:, 0]
        ev = core.step(action[:, None])
        replay.set_transition(slot, np.minimum(action, rc.MOVES - 1), ev["reward"][:, 0], ev["terminated"])
        ended = ev["terminated"] | ev["truncated"]
        age += 1
        slot = replay.add_frames(every, gridworld.observe(core), age, ended)
        if ended.any():
            w = np.flatnonzero(ended)
            core.reset(w)
            obs = gridworld.observe(core)
            slot[w] = replay.add_frames(w, {k: v[w] for k, v in obs.items()}, np.zeros(len(w), np.int64),
                                        np.zeros(len(w), bool))
            age[w] = 0
    return replay


def ms_per_update(run: rc.Args, replay: rc.Replay, device: torch.device, repeats: int) -> float:
    torch.manual_seed(0)
    spec = {**asdict(run), "frames": run.frame_stack, "view": rc.VIEW}
    q, target = (rc.build_network(spec, run.sigma0).to(device) for _ in range(2))
    target.load_state_dict(q.state_dict())
    optimizer = torch.optim.Adam(q.parameters(), lr=run.learning_rate, eps=run.adam_eps, fused=True)
    rng = np.random.default_rng(0)
    times = []
    for _ in range(3 + repeats):
        start = time.perf_counter()
        rc.learn(q, target, optimizer, replay, run, 0.4, rng)  # reads the TD errors back: a device sync
        times.append(time.perf_counter() - start)
    return 1000 * float(np.median(times[3:]))


# ----------------------------------------------------------------------------- env steps/s of training
def env_steps_per_s(run: rc.Args, stage_file: str, steps: int, learning_starts: int, workdir: str) -> float:
    """rainbow_cpp.main over `steps` steps after learning starts: two runs, the second `steps` longer."""
    wall = []
    here = tempfile.mkdtemp(dir=workdir)  # a fresh folder per measurement: runs/ and the exports never meet old ones
    for total in (learning_starts, learning_starts + steps):
        args = rc.Args(**{**asdict(run), "stages": stage_file, "total_steps": total, "learning_starts": learning_starts,
                          "eval_every": 0, "save_every": 0, "quiet": True,
                          "run_name": f"bench_{total}", "export": os.path.join(here, f"model_{total}.pt")})
        start = time.perf_counter()
        with contextlib.chdir(here):  # the trainer writes runs/RUN_NAME under the working folder
            rc.main(args)
        wall.append(time.perf_counter() - start)
    return steps / max(wall[1] - wall[0], 1e-9)


# ----------------------------------------------------------------------------- the SB3 yardstick
class Stacked(gym.ObservationWrapper):
    """GridWorld-v0 with rainbow_cpp's frame stack: obs {"maps": (k * C, V, V) uint8, "extras": (1 + 13k,)}, as
    rainbow_cpp.Stacker builds them (a new episode repeats its first frame)."""

    def __init__(self, env: gym.Env, k: int):
        super().__init__(env)
        c, v = env.observation_space["map"].shape[0], env.observation_space["map"].shape[-1]
        self.k, self.frames = k, collections.deque(maxlen=k)
        self.observation_space = gym.spaces.Dict({
            "maps": gym.spaces.Box(0, 255, (k * c, v, v), np.uint8),
            "extras": gym.spaces.Box(-np.inf, np.inf, (1 + k * rc.EXTRAS,), np.float32)})

    def reset(self, **kw):
        obs, info = self.env.reset(**kw)
        self.frames.clear()
        return self.observation(obs), info

    def observation(self, obs):
        extra = np.concatenate([obs["last_action"], obs["out_of_bounds"].ravel() / rc.OUT_OF_BOUNDS_SCALE])
        for _ in range(self.k if not self.frames else 1):
            self.frames.append((obs["map"], extra))
        return {"maps": np.concatenate([f[0] for f in self.frames]),
                "extras": np.concatenate([obs["battery"], *[f[1] for f in self.frames]]).astype(np.float32)}


def sb3_env_steps_per_s(run: rc.Args, config: gridworld.EnvConfig, steps: int, learning_starts: int) -> float:
    """SB3 DQN, our network as its Q-network, on one GridWorld-v0 env: env steps/s after learning starts."""
    from stable_baselines3 import DQN
    from stable_baselines3.common.torch_layers import FlattenExtractor
    from stable_baselines3.dqn.policies import DQNPolicy
    from stable_baselines3.dqn.policies import QNetwork as SB3QNetwork

    spec = {**asdict(run), "frames": run.frame_stack, "view": rc.VIEW}

    class OurQ(SB3QNetwork):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            self.q_net = rc.build_network(spec, run.sigma0)

        def forward(self, obs):
            return self.q_net(obs["maps"], obs["extras"])

    class OurPolicy(DQNPolicy):
        def make_q_net(self):
            return OurQ(**self._update_features_extractor(self.net_args, features_extractor=None)).to(self.device)

    env = Stacked(gym.make("GridWorld-v0", config=config.replace(**rc.observation_settings(asdict(run)))),
                  run.frame_stack)
    train_freq = round(run.batch_size / run.replay_ratio)
    warnings.filterwarnings("ignore", "Treating image space as channels-last")  # no SB3 preprocessing is used
    model = DQN(OurPolicy, env, learning_rate=run.learning_rate, buffer_size=learning_starts + steps + 1000,
                learning_starts=learning_starts, batch_size=run.batch_size, tau=run.tau, gamma=run.gamma,
                train_freq=train_freq, gradient_steps=1, target_update_interval=train_freq,
                exploration_initial_eps=0.0, exploration_final_eps=0.0, max_grad_norm=run.max_grad_norm,
                policy_kwargs=dict(features_extractor_class=FlattenExtractor, normalize_images=False, net_arch=[]),
                seed=0, device="cpu", verbose=0)
    model.learn(total_timesteps=learning_starts)
    start = time.perf_counter()
    model.learn(total_timesteps=steps, reset_num_timesteps=False)
    return steps / (time.perf_counter() - start)


# ----------------------------------------------------------------------------- the run
def devices(args: Args) -> list[tuple[torch.device, int]]:
    out = [(torch.device("cpu"), t) for t in args.threads]
    if args.cuda and torch.cuda.is_available():
        out.append((torch.device("cuda"), 1))
    return out


def table(rows: list[dict]) -> str:
    keys = ["trainer", "network", "hidden", "device", "threads", "batch_size", "replay_ratio", "ms_per_update", "env_steps_per_s"]
    cells = [keys] + [["-" if r[k] is None else str(r[k]) for k in keys] for r in rows]
    widths = [max(len(c[i]) for c in cells) for i in range(len(keys))]
    return "\n".join("  ".join(c[i].rjust(widths[i]) for i in range(len(keys))) for c in cells)


def targets(rows: list[dict]) -> list[str]:
    def find(**kw):
        hits = [r for r in rows if all(r[k] == v for k, v in kw.items())]
        return hits[0] if hits else None

    lines = []
    one = dict(threads=1, device="cpu", trainer="rainbow_cpp")
    fig, small = (find(network=n, hidden=h, batch_size=32, replay_ratio=None, **one)
                  for n, h in (("fig6.8", 512), ("compact", 256)))
    if fig and small:
        ratio = fig["ms_per_update"] / small["ms_per_update"]
        lines.append(f"compact update {ratio:.1f}x cheaper than fig6.8-512 at batch 32 on one thread "
                     f"({small['ms_per_update']} vs {fig['ms_per_update']} ms; target >= 10x): "
                     f"{'PASS' if ratio >= 10 else 'FAIL'}")
    ours = find(network="compact", replay_ratio=4.0, batch_size=32, **one)
    if ours:
        lines.append(f"compact training at replay ratio 4 on one thread: {ours['env_steps_per_s']} env steps/s "
                     f"(target >= 400): {'PASS' if ours['env_steps_per_s'] >= 400 else 'FAIL'}")
    sb3 = find(trainer="sb3_dqn")
    if ours and sb3:
        ratio = ours["env_steps_per_s"] / sb3["env_steps_per_s"]
        lines.append(f"ours {ratio:.2f}x SB3 DQN's env steps/s, compact network, replay ratio 4, batch 32, one "
                     f"thread ({ours['env_steps_per_s']} vs {sb3['env_steps_per_s']}; target >= 1.5x): "
                     f"{'PASS' if ratio >= 1.5 else 'FAIL'}")
    return lines


def main(args: Args) -> list[dict]:
    if args.quick:  # at most these; smaller values given with --quick stay (the tests run a few steps)
        args.steps, args.sb3_steps, args.repeats = min(args.steps, 320), min(args.sb3_steps, 320), min(args.repeats, 3)
    if args.json:
        gridworld.check_output(args.json, "result", args.overwrite, "--json")  # before the minutes of measuring
    config = stage(args)
    rows: list[dict] = []
    threads_before = torch.get_num_threads()

    def add(r):
        rows.append(r)
        shown = r["ms_per_update"] if r["ms_per_update"] is not None else r["env_steps_per_s"]
        print(f"  {r['trainer']} {r['network']}-{r['hidden']} {r['device']} x{r['threads']} batch {r['batch_size']} "
              f"rr {r['replay_ratio']}: "
              f"{shown} {'ms/update' if r['ms_per_update'] is not None else 'env steps/s'}", flush=True)

    with tempfile.TemporaryDirectory() as workdir:
        stage_file = write_stage(config, os.path.join(workdir, "stage.yaml"))
        for device, threads in devices(args):
            torch.set_num_threads(threads)
            for network, hidden in NETWORKS:
                run = spec_of(network, hidden)
                replay = filled_replay(run, config)
                fig = network == "fig6.8"
                for batch in args.batch_sizes:
                    ms = ms_per_update(rc.Args(**{**asdict(run), "batch_size": batch}), replay, device,
                                       max(4, args.repeats // 4) if fig and not args.quick else args.repeats)
                    add(row(network, hidden, batch, threads, device.type, ms_per_update=ms))
                for ratio in args.replay_ratios:
                    run_loop = rc.Args(**{**asdict(run), "replay_ratio": ratio, "threads": threads,
                                          "cuda": device.type == "cuda"})
                    steps = max(400, args.steps // 5) if fig and not args.quick else args.steps
                    sps = env_steps_per_s(run_loop, stage_file, steps, args.learning_starts, workdir)
                    add(row(network, hidden, 32, threads, device.type, replay_ratio=ratio, env_steps_per_s=sps))
        if args.sb3:
            try:
                import stable_baselines3  # noqa: F401
            except ImportError:
                print("SB3 yardstick skipped: stable-baselines3 is not installed "
                      "(pip install -r benchmarks/requirements.txt)")
            else:
                torch.set_num_threads(1)
                run = rc.Args(**{**asdict(spec_of("compact", 256)), "replay_ratio": 4.0, "batch_size": 32})
                sps = sb3_env_steps_per_s(run, config, args.sb3_steps, args.learning_starts)
                add(row("compact", 256, 32, 1, "cpu", replay_ratio=4.0, env_steps_per_s=sps, trainer="sb3_dqn"))
    torch.set_num_threads(threads_before)
    print()
    print(table(rows))
    print()
    cpu = next((line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name")),
               "?") if os.path.exists("/proc/cpuinfo") else "?"
    print(f"{os.cpu_count()}-core {cpu}, torch {torch.__version__}, stage {config.name or 'bench'} "
          f"(size {config.size}), compact: {', '.join(f'{k} {v}' for k, v in rc.COMPACT.items())}")
    for line in targets(rows):
        print(line)
    if args.json:
        gridworld.write_json(args.json, rows, "result", args.overwrite, "--json")
        print(f"wrote {args.json}")
    return rows


if __name__ == "__main__":
    with gridworld.cli_errors():  # a ValueError or Ctrl-C: one line, no traceback
        main(gridworld.cli(Args))
