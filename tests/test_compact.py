"""The GPU path and the compact network of the two Rainbow trainers (GitHub issue 16, items 1 and 3), on the CPU.

- With --no-cuda (and on a machine without a GPU) the default network trains exactly as before: a fixed-seed
  short run gives the losses and weights recorded from the code before the GPU path and the compact network.
- The compact network (--network compact) reads the multiscale observation: its shapes for several scale
  settings and frame stacks, a convolution group per scale that no other scale reaches, the replay keeping
  its frames as they are (uint8, not bit-packed).
- Exports record the network and the observation it needs; load_policy rebuilds the right class; a model whose
  observation settings disagree with the flags or a stage is a one-line error; loading is device-agnostic.
"""
from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
import tyro

import gridworld as gw
import rainbow_cpp as rc
import rainbow_marl as rm

ROOT = Path(__file__).resolve().parent.parent
TRAINERS = {"rainbow_cpp": rc, "rainbow_marl": rm}
SETTINGS = [(3, 3, 11), (1, 2, 5), (2, 3, 7), (4, 2, 9), (2, 2, 3), (3, 3, 15)]  # scales, scale_factor, scale_view


def multiscale(scales=3, scale_factor=3, scale_view=11) -> dict:
    return {"observation": "multiscale", "scales": scales, "scale_factor": scale_factor, "scale_view": scale_view}


def compact(frames=3, hidden=16, width=8, settings=(3, 3, 11), sigma0=0.5, t=rc) -> rc.CompactQNetwork:
    return t.CompactQNetwork(frames, hidden, sigma0, width, *settings)


def core_for(observation: dict, worlds=3, seed=0, **kw) -> gw.GridWorldCore:
    core = gw.GridWorldCore(gw.EnvConfig(size=12, number_obstacles=10, obstacles_random=True, **observation, **kw),
                            worlds, seed=seed)
    core.reset()
    return core


def tiny(t, **kw):
    base = dict(run_name="t", total_steps=64, num_envs=2, learning_starts=32, buffer_size=2000, hidden=16,
                eval_every=0, save_every=0, quiet=True, cuda=False)
    if t is rm:
        base["init_from"] = ""
    return t.Args(**{**base, **kw})


# ----------------------------------------------------------------------------- the default network, unchanged
# Recorded with the code before this change (git 8815aeb), 2-core AMD EPYC VM, one thread: rainbow_cpp.main /
# rainbow_marl.main with the flags of REFERENCE_FLAGS; the first TD losses and sums of the weights at the end.
REFERENCE_FLAGS = ["--total-steps", "96", "--num-envs", "2", "--learning-starts", "32", "--buffer-size", "2000",
                   "--eval-every", "0", "--save-every", "0", "--hidden", "16", "--quiet", "--margin-loss", "1"]
REFERENCE = {
    "rainbow_cpp": {"losses": [0.17629852890968323, 0.21531467139720917, 0.11413466185331345], "updates": 16,
                    "sums": {"conv.0.weight": -3.362642, "conv.4.weight": 7.062855, "value.0.weight_mu": 1.786145,
                             "advantage.0.weight_mu": -2.732986, "advantage.2.weight_mu": -1.208619}},
    "rainbow_marl": {"losses": [0.06044670194387436], "updates": 16,
                     "sums": {"conv.0.weight": -3.378946, "conv.4.weight": 6.374366, "value.0.weight_mu": 0.203901,
                              "advantage.0.weight_mu": -0.731076, "advantage.2.weight_mu": -1.218061}},
}


@pytest.mark.parametrize("name", TRAINERS)
def test_no_cuda_trains_the_default_network_exactly_as_before(name, tmp_path, monkeypatch, restore_sigint):
    t = TRAINERS[name]
    monkeypatch.chdir(tmp_path)
    losses, learn = [], t.learn

    def recording(*a, **k):  # every update's TD loss: the diagnostics read the network, they change nothing
        logs = learn(*a[:7], diagnose=True)
        losses.append(logs["losses/td_loss"])
        return logs

    monkeypatch.setattr(t, "learn", recording)
    flags = [*REFERENCE_FLAGS, "--no-cuda", "--run-name", "run", "--export", str(tmp_path / "m.pt")]
    threads = torch.get_num_threads()
    try:
        t.main(tyro.cli(t.Args, args=flags + (["--init-from", ""] if t is rm else [])))
    finally:
        torch.set_num_threads(threads)
    ref = REFERENCE[name]
    assert len(losses) == ref["updates"]
    assert losses[:len(ref["losses"])] == pytest.approx(ref["losses"], rel=1e-5)  # the first: before any step
    weights = torch.load(tmp_path / "runs" / "run" / "checkpoint.pt", weights_only=True)["model"]
    assert {k: float(weights[k].double().sum()) for k in ref["sums"]} == pytest.approx(ref["sums"], rel=1e-3, abs=1e-4)


