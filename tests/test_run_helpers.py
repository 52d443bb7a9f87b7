"""gridworld's helpers for the trainers: packed deep frames, §6.5.2.1's hand-over and greedy evaluation, flag checks,
choices and resumed flags, the curriculum and the stop signals."""
import signal
from dataclasses import dataclass
from typing import Literal

import numpy as np
import pytest
import torch

import gridworld as gw


def test_packed_frames_round_trip_and_keep_the_edge_lines_raw():
    core = gw.GridWorldCore(dict(size=12, number_obstacles=10, sensor="camera", sensor_range=2), 3, seed=4)
    core.reset()
    maps = core.observe()["map"][:, 0]  # (3, 4, 41, 41)
    maps[:, :, 1, 7] = 37  # a compressed out-of-bounds count on an edge line: not 0 or 255
    packed = gw.pack_frames(maps)
    assert packed.shape == (3, gw.packed_frame_bytes(4, 41)) == (3, 841 + 4 * 4 * 41)
    np.testing.assert_array_equal(gw.unpack_frames(packed, 4, 41), maps)


def one_agent_core():
    core = gw.GridWorldCore(dict(size=6, number_obstacles=0), 1, seed=0)
    core.reset()
    return core


def test_a_stuck_agent_owes_the_heuristic_one_more_new_cell_each_time():
    core = one_agent_core()
    watch = gw.StuckWatch(core)
    working = np.ones((1, 1), bool)
    no_new = np.zeros((1, 1), bool)
    for _ in range(5):  # five steps without a new cell or a move: stuck (§6.4.2.4 condition 4)
        assert not watch.hand_over(core, working).any()
        watch.step(core, no_new)
    assert watch.hand_over(core, working).all() and watch.owed[0, 0] == 1
    watch.step(core, np.ones((1, 1), bool))  # the heuristic's new cell pays the debt
    assert watch.owed[0, 0] == 0 and watch.since_new[0, 0] == 0
    for _ in range(5):
        watch.hand_over(core, working)
        watch.step(core, no_new)
    assert watch.hand_over(core, working).all() and watch.owed[0, 0] == 2  # stuck a second time: two cells
    assert not watch.hand_over(core, ~working).any()  # an agent that no longer acts is never handed over
    watch.restart(core, np.array([0]))
    assert watch.owed[0, 0] == watch.times_stuck[0, 0] == watch.since_new[0, 0] == 0


@dataclass
class Flags:
    seed: int = 1
    rate: float | None = None
    chance: float = 0.5
    steps: int = 10
    name: str = "a"


@pytest.mark.parametrize("flags, message", [
    (Flags(seed=-1), "--seed must be >= 0, got -1"), (Flags(chance=1.5), "--chance must be in [0, 1], got 1.5"),
    (Flags(rate=0.0), "--rate must be > 0, got 0.0"), (Flags(chance=float("nan")), "--chance must be a finite number"),
    (Flags(steps=-3), "--steps must be >= 0, got -3")])
def test_check_ranges_names_the_flag_and_its_range(flags, message):
    with pytest.raises(ValueError, match="^" + message.replace("[", r"\[").replace("]", r"\]")):
        gw.check_ranges(flags, {"seed": 0}, unit=("chance",), positive=("rate",), nonnegative=("steps",))
    gw.check_ranges(Flags(), {"seed": 0}, unit=("chance",), positive=("rate",), nonnegative=("steps",))  # None: unset


def test_resumed_flags_keep_the_runs_own_and_refuse_a_contradiction():
    saved = {"seed": 7, "rate": 0.1, "chance": 0.2, "name": "b", "gone": 1}
    kept = gw.resumed_flags(Flags(rate=0.3, name="c"), saved, "ck.pt", own=("name",), replaceable=("rate",))
    assert kept == {"seed": 7, "chance": 0.2}  # defaults take the run's; own and replaceable stay the command line's
    with pytest.raises(ValueError, match=r"^--chance 0.9 contradicts ck.pt \(chance 0.2\): a resumed run keeps its "):
        gw.resumed_flags(Flags(chance=0.9), saved, "ck.pt", own=("name",), replaceable=("rate",))
    with pytest.raises(ValueError, match=r"\(rate 0.1\): a resumed run keeps its flags$"):  # nothing may change
        gw.resumed_flags(Flags(rate=0.3), saved, "ck.pt", own=())


