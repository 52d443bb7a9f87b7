"""gridworld's helpers for the trainers: packed deep frames, §6.5.2.1's hand-over, flag checks and resumed flags."""
from dataclasses import dataclass

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