@pytest.mark.parametrize("name", TRAINERS)
def test_the_default_network_is_fig_6_8_on_the_cpu_without_a_gpu(name, tmp_path, monkeypatch, restore_sigint):
    t = TRAINERS[name]
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    args, _, q, target, *_ = t.start_run(t.settle_flags(tiny(t, cuda=True)), 1)
    assert args.network == "fig6.8" and args.conv_width is None and args.scales is None
    assert type(q) is t.QNetwork and gw.device_of(q).type == "cpu" and gw.device_of(target).type == "cpu"


# ----------------------------------------------------------------------------- the compact network
@pytest.mark.parametrize("settings", SETTINGS)
@pytest.mark.parametrize("frames", [1, 3, 4])
def test_compact_network_shapes(settings, frames):
    observation = multiscale(*settings)
    channels, view = gw.frame_shape(observation)
    assert (channels, view) == (settings[0] * gw.MULTISCALE_CHANNELS, settings[2])
    q = compact(frames, 16, 8, settings)
    assert q.frames == frames and q.conv[0].groups == settings[0] and q.conv[0].in_channels == channels * frames
    core = core_for(observation, worlds=3, seed=frames)
    stack = rc.Stacker(3, frames, view, channels)
    stack.push(gw.observe(core), np.ones(3, bool))
    maps, extras = gw.to_torch(*stack.get())
    assert maps.shape == (3, channels * frames, view, view) and extras.shape == (3, 1 + frames * rc.EXTRAS)
    assert q(maps, extras).shape == (3, rc.MOVES)
    assert q.network() == {"network": "compact", "frames": frames, "hidden": 16, "conv_width": 8, "view": view,
                           "extras": rc.EXTRAS, **observation, "hint": False, "far_first": False}
    assert rc.observation_settings(q.network()) == observation


def test_compact_network_default_layers_and_size():
    q = rc.CompactQNetwork(3, 256, 0.5)
    assert q.network()["conv_width"] == 32 and (q.scales, q.scale_factor, q.scale_view) == (3, 3, 11)
    features = q.conv(torch.zeros(1, 45, 11, 11))
    assert features.shape == (1, 3 * 32)  # 11 -> 5 -> 3 -> 1 blocks a scale
    assert q.value[0].n_in == 96 + 1 + 3 * 13
    assert 0.4e6 < sum(p.numel() for p in q.parameters()) < 0.6e6


def test_scales_do_not_mix_before_the_streams():
    """Group s of every convolution sees scale s of every frame, and only it."""
    torch.manual_seed(0)
    frames, scales, width = 2, 3, 4
    q = compact(frames, 16, width, (scales, 3, 11))
    maps = torch.randint(0, 256, (2, frames * scales * 5, 11, 11), dtype=torch.uint8)  # frame-major, as stacked
    extras = torch.rand(2, 1 + frames * rc.EXTRAS)
    features = []
    q.conv[4].register_forward_hook(lambda m, i, o: features.append(o.reshape(2, scales, -1)))  # before its ReLU
    q(maps, extras)
    for s in range(scales):
        changed = maps.clone().view(2, frames, scales, 5, 11, 11)
        changed[:, :, s] = 255 - changed[:, :, s]  # scale s of every frame
        q(changed.view(maps.shape), extras)
        moved = (features[-1] - features[0]).abs().amax((0, 2))
        assert moved[s] > 0 and all(moved[o] == 0 for o in range(scales) if o != s)


