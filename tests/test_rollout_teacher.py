"""Tests for the rollout teacher: gridworld.rollout_actions (the one-step rollout of greedy-dead-ends, batched)
and rainbow_cpp's --teacher rollout.

rollout_actions: beats the heuristic's first move on a hand-made map, equals classical_cpp.rollout_many's first
move on random maps (fresh and part-covered), leaves its core alone, handles finished worlds and plans on the full
state in sensor tasks. rainbow_cpp: a tiny --teacher rollout run works and records its flags; the rollout labels the worlds
the teacher acts in (every world with a margin loss); bad values are one-line ValueErrors; --teacher heuristic is the
run it always was.
"""
from __future__ import annotations

import hashlib
import json
import sys
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


def from_rows(rows: list[str]) -> gw.Scenario:
    """'.' free, '0' obstacle, '@' the agent's start (covered)."""
    chars = np.array([list(r) for r in rows])
    return cc.with_starts(gw.Scenario(chars == "0", np.argwhere(chars == "@")))


def core_of(scenarios: list[gw.Scenario], **cfg) -> gw.GridWorldCore:
    core = gw.GridWorldCore(gw.EnvConfig(load_state=True, load_random=False, battery_factor=1e6, **cfg),
                            len(scenarios))
    core.configure(scenarios=scenarios)
    core.reset()
    return core


def first_move(path: np.ndarray) -> int:
    d = tuple(path[1] - path[0])
    return [tuple(v) for v in gw.ACTION_DELTAS].index(d)


def random_maps(n: int, seed: int = 0) -> list[gw.Scenario]:
    """n connected maps of 4x4 to 7x7, some part-covered (a state mid-episode)."""
    rng = np.random.default_rng(seed)
    maps = []
    while len(maps) < n:
        (s,) = gw.generate_scenarios(1, seed=int(rng.integers(1 << 30)), size=int(rng.integers(4, 8)),
                                     number_obstacles=int(rng.integers(0, 10)), obstacles_random=True)
        covered = s.covered & ~s.obstacles if len(maps) % 2 else None
        if covered is not None:
            covered = covered | (rng.random(covered.shape) < 0.4) & ~s.obstacles
            if not (~s.obstacles & ~covered).any():
                continue
        maps.append(cc.with_starts(gw.Scenario(s.obstacles, s.starts, covered)))
    return maps


def test_rollout_beats_the_heuristic_by_hand():
    """Agent at (0, 2). greedy-dead-ends: both near targets (0, 1) and (0, 3) have one target neighbour, row-major
    order takes WEST: (0,1) (0,0) (1,0), back (0,0) (0,1) (0,2) (0,3) (1,3) = 8 steps. EAST first: (0,3) (1,3),
    back (0,3) (0,2) (0,1) (0,0) (1,0) = 7 steps: the rollout goes EAST."""
    s = from_rows(["..@.", ".00."])
    core = core_of([s])
    assert gw.heuristic_actions(core, False, True)[0, 0] == gw.WEST
    assert gw.rollout_actions(core)[0] == gw.EAST
    assert len(cc.greedy_dead_ends(s)[0]) - 1 == 8 and len(cc.rollout(s)[0]) - 1 == 7


def heuristic_steps_after(scenario: gw.Scenario, first: int) -> int:
    """Steps to cover the map: `first`, then greedy-dead-ends to the end."""
    core = core_of([scenario])
    core.step(np.array([[first]]))
    steps = 1
    while core.remaining[0] > 0:
        core.step(gw.heuristic_actions(core, False, True))
        steps += 1
    return steps


def test_rollout_costs_by_hand_and_by_walking_every_move():
    """The example above: WEST then the heuristic takes 8 steps, EAST 7, N and S are blocked. On random maps each
    tried move's cost is the steps of that move then the heuristic to the end, the chosen move is the cheapest, and
    asking for costs does not change the moves."""
    out, cost = gw.rollout_actions(core_of([from_rows(["..@.", ".00."])]), costs=True)
    assert out.tolist() == [gw.EAST] and cost.tolist() == [[-1, -1, 8, 7]]
    maps = random_maps(20, seed=3)
    core = core_of(maps)
    out, cost = gw.rollout_actions(core, costs=True)
    assert out.tolist() == gw.rollout_actions(core).tolist()
    tried = 0
    for s, o, c in zip(maps, out, cost):
        for move in np.flatnonzero(c >= 0):
            assert c[move] == heuristic_steps_after(s, move)
            tried += 1
        if (c >= 0).any():
            assert c[o] == c[c >= 0].min()
    assert tried > 40


def test_rollout_actions_equal_rollout_many_first_moves():
    maps = random_maps(20)
    core = core_of(maps)
    want = [first_move(p[0]) for p in cc.rollout_many(maps)]
    assert gw.rollout_actions(core).tolist() == want
    assert gw.rollout_actions(core, np.arange(19, -1, -3)).tolist() == want[19::-3]  # any subset, in its order


