"""The dissertation's recipe at scale (issue 43): what the long run needs from the trainers, and its committed state.

- --curve-every appends a learning-curve point (greedy policy with and without the fallback on fixed held-out maps,
  steps/s, peak memory) to runs/RUN/curve.json and to the checkpoint; a resumed run goes on with the same curve.
- A resumed run refills its empty replay memory for learning_starts steps before it learns (--learning-starts and
  --learning-rate may change on --resume), and gets its target network back from the checkpoint.
- SIGTERM and Ctrl-C save a checkpoint and exit 128 + the signal's number.
- diagnostics_of reports hand-computable figures (Q spread, action gap, |TD error|, dead units).
- The compact network's channels-last forward is the grouped convolution of the scale-major channels.
- The scale run's committed checkpoint (models/rainbow_cpp_dissertation_run.pt) loads and resumes with the command
  docs/rainbow_cpp.md gives: a refactor never breaks the long run.
"""
from __future__ import annotations

import json
import os
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn as nn
import tyro

import gridworld as gw
import rainbow_cpp as rc
import rainbow_marl as rm

ROOT = Path(__file__).resolve().parent.parent
SCALE_CHECKPOINT = ROOT / "models" / "rainbow_cpp_dissertation_run.pt"


def tiny(t, **kw):
    base = dict(run_name="t", total_steps=64, num_envs=2, learning_starts=32, buffer_size=2000, hidden=16,
                eval_every=0, save_every=0, quiet=True, cuda=False, network="compact", conv_width=8)
    if t is rm:
        base["init_from"] = ""
    return t.Args(**{**base, **kw})


def small_curve_maps():
    """Three 5x5 held-out maps a set, so that a curve point takes a moment."""
    maps = {name: [gw.Scenario(s.obstacles, s.starts[:1], s.covered) for s in gw.load_dataset(
        ROOT / "maps" / f"{name}.npz")[:3]] for name in gw.CURVE_SLICES}
    return maps


def test_curve_points_go_to_the_json_and_the_checkpoint_and_survive_a_resume(tmp_path, monkeypatch, restore_sigint):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(gw, "curve_maps", small_curve_maps)
    rc.main(tiny(rc, total_steps=64, curve_every=32))
    curve = json.loads((tmp_path / "runs" / "t" / "curve.json").read_text())["curve"]
    assert [p["step"] for p in curve] == [32, 64]
    point = curve[-1]
    for name in ("cpp_eval", "structured_eval"):
        assert point[name]["maps"] == 3 and point[name]["completion"] == 1.0  # the fallback always finishes
        assert 0 <= point[name]["fallback_share"] <= 1
        assert {"maps", "overlap", "completion", "outliers"} <= set(point[f"{name}_alone"])
        assert 0 <= point[f"{name}_alone"]["outliers"] <= 3
    assert set(point["cpp_eval"]["overlap_by_size"]) == set(point["cpp_eval_alone"]["overlap_by_size"]) == {"5"}
    assert point["sps"] > 0 and point["peak_rss_mb"] > 50
    state = torch.load(tmp_path / "runs" / "t" / "checkpoint.pt", weights_only=True)
    assert state["curve"] == curve and set(state["target"]) == set(state["model"])

    rc.main(tiny(rc, total_steps=96, curve_every=32, resume=True))
    resumed = json.loads((tmp_path / "runs" / "t" / "curve.json").read_text())["curve"]
    assert [p["step"] for p in resumed] == [32, 64, 96] and resumed[:2] == curve
    assert [p["steps_since_resume"] for p in resumed] == [32, 64, 32]  # the memory restarted at 64
    rolled_back = torch.load(tmp_path / "runs" / "t" / "checkpoint_32.pt", weights_only=True)
    assert rolled_back["global_step"] == 32 and rolled_back["curve"] == curve[:1]  # each point can be rolled back to


