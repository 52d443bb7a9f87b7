"""evaluate.py --video: which episodes are filmed, that each video and picture shows the episode's own path
(planners, rainbow, marl, tabular), compare.png, and one real MP4 end to end."""
import csv
import json
import os
import re
from pathlib import Path

import numpy as np
import pytest

import evaluate
import gridworld as gw

ROOT = Path(__file__).resolve().parent.parent
ROOM = "......\n......\n..@@..\n......\n"


@pytest.fixture
def filmed(monkeypatch):
    """Per video file name: the (T+1, N, 2) cells it replays and its frame count (no encoding)."""
    seen = {}
    replay = gw.replay_frames

    def frames(scenario, paths, cell=16, config=None):
        out = replay(scenario, paths, cell, config)
        frames.last = (gw._path_array(scenario, paths), len(out))
        return out

    def video(frames_, path, fps=10):
        staged = re.fullmatch(r"\.(.+)\.[^.]+\.partial(\.\w+)", os.path.basename(path))  # gridworld.staged_output's
        seen[staged[1] + staged[2] if staged else os.path.basename(path)] = frames.last
        Path(path).write_bytes(b"")
        return path

    monkeypatch.setattr(gw, "replay_frames", frames)
    monkeypatch.setattr(gw, "write_video", video)
    return seen


def rows_of(out):
    with open(out / "episodes.csv") as f:
        return list(csv.DictReader(f))


def hand_count(scenario, cells):
    """(steps, revisits by moves, every free cell reached) of a (T+1, N, 2) path, counted here: a move onto a
    covered cell is a revisit (gridworld also counts a move that bumps into a wall, which a path cannot show)."""
    covered = {tuple(c) for c in np.argwhere(scenario.covered)} | {tuple(c) for c in cells[0].tolist()}
    revisits = 0
    for t in range(1, len(cells)):
        for old, new in zip(cells[t - 1].tolist(), cells[t].tolist()):
            if old != new:
                revisits += tuple(new) in covered
                covered.add(tuple(new))
    return len(cells) - 1, revisits, covered == {tuple(c) for c in np.argwhere(~scenario.obstacles)}


def check_filmed(out, video, seen, expected_names, policy):
    rows = rows_of(out)
    episodes = evaluate.scenarios_from(evaluate.Args(**json.loads((out / "args.json").read_text())))
    assert sorted(seen) == sorted(f"{n}.mp4" for n in expected_names)
    for name in expected_names:
        i = int(name[:3])
        cells, n_frames = seen[f"{name}.mp4"]
        assert n_frames == int(rows[i]["steps"]) + 1 and (video / f"{name}.png").stat().st_size > 1000
        assert cells[0].tolist() == json.loads(rows[i]["start"])
        steps, revisits, complete = hand_count(episodes[i][1], cells)
        assert steps == int(rows[i]["steps"]) and complete == (rows[i]["completed"] == "True")
        bumps = int(rows[i]["revisits"]) - revisits  # moves into a wall; the planners never make one
        assert bumps == 0 if policy in evaluate.classical_cpp.PLANNERS else bumps >= 0


def run(tmp_path, **kw):
    out, video = tmp_path / "out", tmp_path / "video"
    kw = dict(out=str(out), video=str(video), quiet=True, **kw)
    evaluate.main(evaluate.Args(**kw))
    (out / "args.json").write_text(json.dumps({k: v for k, v in kw.items() if k not in ("out", "video")}))
    return out, video