def test_rollout_actions_leave_the_core_alone_and_handle_finished_worlds():
    maps = [from_rows(["@.."])] + random_maps(2, seed=1)
    core = core_of(maps)
    while core.remaining[0] > 0:  # world 0 finishes, the others walk on
        core.step(gw.heuristic_actions(core, False, True))
    before = {k: getattr(core, k).copy() for k in core.WORLD_ARRAYS}
    rng_state = core.rng.bit_generator.state
    out = gw.rollout_actions(core, [0, 1, 2])
    assert out[0] == gw.WAIT
    live = [1, 2]
    assert (core.remaining[live] > 0).all()
    assert out[live].tolist() == [first_move(p[0]) for p in cc.rollout_many(core.snapshot(live))]
    for k, v in before.items():
        assert np.array_equal(getattr(core, k), v), k
    assert core.rng.bit_generator.state == rng_state
    assert gw.rollout_actions(core, []).shape == (0,)
    assert [a.shape for a in gw.rollout_actions(core, [], costs=True)] == [(0,), (0, 4)]


def test_rollout_actions_plan_on_the_full_state_in_sensor_tasks():
    maps = random_maps(6, seed=2)
    full, camera = core_of(maps), core_of(maps, sensor="camera", sensor_range=1)
    assert not camera.seen.all()
    assert np.array_equal(gw.rollout_actions(camera), gw.rollout_actions(full))


def test_rollout_actions_reject_several_agents():
    core = gw.GridWorldCore(gw.EnvConfig(number_agents=2), 1)
    core.reset()
    with pytest.raises(ValueError, match="one agent"):
        gw.rollout_actions(core)


# ----------------------------------------------------------------------------- rainbow_cpp --teacher
def tiny(tmp_path, **kw) -> rc.Args:
    base = dict(run_name="t", total_steps=200, learning_starts=100, hidden=16, num_envs=4, buffer_size=4096,
                eval_every=0, save_every=0, export=str(tmp_path / "m.pt"), stage_steps_scale=0.001,
                replay_ratio=1.0, margin_loss=1.0, quiet=True, threads=1)
    return rc.Args(**{**base, **kw})


def weights_hash(tmp_path, run: str) -> str:
    model = torch.load(tmp_path / "runs" / run / "checkpoint.pt", map_location="cpu", weights_only=False)["model"]
    return hashlib.sha256(b"".join(v.numpy().tobytes() for _, v in sorted(model.items()))).hexdigest()


def test_rollout_teacher_run_records_its_flags(tmp_path, monkeypatch, restore_sigint):
    monkeypatch.chdir(tmp_path)
    rc.main(tiny(tmp_path, teacher="rollout"))
    info = json.loads((tmp_path / "m.json").read_text())
    assert info["args"]["teacher"] == "rollout"


def test_heuristic_teacher_is_the_default_run(tmp_path, monkeypatch, restore_sigint):
    """--teacher heuristic draws nothing more: the same weights as the default run (the code before --teacher gave
    the same weights too: checked by hand on a fixed-seed run)."""
    monkeypatch.chdir(tmp_path)
    rc.main(tiny(tmp_path, run_name="a"))
    rc.main(tiny(tmp_path, run_name="b", teacher="heuristic", overwrite=True))
    assert weights_hash(tmp_path, "a") == weights_hash(tmp_path, "b")


def test_rollout_labels_the_teachers_worlds_or_every_world_with_a_margin_loss():
    core = core_of(random_maps(8, seed=5))
    core.step(gw.heuristic_actions(core, False, True))
    heuristic = gw.heuristic_actions(core, False, True)[:, 0]
    teach = np.zeros(core.B, bool)
    teach[[2, 5]] = True
    label, w = rc.rollout_labels(core, heuristic, teach, rc.Args(teacher="rollout"))
    assert w.tolist() == [2, 5] and label[w].tolist() == gw.rollout_actions(core, w).tolist()
    assert np.array_equal(np.delete(label, w), np.delete(heuristic, w))
    label, w = rc.rollout_labels(core, heuristic, teach, rc.Args(teacher="rollout", margin_loss=1.0))
    assert w.tolist() == list(range(core.B)) and label.tolist() == gw.rollout_actions(core).tolist()


@pytest.mark.parametrize("kw, msg", [(dict(teacher="oracle"), "--teacher must be one of heuristic, rollout"),
                                     (dict(teacher="policy-rollout"), "--teacher must be one of heuristic, rollout")])
def test_bad_teacher_flags_are_one_line_errors(tmp_path, monkeypatch, restore_sigint, kw, msg):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match=msg) as e:
        rc.main(tiny(tmp_path, **kw))
    assert "\n" not in str(e.value)
    assert not (tmp_path / "runs").exists()