def test_shapes_differ_names_the_first_three_differences():
    assert gw.shapes_differ({"a": (1,)}, {"a": (1,)}) == ""
    here = {"a": (2,), "b": (1,), "c": (1,), "d": (1,)}
    assert gw.shapes_differ(here, {"a": (3,), "e": (1,)}) == \
        "a (3,) in the file, (2,) here; b only here; c only here and 2 more"


def test_read_torch_refuses_a_foreign_file_in_one_line(tmp_path):
    (tmp_path / "x.pt").write_text("not torch")
    with pytest.raises(ValueError, match=r"^\S+x.pt: not a model \("):
        gw.read_torch(str(tmp_path / "x.pt"), "model")
    gw.save_torch(str(tmp_path / "y.pt"), {"w": torch.ones(2)})
    assert gw.read_torch(str(tmp_path / "y.pt"), "model")["w"].tolist() == [1.0, 1.0]


def corridor():
    """A 1x4 corridor, the agent at its west end: three points of interest to the east."""
    return gw.Scenario(np.zeros((1, 4), bool), np.array([[0, 0]]))


def waiting_policy(calls):
    def act(obs, restart, acting):
        calls.append(restart.copy())
        return np.full(len(acting), gw.WAIT)
    return act


def test_greedy_episodes_hand_a_stuck_agent_over_for_one_more_cell_each_time():
    calls = []
    m = gw.greedy_episodes(gw.replay_config([corridor()]), [corridor()], waiting_policy(calls))
    # waits 0-4, stuck at 5 (owes 1 cell: the heuristic's move), waits 6-10, stuck at 11 (owes 2): 13 steps
    assert m["steps"].tolist() == [13] and m["heuristic_steps"].tolist() == [3] and m["completed"].all()
    assert not m["truncated"].any() and m["agents"].tolist() == [1] and "walled_off" not in m
    assert calls[0].all() and not any(c.any() for c in calls[1:])  # each stream's first frame is marked once


def test_greedy_episodes_without_the_fallback_run_out_of_battery():
    m = gw.greedy_episodes(gw.replay_config([corridor()]), [corridor()], waiting_policy([]), heuristic=False)
    assert m["steps"].tolist() == [5 * 1 * 4] and m["truncated"].all() and not m["completed"].any()
    assert m["heuristic_steps"].tolist() == [0]


def test_check_choices_reads_the_literal_flags():
    @dataclass
    class Choices:
        teacher: Literal["heuristic", "rollout"] = "heuristic"
        network: Literal["fig6.8", "compact"] | None = None

    gw.check_choices(Choices())
    with pytest.raises(ValueError, match=r"^--teacher must be one of heuristic, rollout, got 'oracle'$"):
        gw.check_choices(Choices(teacher="oracle"))
    with pytest.raises(ValueError, match=r"^--network must be one of fig6.8, compact, got 'big'$"):
        gw.check_choices(Choices(network="big"))


def test_curriculum_refuses_what_a_trainer_cannot_run(tmp_path):
    assert [s.size for s in gw.curriculum(None, [dict(name="a", base_steps=5, size=6)])] == [6]
    (tmp_path / "s.yaml").write_text("team:\n  number_agents: 2\n  base_steps: 10\n")
    assert gw.curriculum(str(tmp_path / "s.yaml"), [])[0].number_agents == 2
    with pytest.raises(ValueError, match=r"^stage team: this trainer is single-agent \(number_agents: 1\)$"):
        gw.curriculum(str(tmp_path / "s.yaml"), [], single_agent=True)
    with pytest.raises(ValueError, match=r"^stage a: base_steps must be a whole number > 0$"):
        gw.curriculum(None, [dict(name="a", base_steps=0)])


def test_restore_signals_puts_back_the_handlers():
    before = signal.getsignal(signal.SIGTERM)
    stop, previous = gw.stop_signals()
    signal.raise_signal(signal.SIGTERM)
    assert stop["signal"] == signal.SIGTERM
    gw.restore_signals(previous)
    assert signal.getsignal(signal.SIGTERM) is before