def test_episodes_filmed_per_map_and_in_all(tmp_path, filmed):
    for name in ("a.txt", "b.txt"):
        (tmp_path / name).write_text(ROOM)
    starts = tmp_path / "starts.json"
    starts.write_text(json.dumps({"a.txt": [[0, 0], [3, 5], [1, 2]], "b.txt": [[0, 5], [3, 0], [1, 1]]}))
    kw = dict(maps=(str(tmp_path / "a.txt"), str(tmp_path / "b.txt")), starts=str(starts))
    out, video = run(tmp_path, policy="greedy", video_episodes=2, video_max=3, **kw)
    check_filmed(out, video, filmed, ["000-a-txt", "001-a-txt", "003-b-txt"], "greedy")  # 2 of a, then the cap
    filmed.clear()
    out, video = run(tmp_path / "one", policy="boustrophedon", **kw)
    check_filmed(out, video, filmed, ["000-a-txt", "003-b-txt"], "boustrophedon")  # default: one per map
    assert not (out / "compare.png").exists()


def test_several_agents_and_workers(tmp_path, filmed):
    out, video = run(tmp_path, policy="partition", dataset=str(ROOT / "maps/marl_eval.npz"), limit=3, agents=3,
                     workers=2)
    check_filmed(out, video, filmed, ["000-marl_eval-npz-0", "001-marl_eval-npz-1", "002-marl_eval-npz-2"], "partition")
    assert {cells.shape[1] for cells, _ in filmed.values()} == {3}


def test_rainbow_video_and_compare_picture(tmp_path, filmed):
    import rainbow_cpp
    q = rainbow_cpp.QNetwork(3, 41, 16, 0.5)
    model = tmp_path / "tiny.pt"
    gw.save_torch(str(model), {"weights": {k: v.half() for k, v in q.state_dict().items()
                                                         if "sigma" not in k and "eps" not in k},
                                             "frames": 3, "hidden": 16})
    out, video = run(tmp_path, policy="rainbow", checkpoint=str(model), dataset=str(ROOT / "maps/cpp_eval.npz"),
                     limit=2, compare="greedy,wavefront")
    check_filmed(out, video, filmed, ["000-cpp_eval-npz-0", "001-cpp_eval-npz-1"], "rainbow")
    import matplotlib.image
    height, width, _ = matplotlib.image.imread(out / "compare.png").shape
    assert width > 2 * height  # a panel for each of the three policies, side by side


def test_marl_video(tmp_path, filmed):
    import rainbow_marl
    q = rainbow_marl.QNetwork(3, 41, 16, 0.5)
    model = tmp_path / "tiny.pt"
    gw.save_torch(str(model), {"weights": {k: v.half() for k, v in q.state_dict().items()
                                                          if "sigma" not in k and "eps" not in k},
                                              "frames": 3, "hidden": 16})
    out, video = run(tmp_path, policy="marl", checkpoint=str(model), dataset=str(ROOT / "maps/marl_eval.npz"),
                     limit=2, agents=2)
    check_filmed(out, video, filmed, ["000-marl_eval-npz-0", "001-marl_eval-npz-1"], "marl")


def test_tabular_video(tmp_path, filmed):
    import tabular_q
    table = tmp_path / "untrained.npz"
    tabular_q.QTable(3, 3).save(str(table))  # every state never seen: the heuristic's moves
    out, video = run(tmp_path, policy="tabular", checkpoint=str(table), dataset=str(ROOT / "maps/ch5_eval.npz"),
                     limit=2, sensor="lidar")
    check_filmed(out, video, filmed, ["000-ch5_eval-npz-0", "001-ch5_eval-npz-1"], "tabular")


def test_a_real_mp4(tmp_path):
    import imageio.v3 as iio
    (tmp_path / "room.txt").write_text(ROOM)
    out, video = tmp_path / "out", tmp_path / "video"
    evaluate.main(evaluate.Args(policy="greedy", maps=(str(tmp_path / "room.txt"),), out=str(out), video=str(video),
                                quiet=True))
    steps = int(rows_of(out)[0]["steps"])
    frames = iio.imread(video / "000-room-txt.mp4")
    cell = evaluate.VIDEO_PIXELS // 6
    assert frames.shape[1:] == (4 * cell, 6 * cell, 3) and len(frames) > steps  # then the end held a second
    assert sorted(p.name for p in video.iterdir()) == ["000-room-txt.mp4", "000-room-txt.png"]
