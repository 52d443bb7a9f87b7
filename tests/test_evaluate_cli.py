"""evaluate.py on bad input: one ValueError naming the file or flag, and nothing written; on the command line
one `error:` line on stderr and a non-zero exit."""
import json
import subprocess
import sys
from pathlib import Path

import pytest

import evaluate

ROOT = Path(__file__).resolve().parent.parent
ROOM = "....\n.@..\n....\n"  # 11 free cells, an obstacle at [1, 1]


@pytest.fixture
def files(tmp_path):
    """Small input files, good and bad, by name."""
    (tmp_path / "room.txt").write_text(ROOM)
    (tmp_path / "other.txt").write_text(ROOM)
    (tmp_path / "empty.txt").write_text("")
    (tmp_path / "binary.map").write_bytes(bytes(range(256)) * 4)
    (tmp_path / "text.pt").write_text("not a model\n")
    (tmp_path / "truncated.pt").write_bytes((ROOT / "models/rainbow_cpp.pt").read_bytes()[:300])
    starts = {"object.json": [[0, 0]], "short.json": {"room.txt": [[0]]}, "words.json": {"room.txt": [["a", 0]]},
              "floats.json": {"room.txt": [[0.5, 1]]}, "number.json": {"room.txt": 5}, "none.json": {"room.txt": []},
              "obstacle.json": {"room.txt": [[1, 1]]}, "outside.json": {"room.txt": [[3, 0]]},
              "negative.json": {"room.txt": [[-1, 0]]}, "typo.json": {"room.txt": [[0, 0]], "rom.txt": [[0, 0]]},
              "few.json": {"room.txt": [[0, 0]]}, "twice.json": {"room.txt": [[0, 0], [0, 0]]}}
    for name, content in starts.items():
        (tmp_path / name).write_text(json.dumps(content))
    (tmp_path / "broken.json").write_text("{")
    return tmp_path


def room(d):
    return (str(d / "room.txt"),)