@pytest.mark.parametrize("t", [rc, rm])
def test_the_learning_rate_flag_replaces_the_saved_rate_on_resume(t, tmp_path, monkeypatch, restore_sigint):
    monkeypatch.chdir(tmp_path)
    t.main(tiny(t, total_steps=64, learning_rate=5e-4))
    loaded, start_run = [], t.start_run
    monkeypatch.setattr(t, "start_run", lambda *a: loaded.append(start_run(*a)) or loaded[-1])
    t.main(tiny(t, total_steps=96, learning_rate=2.5e-4, resume=True))
    assert [g["lr"] for g in loaded[0][4].param_groups] == [2.5e-4]
    state = torch.load(tmp_path / "runs" / "t" / "checkpoint.pt", weights_only=True)
    assert state["args"]["learning_rate"] == 2.5e-4
    assert [g["lr"] for g in state["optimizer"]["param_groups"]] == [2.5e-4]


@pytest.mark.parametrize("t", [rc, rm])
def test_past_the_curriculum_its_last_stage_goes_on(t, tmp_path, monkeypatch, restore_sigint):
    """Two stages of 32 steps and --total-steps 96: the second stage runs 64 steps (the scale run's "continue the
    last stage"), with no stage past the last."""
    monkeypatch.chdir(tmp_path)
    agents = ", number_agents: 2" if t is rm else ""
    (tmp_path / "two.yaml").write_text("".join(f"s{i}: {{size: 5, number_obstacles: 2, base_steps: 32{agents}}}\n"
                                               for i in (1, 2)))
    t.main(tiny(t, total_steps=96, stages="two.yaml", stage_steps_scale=1.0))
    state = torch.load(tmp_path / "runs" / "t" / "checkpoint.pt", weights_only=True)
    assert state["global_step"] == 96 and state["stage"] == 1


@pytest.mark.parametrize("t", [rc, rm])
def test_a_resumed_run_keeps_its_own_flags_and_refuses_contradicting_ones(t, tmp_path, monkeypatch, restore_sigint):
    """`--resume --run-name NAME` alone continues the run as it was started; a training flag set otherwise is a
    one-line error; how the run goes (--total-steps, --quiet, ...) is the command line's."""
    monkeypatch.chdir(tmp_path)
    t.main(tiny(t, total_steps=64, learning_rate=5e-4, gamma=0.99, stage_steps_scale=0.5, n_step=3))
    started = torch.load(tmp_path / "runs" / "t" / "checkpoint.pt", weights_only=True)["args"]
    resumed = t.settle_flags(t.Args(run_name="t", resume=True, total_steps=96))
    for key in ("learning_rate", "gamma", "stage_steps_scale", "n_step", "num_envs", "buffer_size", "hidden",
                "network", "conv_width"):
        assert getattr(resumed, key) == started[key], key
    assert resumed.total_steps == 96 and not resumed.quiet  # RUN_FLAGS: from the command line
    with pytest.raises(ValueError, match=r"^--gamma 0.9 contradicts runs/t/checkpoint.pt \(gamma 0.99\)"):
        t.settle_flags(t.Args(run_name="t", resume=True, gamma=0.9))
    assert t.settle_flags(t.Args(run_name="t", resume=True, learning_rate=1e-4)).learning_rate == 1e-4
    assert t.settle_flags(t.Args(run_name="t", resume=True, learning_starts=250_000)).learning_starts == 250_000
    assert t.settle_flags(t.Args(run_name="t", resume=True, seed=2)).seed == 2
    assert t.settle_flags(t.Args(run_name="t", resume=True, tau=0.01)).tau == 0.01


@pytest.mark.parametrize("t", [rc, rm])
def test_a_resume_with_another_seed_draws_other_random_states(t, tmp_path, monkeypatch, restore_sigint):
    """The same --seed puts the run's numpy and torch states back; another one leaves them as it seeded them."""
    monkeypatch.chdir(tmp_path)
    t.main(tiny(t, total_steps=64))
    state = torch.load(tmp_path / "runs" / "t" / "checkpoint.pt", weights_only=False)
    loaded, start_run = [], t.start_run

    def recording(*a):  # the random states as start_run leaves them, before the run draws from them
        run = start_run(*a)
        loaded.append((run[5].bit_generator.state, torch.get_rng_state()))
        return run

    monkeypatch.setattr(t, "start_run", recording)
    for seed, total in ((1, 80), (2, 96)):
        t.main(tiny(t, total_steps=total, resume=True, seed=seed))
    (same, same_torch), (other, other_torch) = loaded
    assert same == state["numpy_rng"] and torch.equal(same_torch, state["torch_rng"])
    assert other == np.random.default_rng(2).bit_generator.state
    assert not torch.equal(other_torch, state["torch_rng"])
    assert torch.load(tmp_path / "runs" / "t" / "checkpoint.pt", weights_only=True)["args"]["seed"] == 2
    assert t.settle_flags(t.Args(run_name="u")).learning_rate == t.LEARNING_RATE  # Table 6.1's / 7.1's


