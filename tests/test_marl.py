"""Tests for rainbow_marl.py (parameter-shared Rainbow for multi-agent coverage, chapter 7).

Every expectation is a rule of the world or counted by hand on a tiny map:
- the replay memory keeps one segment per (world, agent): the last action stored with each frame
  is the action of the same agent's previous transition, and stacks never mix agents;
- eq. 7.3 / 7.4 / 7.5 rewards of a hand-made step, as the run's stage settings configure them;
- one forward pass gives the actions of every working agent of every world, equal to each agent
  acting alone with its own copy of the weights (decentralised execution);
- a faulty agent stays put and the others still finish the map;
- a smoke run trains over a change of the number of agents, saves, resumes and is loaded by
  evaluate.py; bad flags are one-line errors.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import from_rows

import evaluate
import gridworld as gw
import rainbow_marl as rm

ROOT = Path(__file__).resolve().parent.parent


STAGES = """\
two: {base_steps: 300, number_agents: 2, size: 6, min_size: 4, random_size: true, number_obstacles: 4, obstacles_random: true}
three: {base_steps: 1500, number_agents: 3, size: 7, min_size: 5, random_size: true, number_obstacles: 5, obstacles_random: true}
"""


def small_args(tmp_path, **kw):
    (tmp_path / "stages.yaml").write_text(STAGES)
    base = dict(run_name="t", stages=str(tmp_path / "stages.yaml"), total_steps=600, learning_starts=100,
                hidden=16, num_envs=3, buffer_size=3 * 3 * 200, eval_every=300, eval_maps=4, save_every=300,
                export=str(tmp_path / "m.pt"), replay_ratio=2.0, init_from="")
    return rm.Args(**{**base, **kw})


def capture_replays(monkeypatch) -> list:
    made = []

    class Recorded(rm.Replay):
        def __init__(self, *a, **k):
            super().__init__(*a, **k)
            made.append(self)

    monkeypatch.setattr(rm, "Replay", Recorded)
    return made


# ----------------------------------------------------------------------------- replay per agent
def consecutive_pairs(r: rm.Replay):
    """(slot, next slot) of every stored transition whose successor frame is in the same episode."""
    for stream in range(r.worlds):
        n = int(r.filled[stream])
        order = stream * r.cap + (r.pointer[stream] - n + np.arange(n)) % r.cap
        for a, b in zip(order[:-1], order[1:]):
            if r.age[b] == r.age[a] + 1 and not r.final[a]:
                yield a, b


def test_replay_keeps_each_agents_frames_apart(tmp_path, monkeypatch, restore_sigint):
    monkeypatch.chdir(tmp_path)
    torch.set_num_threads(1)
    replays = capture_replays(monkeypatch)
    rm.main(small_args(tmp_path, eval_every=0, save_every=0, imitation=0.5))
    assert [r.worlds for r in replays] == [3 * 2, 3 * 3]  # one segment per (world, agent); rebuilt for N = 3
    for r in replays:
        pairs = list(consecutive_pairs(r))
        assert len(pairs) > 100
        # the last action seen in a frame is the action this same agent took one frame earlier
        assert all(r.last[b] == r.action[a] for a, b in pairs)
        assert all(0 <= r.action[a] < 4 for a, _ in pairs)  # WAIT is never a learned action
        # sampled transitions: the next state's newest frame is the same agent's next frame
        rng = np.random.default_rng(0)
        slot, _, action, _, (next_maps, next_extras), _, _ = r.sample(64, 0.4, rng)
        successor = dict(pairs)
        for i, s in enumerate(slot):
            if s in successor:
                m1, e1 = r._frames(np.array([successor[s]]))
                assert np.array_equal(next_maps[i], m1[0]) and np.array_equal(next_extras[i], e1[0])
                assert next_extras[i][1 + 2 * 13:1 + 2 * 13 + 5].argmax() == action[i]


def test_episodes_draw_the_number_of_agents(tmp_path):
    stage = gw.EnvConfig(number_agents=4, size=8, number_obstacles=3)
    args = rm.Args(init_from="")
    core = gw.GridWorldCore(rm.stage_config(stage, args), 200, seed=0)
    core.reset()
    assert set(core.active.sum(1).tolist()) == {1, 2, 3, 4}  # §7.4.2.1: N drawn in [1, 4]
    fixed = gw.GridWorldCore(rm.stage_config(stage, rm.Args(init_from="", random_agents=False)), 50, seed=0)
    fixed.reset()
    assert (fixed.active.sum(1) == 4).all()


# ----------------------------------------------------------------------------- rewards (§7.3.3)
@pytest.mark.parametrize("structure, gain, expected", [
    ("competitive", 0.25, [0.0, 0.0, -1.0]),  # eq. 7.3: -1 a step, +1 a new cell
    ("cooperative", 0.5, [0.25, 0.25, -0.5]),  # eq. 7.4: + K/(N-1) * the others' new cells
    ("size_invariant", 0.25, [-0.125, -0.125, -0.75]),  # eq. 7.5: (1 - K) own + K/(N-1) others'
])
def test_the_runs_reward_structure_reaches_the_world(tmp_path, structure, gain, expected):
    # three agents in a row; agents 0 and 1 step onto new cells, agent 2 onto an already covered one
    scenario = gw.Scenario(np.zeros((3, 3), bool), np.array([[0, 0], [1, 0], [2, 0]]),
                           np.array([[1, 0, 0], [1, 0, 0], [1, 1, 0]], bool))
    stage = gw.EnvConfig(number_agents=3, load_state=True)
    cfg = rm.stage_config(stage, rm.Args(init_from="", reward_structure=structure, gain=gain))
    core = gw.GridWorldCore(cfg.replace(number_agent_random=False), 1)
    core.configure(scenarios=[scenario])
    core.reset()
    ev = core.step(np.array([[gw.EAST, gw.EAST, gw.EAST]]))
    assert ev["new"][0].tolist() == [True, True, False]
    np.testing.assert_allclose(ev["reward"][0], expected)


@pytest.mark.parametrize("kw,message", [
    (dict(reward_structure="selfish"), "--reward-structure must be one of"),
    (dict(reward_structure="size_invariant", gain=1.5), "--gain 1.5"),
    (dict(gain=-0.1), "--gain -0.1"),
])
def test_bad_reward_flags(tmp_path, monkeypatch, kw, message):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match=message):
        rm.main(small_args(tmp_path, **kw))


def test_default_curriculum_is_table_7_2_for_2_5_10_agents():
    stages = rm.load_stages(rm.Args(init_from=""))
    assert [s.number_agents for s in stages] == [2] * 6 + [5] * 6 + [10] * 6
    first = stages[:6]
    assert [s.base_steps for s in first] == [1_000_000, 2_000_000, 3_000_000, 5_000_000, 10_000_000, 20_000_000]
    assert [(s.min_size, s.size, s.number_obstacles) for s in first] == [
        (4, 5, 5), (5, 10, 10), (10, 15, 20), (10, 20, 30), (10, 25, 40), (5, 30, 50)]
    for s in stages:  # every stage, even 10 agents with up to 50 obstacles on 5x5..30x30, draws maps
        core = gw.GridWorldCore(rm.stage_config(s, rm.Args(init_from="")), 8, seed=1)
        core.reset()
        small = core.hw[:, 0] * core.hw[:, 1]
        assert (core.n_poi_start >= 1).all() and (core.n_free <= small).all()


# ----------------------------------------------------------------------------- acting
class CountingQ(torch.nn.Module):
    def __init__(self, q):
        super().__init__()
        self.q, self.batches = q, []

    def reset_noise(self, on=True):
        self.q.reset_noise(on)

    def forward(self, maps, extras):
        self.batches.append(len(maps))
        return self.q(maps, extras)


def marl_scenarios(n_maps: int, agents: int, size_at_most: int = 12):
    data = gw.load_dataset(str(ROOT / "maps" / "marl_eval.npz"))
    sizes = np.load(ROOT / "maps" / "marl_eval.npz")["size"]
    keep = [i for i in np.flatnonzero((sizes >= 8) & (sizes <= size_at_most))][:n_maps]
    return [gw.Scenario(data[i].obstacles, data[i].starts[:agents]) for i in keep]


def test_one_forward_pass_acts_for_every_agent_as_its_own_copy_would():
    torch.manual_seed(0)
    q = rm.QNetwork(3, 41, 16, 0.5)
    q.reset_noise(False)
    counting = CountingQ(q)
    scenarios = marl_scenarios(3, 4)
    m = rm.evaluate_policy(counting, scenarios, 3, heuristic=False)
    assert counting.batches[0] == 3 * 4  # the first step: every agent of every world in one pass
    assert len(counting.batches) == m["steps"].max()  # one pass per step, never one per agent
    # decentralised: each agent's own copy of the weights on its own observation picks the same action
    core = gw.GridWorldCore(gw.EnvConfig(load_state=True, number_agents=4), 3)
    core.configure(scenarios=scenarios)
    core.reset()
    stack = rm.Stacker(12, 3, core.V)
    stack.push(gw.observe(core), np.ones(12, bool))
    maps, extras = gw.to_torch(*stack.get())
    q.reset_noise(False)  # evaluate_policy turned the training noise back on
    with torch.no_grad():
        together = q(maps, extras).argmax(1)
    copies = []
    for i in range(12):
        own = rm.QNetwork(3, 41, 16, 0.5)
        own.load_state_dict(q.state_dict())
        own.reset_noise(False)
        with torch.no_grad():
            copies.append(own(maps[i:i + 1], extras[i:i + 1]).argmax(1).item())
    assert together.tolist() == copies


def test_faulty_agent_stays_put_and_the_others_finish():
    torch.manual_seed(0)
    q = rm.QNetwork(3, 41, 16, 0.5)
    scenarios = marl_scenarios(4, 3)
    m = rm.evaluate_policy(q, scenarios, 3, faulty_at=0.5)
    assert m["completed"].all() and (m["agents"] == 3).all()
    # by hand: freeze agent 2 of a world, then no action or heuristic target moves it
    core = gw.GridWorldCore(gw.EnvConfig(load_state=True, number_agents=3), 1)
    core.configure(scenarios=scenarios[:1])
    core.reset()
    core.freeze([0], 2)
    where = core.agent_cells()[0, 2].copy()
    assert gw.heuristic_actions(core, False)[0, 2] == gw.WAIT
    for a in (gw.NORTH, gw.SOUTH, gw.WEST, gw.EAST):
        core.step(np.array([[gw.heuristic_actions(core, False)[0, 0], gw.WAIT, a]]))
        assert (core.agent_cells()[0, 2] == where).all()


def test_a_frozen_agent_in_a_corridor_walls_off_the_cells_behind_it():
    """Corridor 0 . 1 . . with agent 1 frozen: cells (0, 3) and (0, 4) lie behind it, (0, 1) does not; frozen in the
    open (a 2-row map), it walls nothing off. A team never completes a walled-off map: evaluate_policy says which,
    and ends that episode once the working agent has covered what it can reach, not at the step limit."""
    corridor = from_rows(["0.1.."])
    core = gw.GridWorldCore(gw.EnvConfig(load_state=True, load_random=False, number_agents=2), 2)
    core.configure(scenarios=[corridor, from_rows(["0.1..", "....."])])
    core.reset()
    assert core.unreachable_poi().tolist() == [0, 0]
    core.freeze([0, 1], 1)
    assert core.unreachable_poi().tolist() == [2, 0] and core.unreachable_poi([0]).tolist() == [2]
    torch.manual_seed(0)
    q = rm.QNetwork(3, 41, 16, 0.5)
    m = rm.evaluate_policy(q, [from_rows(["0...1...."]), from_rows(["0.1..", "....."])], 3, faulty_at=0.3)
    assert m["walled_off"].tolist() == [True, False]
    assert m["completed"].tolist() == [False, True]
    assert m["truncated"].tolist() == [False, False]
    paths = []
    m = rm.evaluate_policy(q, [from_rows(["0...1...."])], 3, faulty_at=0.3, trajectories=paths)
    columns = paths[0][:, :, 1]  # (T + 1, 2): the row is 0 throughout
    frozen_at = columns[-1, 1]  # agent 1 froze there; the cells before it are agent 0's to cover
    first_walked = [np.flatnonzero((columns == x).any(1))[0] for x in range(frozen_at)]
    assert len(columns) - 1 == max(first_walked)  # the episode ends on the step that covers the last of them


def test_the_heuristic_routes_around_a_frozen_agent():
    """Agent 0 at (0, 0), agent 1 at (0, 1), the bottom row covered: the nearest point of interest (0, 2) lies 2 steps
    east through agent 1's cell, 4 steps round by the bottom row. A moving agent 1 is no obstacle (EAST); a frozen one
    never moves off its cell, so the heuristic goes round (SOUTH) instead of waiting behind it for ever."""
    core = gw.GridWorldCore(gw.EnvConfig(load_state=True, load_random=False, number_agents=2), 1)
    core.configure(scenarios=[from_rows(["01..", "xxxx"])])
    core.reset()
    assert gw.heuristic_actions(core, False, True)[0, 0] == gw.EAST
    core.freeze([0], 1)
    assert gw.heuristic_actions(core, False, True)[0].tolist() == [gw.SOUTH, gw.WAIT]
    for _ in range(4):
        core.step(gw.heuristic_actions(core, False, True))
    assert core.covered[0, core.c, core.c + 2] and core.unreachable_poi().tolist() == [0]


def test_missed_actions_slow_the_team_down():
    torch.manual_seed(0)
    q = rm.QNetwork(3, 41, 16, 0.5)
    scenarios = marl_scenarios(6, 2)
    clean = rm.evaluate_policy(q, scenarios, 3)
    lossy = rm.evaluate_policy(q, scenarios, 3, action_loss=0.5, seed=3)
    assert clean["completed"].all() and lossy["completed"].all()
    assert lossy["steps"].sum() > clean["steps"].sum()


# ----------------------------------------------------------------------------- the whole run
def test_smoke_run_trains_saves_resumes_and_evaluates(tmp_path, monkeypatch, restore_sigint):
    monkeypatch.chdir(tmp_path)
    torch.set_num_threads(1)
    rm.main(small_args(tmp_path, margin_loss=1.0, total_steps=1050))  # losses and SPS are logged every 1000 steps
    ckpt = tmp_path / "runs" / "t" / "checkpoint.pt"
    state = torch.load(ckpt, map_location="cpu", weights_only=False)
    assert state["global_step"] == 1050 and state["stage"] == 1  # ran into the three-agent stage
    info = json.loads((tmp_path / "m.json").read_text())
    assert info["stage"] == "three" and info["args"]["reward_structure"] == "size_invariant"
    blob = torch.load(tmp_path / "m.pt", map_location="cpu", weights_only=False)
    assert all(v.dtype == torch.float16 for v in blob["weights"].values())

    rm.main(small_args(tmp_path, resume=True, total_steps=1200))
    state2 = torch.load(ckpt, map_location="cpu", weights_only=False)
    assert state2["global_step"] == 1200
    assert any(not torch.equal(state2["model"][k], state["model"][k]) for k in state["model"])

    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    tags = set()
    for p in (tmp_path / "runs" / "t").glob("events.out.tfevents*"):
        acc = EventAccumulator(str(p))
        acc.Reload()
        tags |= set(acc.Tags()["scalars"])
    assert {"charts/episodic_return", "charts/time_save", "charts/SPS", "losses/td_loss", "losses/margin_loss",
            "eval/time_save", "eval/completion"} <= tags

    out = evaluate.main(evaluate.Args(policy="marl", checkpoint=str(tmp_path / "m.pt"), agents=3,
                                      dataset=str(ROOT / "maps" / "marl_eval.npz"), limit=4, out=str(tmp_path / "e")))
    assert out["all"]["episodes"] == 4 and out["all"]["completion_rate"] == 1.0
    rows = (tmp_path / "e" / "episodes.csv").read_text().splitlines()
    assert all(r.split(",")[3] == "3" for r in rows[1:])  # three agents in every episode


def test_transfer_from_a_single_agent_model(tmp_path, monkeypatch, restore_sigint):
    """--init-from a rainbow_cpp export: the shared network starts from its mean weights."""
    import rainbow_cpp
    monkeypatch.chdir(tmp_path)
    single = rainbow_cpp.QNetwork(3, 41, 16, 0.0)
    gw.export_model(single, rainbow_cpp.Args(hidden=16, export=str(tmp_path / "single.pt")), {})
    rm.main(small_args(tmp_path, init_from=str(tmp_path / "single.pt"), total_steps=30, learning_starts=10 ** 6,
                       eval_every=0, save_every=0))
    model = torch.load(tmp_path / "runs" / "t" / "checkpoint.pt", map_location="cpu", weights_only=False)["model"]
    for k, v in single.state_dict().items():
        if "sigma" not in k and "eps" not in k:
            assert torch.allclose(model[k], v.half().float()), k
    with pytest.raises(ValueError, match="hidden 16"):
        rm.main(small_args(tmp_path, init_from=str(tmp_path / "single.pt"), hidden=32, run_name="t2"))


@pytest.mark.parametrize("flags,message", [
    (["--init-from", "models/none.pt"], "no such checkpoint"),
    (["--resume", "--run-name", "never", "--init-from", ""], "nothing to resume"),
    (["--stages", "missing.yaml", "--init-from", ""], "missing.yaml"),
])
def test_bad_flags_are_one_line_errors(tmp_path, flags, message):
    result = subprocess.run([sys.executable, str(ROOT / "rainbow_marl.py"), *flags], cwd=tmp_path,
                            capture_output=True, text=True)
    assert result.returncode != 0 and "Traceback" not in result.stderr
    assert result.stderr.strip().startswith("error:") and message in result.stderr


@pytest.mark.parametrize("kw,message", [
    (dict(agents=1, faulty_agent_at=0.5), "--faulty-agent-at needs --agents >= 2"),
    (dict(agents=2, action_loss=1.0), "--action-loss must be in"),
    (dict(agents=2, checkpoint="models/none.pt"), "no such checkpoint"),
])
def test_evaluate_refuses_bad_marl_requests(tmp_path, kw, message):
    with pytest.raises(ValueError, match=message):
        evaluate.main(evaluate.Args(policy="marl", dataset=str(ROOT / "maps" / "marl_eval.npz"), limit=1,
                                    out=str(tmp_path / "o"), **kw))


@pytest.mark.parametrize("dead_ends, far_first", [(True, False), (False, False), (True, True)])
def test_teacher_and_fallback_use_the_dead_ends_flag(tmp_path, monkeypatch, restore_sigint, heuristic_ties,
                                                     dead_ends, far_first):
    """Every heuristic call of training and of its evaluations breaks ties as --heuristic-dead-ends and
    --heuristic-far-first say."""
    monkeypatch.chdir(tmp_path)
    rm.main(small_args(tmp_path, total_steps=240, save_every=0, eval_every=150, margin_loss=1.0,
                       heuristic_dead_ends=dead_ends, heuristic_far_first=far_first))
    assert len(heuristic_ties) > 50 and set(heuristic_ties) == {(dead_ends, far_first)}


# ----------------------------------------------------------------------------- --teacher rollout
def test_team_rollout_labels_are_the_multiagent_rollout_where_needed():
    """The worlds where the teacher acts get gridworld.team_rollout_actions, the rest keep the heuristic's labels;
    with a margin loss every world gets the rollout's."""
    maps = gw.generate_scenarios(6, seed=4, size=7, number_obstacles=5, obstacles_random=True, number_agents=2)
    core = gw.GridWorldCore(gw.EnvConfig(load_state=True, load_random=False, number_agents=2), 6)
    core.configure(scenarios=maps)
    core.reset()
    heuristic = gw.heuristic_actions(core, False, True)
    teach = np.zeros((6, 2), bool)
    teach[[1, 4], 0] = True
    args = rm.Args(init_from="", teacher="rollout")
    label, w = rm.team_rollout_labels(core, heuristic, teach, args)
    assert w.tolist() == [1, 4]
    assert np.array_equal(label[w], gw.team_rollout_actions(core, w)) and np.array_equal(label[[0, 2, 3, 5]],
                                                                                   heuristic[[0, 2, 3, 5]])
    everywhere, w = rm.team_rollout_labels(core, heuristic, teach, rm.Args(init_from="", teacher="rollout",
                                                                          margin_loss=1.0))
    assert w.tolist() == list(range(6)) and np.array_equal(everywhere, gw.team_rollout_actions(core))


def test_rollout_teacher_run_records_its_flags(tmp_path, monkeypatch, restore_sigint):
    monkeypatch.chdir(tmp_path)
    rm.main(small_args(tmp_path, teacher="rollout", margin_loss=1.0, total_steps=300,
                       eval_every=0, quiet=True))
    info = json.loads((tmp_path / "m.json").read_text())
    assert info["args"]["teacher"] == "rollout" and info["args"]["margin_loss"] == 1.0


@pytest.mark.parametrize("kw, msg", [(dict(teacher="lkh"), "--teacher must be one of heuristic, rollout")])
def test_bad_teacher_flags_are_one_line_errors(tmp_path, monkeypatch, restore_sigint, kw, msg):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match=msg) as e:
        rm.main(small_args(tmp_path, **kw))
    assert "\n" not in str(e.value) and not (tmp_path / "runs").exists()