def test_the_replay_keeps_multiscale_frames_as_they_are():
    """Raw uint8 frames, stacks and next states as the acting stack built them."""
    observation = multiscale()
    channels, view = gw.frame_shape(observation)
    core = core_for(observation, worlds=2, seed=3)
    replay = rc.Replay(2 * 64, 2, view, 3, 1, 0.9, 0.5, channels)
    assert not replay.packed and replay.frames.dtype == np.uint8
    assert replay.bytes_per_transition() == 15 * 11 * 11 + 8 * 2 + 1 + 2 + 1 + 1 + 4 + 1 + 1 + 8 + 16
    stack = rc.Stacker(2, 3, view, channels)
    obs = gw.observe(core)
    stack.push(obs, np.ones(2, bool))
    every, age, rng = np.arange(2), np.zeros(2, np.int64), np.random.default_rng(0)
    slot = replay.add_frames(every, obs, age, np.zeros(2, bool))
    seen_fractions = False
    for _ in range(30):
        maps, extras = replay._frames(slot)
        want_maps, want_extras = stack.get()
        assert np.array_equal(maps, want_maps) and np.allclose(extras, want_extras, atol=2e-3)  # fp16 storage
        seen_fractions |= bool(((maps > 0) & (maps < 255)).any())
        action = rng.integers(0, 4, 2)
        ev = core.step(action[:, None])
        replay.set_transition(slot, action, ev["reward"][:, 0], ev["terminated"])
        ended = ev["terminated"] | ev["truncated"]
        obs = gw.observe(core)
        age += 1
        slot = replay.add_frames(every, obs, age, ended)
        if ended.any():
            core.reset(np.flatnonzero(ended))
            obs = gw.observe(core)
            w = np.flatnonzero(ended)
            slot[w] = replay.add_frames(w, {k: v[w] for k, v in obs.items()}, np.zeros(len(w), np.int64),
                                        np.zeros(len(w), bool))
            age[w] = 0
        stack.push(obs, ended)
    assert seen_fractions  # block means: the reason the frames are not bit-packed
    idx, (m, e), a, ret, (nm, ne), boot, w = replay.sample(8, 0.4, rng)
    assert m.shape == nm.shape == (8, 3 * channels, view, view) and m.dtype == np.uint8


@pytest.mark.parametrize("name", TRAINERS)
def test_a_compact_run_trains_exports_and_resumes(name, tmp_path, monkeypatch, restore_sigint):
    t = TRAINERS[name]
    monkeypatch.chdir(tmp_path)
    t.main(tiny(t, network="compact", conv_width=8, scales=2, scale_view=7, run_name="c"))
    run = tmp_path / "runs" / "c"
    info = json.loads((run / f"{name}.json").read_text())
    want = {"network": "compact", "frames": 3, "hidden": 16, "conv_width": 8, "view": 7, "extras": 13,
            **multiscale(2, 3, 7), "hint": False, "far_first": False}
    assert info["network"] == want and info["global_step"] == 64 and info["provenance"]["device"] == "cpu"
    assert info["args"]["network"] == "compact" and info["args"]["threads"] == 0
    q = t.load_policy(str(run / f"{name}.pt"))
    assert type(q) is t.CompactQNetwork and q.network() == want
    t.main(tiny(t, run_name="c", resume=True, hidden=None, total_steps=96))  # all from the checkpoint
    state = torch.load(run / "checkpoint.pt", weights_only=True)
    assert state["global_step"] == 96 and state["network"] == "compact" and state["args"]["scale_view"] == 7


def test_the_compact_defaults_when_nothing_is_loaded():
    chosen = rc.with_network(rc.Args(network="compact"), None, None)
    assert (chosen.hidden, chosen.frame_stack, chosen.conv_width) == (256, 3, 32)
    assert (chosen.scales, chosen.scale_factor, chosen.scale_view) == (3, 3, 11)
    assert rc.with_network(rc.Args(), None, None).hidden == 512


# ----------------------------------------------------------------------------- files: export, load, errors
def test_export_and_load_round_trip_of_a_compact_model(tmp_path):
    torch.manual_seed(1)
    q = compact(2, 16, 8, (2, 3, 9))
    path = str(tmp_path / "c.pt")
    gw.export_model(q, rc.Args(export=path), {})
    loaded = rc.load_policy(path)
    assert type(loaded) is rc.CompactQNetwork and loaded.network() == q.network()
    assert json.loads((tmp_path / "c.json").read_text())["network"] == q.network()
    assert rm.load_policy(path).network() == q.network()  # either trainer reads it
    q.reset_noise(False)
    halved = {k: v.half().float() if "sigma" not in k and "eps" not in k else v for k, v in q.state_dict().items()}
    q.load_state_dict(halved)  # what the fp16 export keeps
    core = core_for(multiscale(2, 3, 9), worlds=4)
    stack = rc.Stacker(4, 2, *gw.frame_shape(multiscale(2, 3, 9))[::-1])
    stack.push(gw.observe(core), np.ones(4, bool))
    with torch.no_grad():
        assert torch.allclose(loaded(*gw.to_torch(*stack.get())), q(*gw.to_torch(*stack.get())), atol=1e-6)