BAD = {  # name: (Args keywords from the files folder, part of the message)
    "starts not an object": (lambda d: dict(maps=room(d), starts=str(d / "object.json")), "object.json: a JSON list"),
    "start not [row, col]": (lambda d: dict(maps=room(d), starts=str(d / "short.json")),
                             r"short.json: room.txt: \[0\] is not a \[row, col\] start"),
    "start of words": (lambda d: dict(maps=room(d), starts=str(d / "words.json")), r'\["a", 0\] is not a \[row, col\]'),
    "start of floats": (lambda d: dict(maps=room(d), starts=str(d / "floats.json")), r"\[0.5, 1\] is not a \[row, col\]"),
    "starts not a list": (lambda d: dict(maps=room(d), starts=str(d / "number.json")), "non-empty list of starts"),
    "no starts": (lambda d: dict(maps=room(d), starts=str(d / "none.json")), "non-empty list of starts"),
    "starts not JSON": (lambda d: dict(maps=room(d), starts=str(d / "broken.json")), "broken.json: cannot read starts"),
    "starts missing": (lambda d: dict(maps=room(d), starts=str(d / "gone.json")), "gone.json: cannot read starts"),
    "start on an obstacle": (lambda d: dict(maps=room(d), starts=str(d / "obstacle.json")),
                             r"obstacle.json: room.txt: start \[1, 1\] is on an obstacle"),
    "start outside": (lambda d: dict(maps=room(d), starts=str(d / "outside.json")), r"\[3, 0\] is out of bounds"),
    "start negative": (lambda d: dict(maps=room(d), starts=str(d / "negative.json")), r"\[-1, 0\] is out of bounds"),
    "map name not given": (lambda d: dict(maps=(str(d / "room.txt"), str(d / "other.txt")),
                                          starts=str(d / "typo.json")), "'rom.txt' is none of the maps given"),
    "fewer starts than agents": (lambda d: dict(maps=room(d), policy="partition", agents=2,
                                                starts=str(d / "few.json")), "room.txt has 1 starts for 2 agents"),
    "duplicate starts": (lambda d: dict(maps=room(d), policy="partition", agents=2,
                                        starts=str(d / "twice.json")), "duplicate starts"),
    "empty map": (lambda d: dict(maps=(str(d / "empty.txt"),)), "empty.txt: no map rows"),
    "binary map": (lambda d: dict(maps=(str(d / "binary.map"),)), "binary.map: not a text map file"),
    "folder as map": (lambda d: dict(maps=(str(d),)), "cannot read map"),
    "missing dataset": (lambda d: dict(dataset=str(d / "gone.npz")), "--dataset .*gone.npz: no such file"),
    "text as dataset": (lambda d: dict(dataset=str(d / "room.txt")), "room.txt: not a gridworld dataset"),
    "table as dataset": (lambda d: dict(dataset=str(ROOT / "models/tabular_q.npz")), "not a gridworld dataset"),
    "table for rainbow": (lambda d: dict(maps=room(d), policy="rainbow", checkpoint=str(ROOT / "models/tabular_q.npz")),
                          "tabular_q.npz: not a rainbow_cpp"),
    "text for rainbow": (lambda d: dict(maps=room(d), policy="rainbow", checkpoint=str(d / "text.pt")),
                         "text.pt: not a rainbow_cpp"),
    "truncated for marl": (lambda d: dict(maps=room(d), policy="marl", checkpoint=str(d / "truncated.pt")),
                           "truncated.pt: not a rainbow_cpp / rainbow_marl model"),
    "model for tabular": (lambda d: dict(maps=room(d), policy="tabular", checkpoint=str(ROOT / "models/rainbow_cpp.pt")),
                          "rainbow_cpp.pt: not a tabular_q table"),
    "text for tabular": (lambda d: dict(maps=room(d), policy="tabular", checkpoint=str(d / "text.pt")),
                         "text.pt: not a tabular_q table"),
    "unknown policy": (lambda d: dict(maps=room(d), policy="astar"), "--policy: unknown policy 'astar'"),
    "unknown sensor": (lambda d: dict(maps=room(d), policy="rainbow", sensor="sonar"), "--sensor must be one of"),
    "sensor range 0": (lambda d: dict(maps=room(d), policy="rainbow", sensor_range=0), "--sensor-range must be >= 1"),
    "max size 1": (lambda d: dict(maps=room(d), max_size=1), "--max-size must be 0"),
    "unknown rollout base": (lambda d: dict(maps=room(d), policy="rollout", rollout_base="astar"),
                             "--rollout-base 'astar': choose from"),
    "min size negative": (lambda d: dict(maps=room(d), min_size=-1), "--min-size must be >= 0"),
    "more agents than cells": (lambda d: dict(maps=room(d), agents=11), "11 free cells for 11 agents"),
    "no agents": (lambda d: dict(maps=room(d), agents=0), "--agents must be >= 1"),
    "every -1": (lambda d: dict(maps=room(d), every=-1), "--every must be >= 1"),
    "limit -1": (lambda d: dict(maps=room(d), limit=-1), "--limit must be >= 0"),
    "workers 0": (lambda d: dict(maps=room(d), workers=0), "--workers must be >= 1"),
    "seed -1": (lambda d: dict(maps=room(d), seed=-1), "--seed must be >= 0"),
    "video episodes -1": (lambda d: dict(maps=room(d), video=str(d / "v"), video_episodes=-1),
                          "--video-episodes must be >= 1"),
    "video max 0": (lambda d: dict(maps=room(d), video=str(d / "v"), video_max=0), "--video-max must be >= 1"),
    "unknown compare": (lambda d: dict(maps=room(d), compare="lkh,astar"), "--compare: unknown policy 'astar'"),
    "compare itself": (lambda d: dict(maps=room(d), compare="greedy"), "listed twice"),
    "single-agent compare": (lambda d: dict(maps=room(d), agents=2, compare="lkh"), "lkh is a single-agent planner"),
    "out is a file": (lambda d: dict(maps=room(d), out=str(d / "room.txt")), "--out .*room.txt: exists and is not a folder"),
    "video is a file": (lambda d: dict(maps=room(d), video=str(d / "room.txt")), "--video .*: exists and is not a folder"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_input_is_one_value_error_and_writes_nothing(files, case):
    kw, message = BAD[case]
    kw = {"out": str(files / "out"), "quiet": True, **kw(files)}
    before = sorted(files.iterdir())
    with pytest.raises(ValueError, match=message) as error:
        evaluate.main(evaluate.Args(**kw))
    assert "\n" not in str(error.value)
    assert sorted(files.iterdir()) == before  # no out/ nor video/ folder, no partial file


def test_writing_fails_cleanly(files, monkeypatch):
    def broken(*a, **k):
        raise OSError(28, "No space left on device", str(files / "video" / "x.mp4"))

    monkeypatch.setattr(evaluate.gridworld, "write_video", broken)
    before = sorted(files.iterdir())
    with pytest.raises(ValueError, match="cannot write .No space left on device."):
        evaluate.main(evaluate.Args(maps=room(files), out=str(files / "out"), video=str(files / "video"), quiet=True))
    assert sorted(files.iterdir()) == before  # the files written so far are gone, and their folders


@pytest.mark.parametrize("flags,message", [
    (["--starts", "{d}/object.json"], "object.json: a JSON list"),
    (["--starts", "{d}/obstacle.json"], "is on an obstacle"),
    (["--maps", "{d}/binary.map"], "binary.map: not a text map file"),
    (["--policy", "rainbow", "--checkpoint", "{d}/truncated.pt"], "truncated.pt: not a rainbow_cpp"),
    (["--limit", "-1"], "--limit must be >= 0"),
    (["--compare", "greedy-dead-ends,astar"], "--compare: unknown policy 'astar'"),
])
def test_command_line_error_is_one_line(files, flags, message):
    args = ["--maps", "{d}/room.txt", "--out", "{d}/out", *flags]
    result = subprocess.run([sys.executable, "evaluate.py", *(a.format(d=files) for a in args)],
                            cwd=ROOT, capture_output=True, text=True)
    assert result.returncode != 0
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and message in lines[0]
    assert not (files / "out").exists()


def test_command_line_success_prints_a_summary_and_no_progress_bar(files):
    # stdout is a pipe here, so the bars stay off
    result = subprocess.run([sys.executable, "evaluate.py", "--maps", str(files / "room.txt"), "--out",
                             str(files / "out"), "--compare", "lkh"], cwd=ROOT, capture_output=True, text=True)
    assert result.returncode == 0 and result.stderr == ""
    out = result.stdout.splitlines()
    assert out[0].startswith("greedy on 1 episodes: overlap ") and "| lkh |" in result.stdout
    assert out[-1] == f"wrote {files / 'out'}"
    assert sorted(p.name for p in (files / "out").iterdir()) == ["compare.json", "compare.md", "episodes.csv",
                                                                 "summary.json"]
