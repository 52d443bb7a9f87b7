"""gridworld's recording helpers: replayed frames, MP4 and path pictures."""
import numpy as np
import pytest

import gridworld
from gridworld import Scenario

COVERED_RGB = (220, 50, 50)
AGENT_RGB = (20, 40, 160)


def corridor():
    obstacles = np.zeros((3, 4), bool)
    obstacles[1, 1:3] = True  # a ring around a 1x2 block
    return Scenario(obstacles, np.array([[0, 0]]))


RING = [(0, 0), (0, 1), (0, 2), (0, 3), (1, 3), (2, 3), (2, 2), (2, 1), (2, 0), (1, 0)]


def test_replay_frames_draws_the_walk_step_by_step():
    frames = gridworld.replay_frames(corridor(), [RING], cell=4)
    assert len(frames) == len(RING) and frames[0].shape == (12, 16, 3) and frames[0].dtype == np.uint8
    for t, (y, x) in enumerate(RING):
        centre = frames[t][4 * y + 2, 4 * x + 2]
        assert tuple(centre) == AGENT_RGB  # the agent's disk sits on its cell at step t
    last = frames[-1]
    for y, x in RING[:-1]:
        assert tuple(last[4 * y, 4 * x]) == COVERED_RGB  # every visited cell is drawn covered
    assert tuple(last[4 * 1 + 2, 4 * 1 + 2]) == (0, 0, 0)  # the obstacle block


def test_replay_frames_accepts_the_trajectory_array_and_pads_short_agents():
    s = Scenario(np.zeros((2, 3), bool), np.array([[0, 0], [1, 2]]))
    per_agent = [[(0, 0), (0, 1)], [(1, 2), (1, 1), (1, 0)]]
    array = np.array([[(0, 0), (1, 2)], [(0, 1), (1, 1)], [(0, 1), (1, 0)]])
    a = gridworld.replay_frames(s, per_agent, cell=2)
    b = gridworld.replay_frames(s, array, cell=2)
    assert len(a) == len(b) == 3
    assert all((x == y).all() for x, y in zip(a, b))


@pytest.mark.parametrize("paths, message", [
    ([[(0, 0), (0, 2)]], "4-adjacent"),
    ([[(0, 0), (-1, 0)]], "outside"),
    ([[]], "non-empty"),
])
def test_bad_paths_are_one_line_errors(paths, message):
    with pytest.raises(ValueError, match=message):
        gridworld.replay_frames(corridor(), paths)


def test_write_video_and_plot_path(tmp_path):
    frames = gridworld.replay_frames(corridor(), [RING], cell=5)  # odd sides: padded for yuv420p
    mp4 = gridworld.write_video(frames, str(tmp_path / "v" / "walk.mp4"), fps=5)
    with open(mp4, "rb") as f:
        assert f.read(12)[4:8] == b"ftyp"  # an MP4 container
    png = gridworld.plot_path(corridor(), [RING], str(tmp_path / "walk.png"), title="ring")
    with open(png, "rb") as f:
        assert f.read(8) == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(ValueError, match="no frames"):
        gridworld.write_video([], str(tmp_path / "empty.mp4"))