def test_a_model_for_another_observation_is_a_one_line_error(tmp_path):
    model = rc.network_of({"weights": {}, **compact(3, 16, 8).network()}, "m.pt")
    for flags, message in [(dict(scales=2), "--scales 2 contradicts m.pt (scales 3)"),
                           (dict(scale_view=9), "--scale-view 9 contradicts m.pt (scale view 11)"),
                           (dict(scale_factor=2), "--scale-factor 2 contradicts m.pt (scale factor 3)"),
                           (dict(network="fig6.8"), "--network fig6.8 contradicts m.pt (network compact)"),
                           (dict(conv_width=48), "--conv-width 48 contradicts m.pt (conv width 8)")]:
        with pytest.raises(ValueError) as e:
            rc.with_network(rc.Args(**flags), model, "m.pt")
        assert str(e.value) == message
    fig = rc.network_of({"weights": {}, **rc.QNetwork(3, rc.VIEW, 16, 0.0).network()}, "f.pt")
    with pytest.raises(ValueError, match=r"^--network compact contradicts f.pt \(network fig6.8\)$"):
        rc.with_network(rc.Args(network="compact"), fig, "f.pt")
    with pytest.raises(ValueError, match=r"^--scales is for --network compact, not fig6.8$"):
        rc.with_network(rc.Args(scales=2), fig, "f.pt")
    # a record that contradicts itself, or asks gridworld for what it does not give
    for blob, match in [({**compact(3, 16, 8).network(), "observation": "deep"}, "a compact network for the deep"),
                        ({**rc.QNetwork(3, rc.VIEW, 16, 0.0).network(), "observation": "multiscale"},
                         "a fig6.8 network for the multiscale"),
                        ({**compact(3, 16, 8).network(), "network": "resnet"}, "a 'resnet' network"),
                        ({**compact(3, 16, 8).network(), "scales": None}, "no frame count or hidden width")]:
        torch.save({"weights": {}, **blob}, tmp_path / "bad.pt")
        with pytest.raises(ValueError, match=match) as e:
            rc.load_policy(str(tmp_path / "bad.pt"))
        assert "\n" not in str(e.value)


@pytest.mark.parametrize("name", TRAINERS)
def test_warm_start_from_a_compact_model_with_other_scales_writes_nothing(name, tmp_path, monkeypatch,
                                                                          restore_sigint):
    t = TRAINERS[name]
    monkeypatch.chdir(tmp_path)
    gw.export_model(compact(3, 16, 8), rc.Args(export="c.pt"), {})
    with pytest.raises(ValueError, match=r"^--scale-view 9 contradicts c.pt \(scale view 11\)$"):
        t.main(tiny(t, init_from="c.pt", scale_view=9, run_name=None))
    assert not (tmp_path / "runs").exists()
    t.main(tiny(t, init_from="c.pt", hidden=None, run_name="w"))  # network, widths and scales from the model
    info = json.loads((tmp_path / "runs" / "w" / f"{name}.json").read_text())
    assert info["network"] == compact(3, 16, 8).network() and info["parent"]["path"] == "c.pt"


def test_a_stage_that_asks_for_another_observation_is_an_error():
    deep = gw.EnvConfig(name="d")
    assert rc.observed([deep], rc.with_network(rc.Args(), None, None)) == [deep]  # fig6.8: as it is
    args = rc.with_network(rc.Args(network="compact", scales=2), None, None)
    (stage,) = rc.observed([deep], args)
    assert (stage.observation, stage.scales, stage.scale_factor, stage.scale_view) == ("multiscale", 2, 3, 11)
    with pytest.raises(ValueError, match="stage m: observation"):
        rc.observed([gw.EnvConfig(name="m", observation="multiscale", scales=3)], args)
    with pytest.raises(ValueError, match="stage m: observation"):
        rc.observed([gw.EnvConfig(name="m", observation="multiscale")], rc.with_network(rc.Args(), None, None))


def test_loading_is_device_agnostic(tmp_path, monkeypatch):
    """A model saved from GPU tensors loads on the CPU (map_location), as does a bare state dict."""
    q = compact(3, 16, 8)
    path = tmp_path / "gpu.pt"
    with monkeypatch.context() as m:  # tag every storage as CUDA's, as torch.save does for GPU tensors
        m.setattr(torch.serialization, "location_tag", lambda storage: "cuda:0")
        gw.export_model(q, rc.Args(export=str(path)), {})
    if not torch.cuda.is_available():
        with pytest.raises(RuntimeError, match="CUDA"):
            torch.load(path, weights_only=True)  # without map_location it would not load here
    assert rc.load_policy(str(path)).network() == q.network()
    bare = tmp_path / "bare.pt"
    torch.save({"weights": q.state_dict(), **q.network()}, bare)
    assert type(rc.load_policy(str(bare))) is rc.CompactQNetwork
    fig = rc.QNetwork(3, rc.VIEW, 16, 0.0)
    torch.save({"weights": fig.state_dict(), "frames": 3, "hidden": 16}, tmp_path / "old.pt")  # an older export
    assert type(rc.load_policy(str(tmp_path / "old.pt"))) is rc.QNetwork


