"""Tests for --hint (the heuristic's move as a network input) and the margin loss.

- observe(hint=True) adds the deterministic heuristic's move, agent-major, the same the fallback would take;
  the replay stores it per frame and gives it back one-hot after the last frame's extras, and in batches.
- The margin loss by hand-computed amounts; labels are needed exactly when --margin-loss is on.
- A model without a hint warm-starts into a hinted network with the very same Q values (zero hint weights).
- A tiny hinted run with the rollout teacher exports a model that records the hint, and evaluate_policy and
  evaluate.py run it; bad flag combinations are one-line errors and write nothing.
"""
from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

import classical_cpp as cc  # noqa: E402
import gridworld as gw  # noqa: E402
import rainbow_cpp as rc  # noqa: E402


def corridor_core() -> gw.GridWorldCore:
    """Agent at (0, 2) of '..@.' over '.00.': greedy-dead-ends goes WEST (tests/test_rollout_teacher.py)."""
    chars = np.array([list("..@."), list(".00.")])
    s = cc.with_starts(gw.Scenario(chars == "0", np.argwhere(chars == "@")))
    core = gw.GridWorldCore(gw.EnvConfig(load_state=True, load_random=False), 1)
    core.configure(scenarios=[s])
    core.reset()
    return core


def test_observe_adds_the_heuristic_move():
    core = corridor_core()
    assert "hint" not in gw.observe(core)
    assert gw.observe(core, hint=True)["hint"].tolist() == [gw.WEST]
    team = gw.GridWorldCore(gw.EnvConfig(number_agents=3, size=8), 4, seed=3)
    team.reset()
    assert np.array_equal(gw.observe(team, hint=True)["hint"], gw.heuristic_actions(team, False, True).reshape(-1))


def test_replay_and_stacker_carry_the_hint_one_hot():
    core = gw.GridWorldCore(gw.EnvConfig(size=6), 2, seed=0)
    core.reset()
    replay = rc.Replay(64, 2, rc.VIEW, 2, 1, 0.99, 0.5, hint=True)
    plain = rc.Replay(64, 2, rc.VIEW, 2, 1, 0.99, 0.5)
    assert replay.bytes_per_transition() == plain.bytes_per_transition() + 1
    obs = gw.observe(core, hint=True)
    obs["hint"] = np.array([gw.SOUTH, gw.WAIT])
    slot = replay.add_frames(np.arange(2), obs, np.zeros(2, np.int64), np.zeros(2, bool))
    _, extras = replay._frames(slot)
    _, plain_extras = plain._frames(plain.add_frames(np.arange(2), obs, np.zeros(2, np.int64), np.zeros(2, bool)))
    assert extras.shape[1] == plain_extras.shape[1] + rc.HINTS == 1 + 2 * rc.EXTRAS + 5
    assert np.array_equal(extras[:, :-5], plain_extras)
    assert extras[:, -5:].tolist() == [[0, 1, 0, 0, 0], [0, 0, 0, 0, 1]]
    stack = rc.Stacker(2, 2, rc.VIEW, hint=True)
    stack.push(obs, np.ones(2, bool))
    assert np.array_equal(stack.get()[1], extras)


def test_margin_loss_weights_by_hand():
    q = torch.tensor([[1.0, 0.0, 0.0, 0.0], [0.0, 2.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]])
    label = torch.tensor([0, 0, -1])
    # state 0: the label leads by 1 >= margin 0.5: max(1, 0.5) - 1 = 0; state 1: max(0, 2 + 0.5) - 0 = 2.5;
    # state 2 has no label
    assert rc.large_margin_loss(q, label, 0.5).item() == pytest.approx(2.5 / 2)


@pytest.mark.parametrize("network", ["fig6.8", "compact"])
def test_a_hint_free_model_warm_starts_with_the_same_q(tmp_path, monkeypatch, network):
    spec = {**rc.COMPACT, "network": network, "frames": 2, "hidden": 16, "view": rc.VIEW}
    parent = rc.build_network(spec, 0.5)
    gw.export_model(parent, rc.Args(export=str(tmp_path / "p.pt"), network=network), {})
    monkeypatch.chdir(tmp_path)
    args = rc.Args(run_name="w", init_from=str(tmp_path / "p.pt"), hint=True, threads=1, quiet=True)
    q = rc.start_run(rc.settle_flags(args), 1)[2]
    assert q.hint and q.network()["hint"]
    loaded = rc.load_policy(str(tmp_path / "p.pt"))
    q.reset_noise(False)
    channels, view = gw.frame_shape(rc.observation_settings(q.network()))
    maps = torch.randint(0, 256, (5, channels * 2, view, view), dtype=torch.uint8)
    extras = torch.rand(5, 1 + 2 * rc.EXTRAS)
    hint = torch.eye(rc.HINTS)[torch.tensor([0, 1, 2, 3, 4])]
    with torch.no_grad():
        assert torch.allclose(q(maps, torch.cat([extras, hint], 1)), loaded(maps, extras), atol=2e-3)


def tiny(tmp_path, **kw) -> rc.Args:
    base = dict(run_name="t", total_steps=200, learning_starts=100, hidden=16, num_envs=4, buffer_size=4096,
                eval_every=0, save_every=0, export=str(tmp_path / "m.pt"), stage_steps_scale=0.001,
                replay_ratio=1.0, margin_loss=1.0, quiet=True, threads=1, network="compact")
    return rc.Args(**{**base, **kw})


def test_a_hinted_run_exports_a_model_that_evaluates(tmp_path, monkeypatch, restore_sigint):
    monkeypatch.chdir(tmp_path)
    rc.main(tiny(tmp_path, hint=True, teacher="rollout", margin_loss=0.5))
    info = json.loads((tmp_path / "m.json").read_text())
    assert info["network"]["hint"] is True and info["args"]["teacher"] == "rollout"
    q = rc.load_policy(str(tmp_path / "m.pt"))
    assert q.hint
    maps = gw.load_dataset(str(ROOT / "maps" / "cpp_eval.npz"))[:3]
    m = rc.evaluate_policy(q, maps, 3)
    assert m["completed"].all()
    # a resume keeps the hint without the flag; resuming a hint-free checkpoint with --hint is refused
    rc.main(replace(tiny(tmp_path, total_steps=260, margin_loss=0.5), resume=True))
    assert json.loads((tmp_path / "m.json").read_text())["network"]["hint"] is True
    rc.main(tiny(tmp_path, run_name="plain", overwrite=True))  # a new run over the first run's export
    with pytest.raises(ValueError, match=r"--hint True contradicts runs/plain/checkpoint.pt \(hint False\)"):
        rc.main(replace(tiny(tmp_path, run_name="plain", total_steps=260), resume=True, hint=True))


@pytest.mark.parametrize("kw, msg", [(dict(margin_loss=-1.0), "--margin-loss must be >= 0"),
                                     (dict(time_limit=-1.0), "--time-limit must be >= 0")])
def test_bad_margin_and_time_flags_are_one_line_errors(tmp_path, monkeypatch, restore_sigint, kw, msg):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match=msg) as e:
        rc.main(tiny(tmp_path, **kw))
    assert "\n" not in str(e.value)
    assert not (tmp_path / "runs").exists()


def test_time_limit_bounds_the_run(tmp_path, monkeypatch, restore_sigint):
    """A limit already spent stops the run before its first step (it still saves and exports)."""
    monkeypatch.chdir(tmp_path)
    rc.main(tiny(tmp_path, time_limit=1e-9, total_steps=10 ** 6))
    assert json.loads((tmp_path / "m.json").read_text())["global_step"] == 0