def test_a_resumed_run_refills_its_memory_before_learning_and_keeps_its_target(tmp_path, monkeypatch,
                                                                               restore_sigint):
    monkeypatch.chdir(tmp_path)
    rc.main(tiny(rc, total_steps=64, learning_starts=32))
    state = torch.load(tmp_path / "runs" / "t" / "checkpoint.pt", weights_only=True)
    assert any(not torch.equal(state["target"][k], state["model"][k]) for k in state["model"])  # soft updates lag
    calls, learn = [], rc.learn
    monkeypatch.setattr(rc, "learn", lambda *a, **k: calls.append(1) or learn(*a, **k))
    loaded, start_run = [], rc.start_run

    def recording(*a):
        loaded.append(start_run(*a))
        return loaded[-1]

    monkeypatch.setattr(rc, "start_run", recording)
    rc.main(tiny(rc, total_steps=64 + 32, learning_starts=32, resume=True))  # 32 steps: all of them refill
    assert calls == []
    target = loaded[0][3]
    assert all(torch.equal(target.state_dict()[k], v) for k, v in state["target"].items())
    rc.main(tiny(rc, total_steps=96 + 48, learning_starts=32, resume=True))  # 16 steps past the refill learn
    assert len(calls) == 16 * 8 // 32


@pytest.mark.parametrize("script", ["rainbow_cpp.py", "rainbow_marl.py"])
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_saves_a_checkpoint_and_exits_128_plus_its_number(script, signum, tmp_path):
    flags = ["--total-steps", "100000000", "--num-envs", "2", "--learning-starts", "32", "--buffer-size", "2000",
             "--hidden", "16", "--network", "compact", "--conv-width", "8", "--eval-every", "0", "--save-every", "0",
             "--no-cuda", "--threads", "1", "--run-name", "sig"]
    if script == "rainbow_marl.py":
        flags += ["--init-from", ""]
    run = subprocess.Popen([sys.executable, str(ROOT / script), *flags], cwd=tmp_path, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while not list((tmp_path / "runs" / "sig").glob("events.out.tfevents*")) and time.time() < deadline:
        time.sleep(0.2)
    time.sleep(3)  # inside the training loop
    run.send_signal(signum)
    out, err = run.communicate(timeout=120)
    assert run.returncode == 128 + signum, err
    assert "Traceback" not in err
    state = torch.load(tmp_path / "runs" / "sig" / "checkpoint.pt", weights_only=True)
    assert state["global_step"] > 0 and not (tmp_path / "runs" / "sig" / "checkpoint.pt.tmp").exists()


def test_diagnostics_by_hand():
    torch.manual_seed(0)
    q = rc.build_network({"network": "compact", "frames": 1, "hidden": 4, "conv_width": 2, "scales": 3,
                          "scale_factor": 3, "scale_view": 11}, 0.5)
    with torch.no_grad():  # the value stream's first units never fire; the advantage stream's always do
        q.value[0].weight_mu.zero_()
        q.value[0].weight_sigma.zero_()
        q.value[0].bias_mu.fill_(-1.0)
        q.value[0].bias_sigma.zero_()
        q.advantage[0].weight_mu.zero_()
        q.advantage[0].weight_sigma.fill_(0.25)
        q.advantage[0].bias_mu.fill_(1.0)
        q.advantage[0].bias_sigma.zero_()
    q.reset_noise(False)
    maps, extras = torch.zeros(2, 15, 11, 11, dtype=torch.uint8), torch.zeros(2, 1 + rc.EXTRAS)
    q_all = torch.tensor([[1.0, 4.0, 2.0, 0.0], [0.5, 0.5, 0.5, 0.5]])
    tagged = rc.diagnostics_of(q, maps, extras, q_all, torch.tensor([-2.0, 1.0]), torch.tensor([0.5, 1.0]),
                               torch.tensor(3.0), {"td_loss": torch.tensor(0.25), "margin_loss": None})
    assert tagged["losses/td_loss"] == 0.25 and "losses/margin_loss" not in tagged  # None: not computed
    d = {k.removeprefix("diagnostics/"): v for k, v in tagged.items() if k.startswith("diagnostics/")}
    assert d["q_spread"] == pytest.approx((4 + 0) / 2)
    assert d["action_gap"] == pytest.approx((2 + 0) / 2)
    assert d["td_error"] == pytest.approx(1.5)
    assert d["importance_weight_min"] == 0.5 and d["grad_norm"] == 3.0
    assert d["dead_units_value"] == 1.0 and d["dead_units_advantage"] == 0.0
    sigmas = [m.weight_sigma.detach().abs().mean() for m in q.modules() if isinstance(m, rc.NoisyLinear)]
    assert d["noisy_sigma"] == pytest.approx(float(torch.stack(sigmas).mean()))


def test_the_channels_last_forward_is_the_grouped_convolution_of_scale_major_channels():
    torch.manual_seed(1)
    q = rc.build_network({"network": "compact", "frames": 3, "hidden": 16, "conv_width": 8, "scales": 3,
                          "scale_factor": 3, "scale_view": 11}, 0.5)
    q.reset_noise(False)
    maps = torch.randint(0, 256, (5, 45, 11, 11), dtype=torch.uint8)
    extras = torch.rand(5, 1 + 3 * rc.EXTRAS)
    x = maps.reshape(5, 3, 3, 5, 11, 11).transpose(1, 2).reshape(5, 45, 11, 11).float() / 255  # frames within a scale
    expected = q.head(torch.cat([nn.Sequential(*q.conv)(x.contiguous()), extras], 1))
    with torch.no_grad():
        assert torch.allclose(q(maps, extras), expected, atol=1e-5)


def docs_command(marker: str = "scale-run") -> list[str]:
    """A long run's resume command as docs/rainbow_cpp.md gives it (the block after `<!-- marker -->`)."""
    text = (ROOT / "docs" / "rainbow_cpp.md").read_text()
    block = text.split(f"<!-- {marker} -->", 1)[1].split("```bash", 1)[1].split("```", 1)[0]
    command = next(line for line in block.replace("\\\n", " ").splitlines() if "rainbow_cpp.py" in line)
    words = shlex.split(command)
    return words[words.index("rainbow_cpp.py") + 1:]


@pytest.mark.skipif(not SCALE_CHECKPOINT.exists(), reason="the scale run has not committed its state yet")
def test_the_committed_scale_run_resumes_with_the_documented_command(tmp_path, monkeypatch, restore_sigint):
    flags = docs_command()
    assert "--resume" in flags and flags[flags.index("--run-name") + 1] == "rainbow_cpp_dissertation"
    state = gw.load_checkpoint(str(SCALE_CHECKPOINT), "rainbow_cpp")
    args = tyro.cli(rc.Args, args=flags)
    recorded = state["args"]
    for key in ("network", "learning_rate", "stage_steps_scale", "camera_stages", "heuristic_dead_ends",
                "heuristic_random_ties", "curve_every", "margin_loss", "hint", "teacher", "seed", "buffer_size",
                "batch_size", "replay_ratio", "imitation", "challenging", "uncommon_patterns", "peb", "partial_reset"):
        assert getattr(args, key) == recorded[key], key  # the docs resume the run that was started
    run = tmp_path / "runs" / "rainbow_cpp_dissertation"
    run.mkdir(parents=True)
    shutil.copy(SCALE_CHECKPOINT, run / "checkpoint.pt")
    monkeypatch.chdir(tmp_path)
    settled = rc.settle_flags(args)  # the documented flags do not contradict the run's own
    assert all(getattr(settled, k) == v for k, v in recorded.items() if k not in gw.RUN_FLAGS + gw.RESUME_FLAGS
               and hasattr(settled, k))
    resumed = rc.start_run(args, 6)
    q, target = resumed[2], resumed[3]
    assert resumed[6][:2] == (state["global_step"], state["stage"])
    assert all(torch.equal(q.state_dict()[k], v) for k, v in state["model"].items())
    assert all(torch.equal(target.state_dict()[k], v) for k, v in state["target"].items())
    assert resumed[6][3] == state["curve"]
    with torch.no_grad():
        assert torch.isfinite(q(torch.zeros(1, 45, 11, 11, dtype=torch.uint8), torch.zeros(1, 1 + 3 * rc.EXTRAS))).all()
    assert os.path.getsize(SCALE_CHECKPOINT) <= 20 * 2**20
    assert np.isfinite(state["wall"])


def test_the_recipe_learns_stage_1_from_reward_alone(tmp_path, monkeypatch, restore_sigint):
    """Table 6.2's first stage (sizes 4-5) from scratch with the scale run's flags, 40,000 steps (~3 min on one core):
    the greedy policy covers held-out maps below its teacher, the dissertation's random-tie heuristic, and finishes
    nearly all of them without the fallback. At Table 6.1's 5e-5 the same run does not learn (docs/rainbow_cpp.md)."""
    monkeypatch.chdir(tmp_path)
    threads = torch.get_num_threads()
    args = tyro.cli(rc.Args, args=["--network", "compact", "--no-cuda", "--threads", "1", "--no-heuristic-dead-ends",
                                   "--heuristic-random-ties", "--no-camera-stages", "--learning-rate", "5e-4",
                                   "--total-steps", "40000", "--buffer-size", "100000", "--eval-every", "0",
                                   "--save-every", "0", "--quiet", "--run-name", "stage1"])
    try:
        rc.main(args)
    finally:
        torch.set_num_threads(threads)
    q = rc.load_policy(str(tmp_path / "runs" / "stage1" / "rainbow_cpp.pt"))
    maps = gw.generate_scenarios(64, seed=123, size=5, min_size=4, random_size=True, number_obstacles=5,
                                 obstacles_random=True)
    with_fallback = rc.evaluate_policy(q, maps, 3, heuristic=True, dead_ends_first=False)
    alone = rc.evaluate_policy(q, maps, 3, heuristic=False, dead_ends_first=False)
    teacher = gw.heuristic_walk(gw.replay_config(maps), maps, random_ties=True, dead_ends_first=False)
    assert with_fallback["overlap"].mean() < teacher["overlap"].mean()
    assert alone["completed"].mean() >= 0.9


FINETUNE_CHECKPOINT = ROOT / "models" / "rainbow_cpp_td_finetune_run.pt"


@pytest.mark.skipif(not FINETUNE_CHECKPOINT.exists(), reason="the fine-tuning run has not committed its state yet")
def test_the_committed_td_finetuning_resumes_with_the_documented_command(tmp_path, monkeypatch, restore_sigint):
    """Issue 43 item 6: the TD fine-tuning of the shipped model continues from its committed state, TD alone."""
    run = tmp_path / "runs" / "rainbow_cpp_td_finetune"
    run.mkdir(parents=True)
    shutil.copy(FINETUNE_CHECKPOINT, run / "checkpoint.pt")
    monkeypatch.chdir(tmp_path)
    args = rc.settle_flags(tyro.cli(rc.Args, args=docs_command("td-finetune")))
    assert (args.td_weight, args.margin_loss, args.teacher, args.hint, args.heuristic_far_first) == (1.0, 0.0, "heuristic",
                                                                                                     True, True)
    state = gw.load_checkpoint(str(FINETUNE_CHECKPOINT), "rainbow_cpp")
    assert rc.start_run(args, 1)[6][:2] == (state["global_step"], state["stage"])
    assert os.path.getsize(FINETUNE_CHECKPOINT) <= 20 * 2**20