# ----------------------------------------------------------------------------- evaluation
@pytest.mark.parametrize("name", TRAINERS)
def test_evaluate_policy_observes_as_the_network_needs(name):
    """evaluate.py passes q.conv[0].in_channels // 4 as the frame count: the network's own counts."""
    t = TRAINERS[name]
    torch.manual_seed(0)
    q = compact(2, 16, 8, (2, 3, 7), t=t)
    data = gw.load_dataset(str(ROOT / "maps" / ("cpp_eval.npz" if t is rc else "marl_eval.npz")))
    scenarios = [s for s in data if s.obstacles.shape[0] <= 8][:3]
    if t is rm:
        scenarios = [gw.Scenario(s.obstacles, s.starts[:2], s.covered) for s in scenarios]
    frames = q.conv[0].in_channels // 4
    assert frames != q.frames
    wrong = t.evaluate_policy(q, scenarios, frames, heuristic=False)
    right = t.evaluate_policy(q, scenarios, q.frames, heuristic=False)
    assert np.array_equal(wrong["steps"], right["steps"]) and np.array_equal(wrong["overlap"], right["overlap"])


@pytest.mark.parametrize("name", TRAINERS)
def test_device_and_speed_flags_are_accepted(name):
    t = TRAINERS[name]
    args = tyro.cli(t.Args, args=["--network", "compact", "--no-cuda", "--threads", "1", "--replay-ratio", "4",
                                  "--total-steps", "800", "--learning-starts", "400",
                                  "--no-torch-deterministic", "--conv-width", "16", "--scales", "2",
                                  "--scale-factor", "2", "--scale-view", "9"])
    assert (args.network, args.cuda, args.threads, args.torch_deterministic) == ("compact", False, 1, False)
    assert (args.conv_width, args.scales, args.scale_factor, args.scale_view, args.total_steps) == (16, 2, 2, 9, 800)
    assert tyro.cli(t.Args, args=[]).cuda  # CleanRL's --cuda default
    with pytest.raises(ValueError, match="--threads must be >= 0"):
        t.check_flags(replace(args, threads=-1))


# ----------------------------------------------------------------------------- replay bookkeeping, benchmark
def test_the_sum_tree_counts_its_valid_leaves_as_they_change():
    """Replay.sample's importance weights need the number of leaves above zero, kept without a scan."""
    rng = np.random.default_rng(0)
    tree = rc.SumTree(100)
    for _ in range(200):
        idx = rng.integers(0, 100, rng.integers(0, 12))  # repeats included
        tree.update(idx, np.where(rng.random(len(idx)) < 0.3, 0.0, rng.random(len(idx))))
        assert tree.valid == np.count_nonzero(tree.tree[tree.size:] > 0)


def test_the_benchmark_rows_and_the_sb3_frame_stack():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import train_speed

    r = train_speed.row("compact", 256, 32, 1, "cpu", replay_ratio=4.0, env_steps_per_s=512.34)
    assert {"network", "hidden", "batch_size", "threads", "device", "replay_ratio", "ms_per_update",
            "env_steps_per_s"} <= set(r) and r["env_steps_per_s"] == 512.3 and r["ms_per_update"] is None
    assert train_speed.targets([r]) and "PASS" in train_speed.targets([r])[0]
    # the SB3 env sees exactly what rainbow_cpp's Stacker builds
    config = gw.EnvConfig(size=8, number_obstacles=4, obstacles_random=True, **multiscale())
    env = train_speed.Stacked(gw.GridWorldEnv(config), 3)
    twin = gw.GridWorldEnv(config)
    obs, _ = env.reset(seed=5)
    own, _ = twin.reset(seed=5)
    stack = rc.Stacker(1, 3, *gw.frame_shape(multiscale())[::-1])
    stack.push({k: v[None] for k, v in own.items()}, np.ones(1, bool))
    for step in range(30):
        maps, extras = stack.get()
        assert np.array_equal(obs["maps"], maps[0]) and np.allclose(obs["extras"], extras[0])
        action = step % 4
        obs, _, terminated, truncated, _ = env.step(action)
        own, *_ = twin.step(action)
        if terminated or truncated:
            break
        stack.push({k: v[None] for k, v in own.items()}, np.zeros(1, bool))
