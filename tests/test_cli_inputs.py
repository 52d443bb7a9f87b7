"""Bad input to the command lines (gridworld.py, tabular_q.py, maps/make_datasets.py) and to the
loaders users call directly (load_map, load_dataset, load_config, QTable.load, EnvConfig).

Rules: a loader raises ValueError itself (never a subclass such as UnicodeDecodeError, nor
BadZipFile, KeyError, pickle or YAML errors), on one line naming the file; a command line exits
non-zero with one `error: ...` line on stderr, no traceback, and writes nothing.
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import gridworld as gw
import tabular_q as tq

ROOT = Path(__file__).resolve().parent.parent


def one_line_value_error(call, *args, match: str, **kwargs) -> str:
    """The message of the ValueError (exactly that type) `call` raises; it is one line matching `match`."""
    with pytest.raises(Exception) as info:
        call(*args, **kwargs)
    assert type(info.value) is ValueError, f"{type(info.value).__name__}: {info.value}"
    message = str(info.value)
    assert "\n" not in message and re.search(match, message), message
    return message


def cli_error(cwd: Path, script: str, *flags: str, match: str) -> str:
    """Run a script of the repo with flags in cwd: it must fail with a single `error:` line."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONDONTWRITEBYTECODE": "1"}
    done = subprocess.run([sys.executable, str(ROOT / script), *flags], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=60)
    lines = done.stderr.strip().splitlines()
    assert done.returncode != 0 and len(lines) == 1 and lines[0].startswith("error: "), done.stderr
    assert re.search(match, lines[0]), lines[0]
    return lines[0]


def listing(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


# ----------------------------------------------------------------------------- bad files
@pytest.fixture
def files(tmp_path) -> dict[str, Path]:
    """Malformed inputs, by what is wrong with them, plus a good table and a good dataset."""
    good = [gw.Scenario(np.zeros((3, 4), bool), np.array([[0, 0]])), gw.Scenario(np.zeros((5, 5), bool), np.array([[4, 4]]))]
    gw.save_dataset(str(tmp_path / "dataset.npz"), good)
    table = tq.QTable(3, 3)
    table.rows(np.array([11, 22]))
    table.save(str(tmp_path / "table.npz"))
    with np.load(tmp_path / "dataset.npz") as d:
        arrays = dict(d)
    raw = (tmp_path / "table.npz").read_bytes()
    f = {name: tmp_path / name for name in ("empty", "binary", "text.npz", "half.npz", "array.npz", "flat.npz",
                                             "floats.npz", "no_starts.npz", "none.npz", "objects.npz", "sizes.npz",
                                             "string_q.npz", "two_tables.npz", "negative.npz", "zero_k.npz")}
    f["empty"].write_bytes(b"")
    f["binary"].write_bytes(bytes(range(128, 256)) * 4)
    f["text.npz"].write_text("obstacles, sizes, starts\n")
    f["half.npz"].write_bytes(raw[:len(raw) // 2])  # truncated
    np.save(tmp_path / "array.npy", np.zeros(3))
    os.replace(tmp_path / "array.npy", f["array.npz"])  # one .npy array under an .npz name
    np.savez(f["flat.npz"], **{**arrays, "obstacles": arrays["obstacles"][0]})  # (H, W), not (M, H, W)
    np.savez(f["floats.npz"], **{**arrays, "obstacles": arrays["obstacles"].astype(float)})
    np.savez(f["no_starts.npz"], **{k: v for k, v in arrays.items() if k != "starts"})
    np.savez(f["none.npz"], obstacles=np.zeros((0, 3, 3), bool), sizes=np.zeros((0, 2), int), starts=np.zeros((0, 1, 2), int))
    np.savez(f["objects.npz"], **{**arrays, "starts": np.array([None, 1], dtype=object)})  # would need pickle
    np.savez(f["sizes.npz"], **{**arrays, "sizes": arrays["sizes"] + 10})  # larger than the arrays
    with np.load(tmp_path / "table.npz") as t:
        parts = dict(t)
    np.savez(f["string_q.npz"], **{**parts, "q": parts["q"].astype(str)})
    np.savez(f["two_tables.npz"], **{**parts, "q": np.repeat(parts["q"], 2, 0), "updates": np.repeat(parts["updates"], 2, 0)})
    np.savez(f["negative.npz"], **{**parts, "visits": -parts["visits"].astype(np.int64) - 1})
    np.savez(f["zero_k.npz"], **{**parts, "memory": 0})
    f["table.npz"], f["dataset.npz"] = tmp_path / "table.npz", tmp_path / "dataset.npz"
    return f


@pytest.mark.parametrize("name,problem", [
    ("empty", "no map rows"), ("binary", "not a text map file"), ("text.npz", "unknown character 'o' at line 1, column 1"),
    ("missing.map", "cannot read map"), ("dataset.npz", "not a text map file"), (".", "cannot read map"),
])
def test_load_map_bad_files(files, tmp_path, name, problem):
    path = files.get(name, tmp_path / name)
    one_line_value_error(gw.load_map, str(path), match="^" + re.escape(str(path)) + ": " + problem)
    one_line_value_error(gw.load_map, path, match=problem)  # a pathlib.Path as well


@pytest.mark.parametrize("text,problem", [
    ("type octile\nheight 3\nwidth 3\nmap\n...\n...\n", "header says 3x3 but the rows do not match"),  # truncated
    ("type octile\nheight three\nwidth 3\nmap\n...\n", "bad MovingAI header \\(height/width not integers"),
    ("height 3\nwidth 3\nmap\n...\n", "bad MovingAI header"),
    ("type octile\nheight 1\nwidth 3\nmap\n@@@\n", "no free cell"),
])
def test_load_map_bad_movingai_files(tmp_path, text, problem):
    path = tmp_path / "bad.map"
    path.write_text(text)
    one_line_value_error(gw.load_map, str(path), match=re.escape(str(path)) + ": " + problem)


@pytest.mark.parametrize("name,problem", [
    ("empty", "not an .npz archive"), ("binary", "not an .npz archive"), ("text.npz", "not an .npz archive"),
    ("half.npz", "not an .npz archive"), ("array.npz", "not an .npz archive"), ("missing.npz", "no such file"),
    (".", "not a file"), ("table.npz", "no 'obstacles' array"), ("no_starts.npz", "no 'starts' array"),
    ("flat.npz", "arrays of inconsistent shapes"), ("floats.npz", "obstacles must be boolean, got float64"),
    ("none.npz", "no scenarios"), ("objects.npz", "Object arrays cannot be loaded when allow_pickle=False"),
    ("sizes.npz", "sizes must lie in 1..5 x 1..5"),
])
def test_load_dataset_bad_files(files, tmp_path, name, problem):
    path = files.get(name, tmp_path / name)
    one_line_value_error(gw.load_dataset, str(path), match="^" + re.escape(str(path)) + ": not a gridworld dataset \\(" + problem)
    with pytest.raises(ValueError, match=problem):
        gw.GridWorldCore(gw.EnvConfig(dataset_path=str(path), load_state=True))


def test_load_dataset_accepts_a_path_and_0_1_integers(files, tmp_path):
    assert len(gw.load_dataset(files["dataset.npz"])) == 2
    with np.load(files["dataset.npz"]) as d:
        np.savez(tmp_path / "ints.npz", **{**dict(d), "obstacles": d["obstacles"].astype(np.uint8)})
    assert [s.obstacles.dtype for s in gw.load_dataset(tmp_path / "ints.npz")] == [bool, bool]


@pytest.mark.parametrize("text,problem", [
    ("", "expected a mapping of environment names to settings"),
    ("stage1:\n  size: [5, 6\n", "not valid YAML"),  # truncated
    ("stage1: !!python/object:os.system {}\n", "not valid YAML"),
    ("stage1:\n  size: abc\n", "stage1: invalid environment configuration: size must be an int, got 'abc'"),
    ("stage1:\n  size: 1\n", "need 2 <= min_size <= size"),
    ("stage1:\n  sensor: sonar\n", "sensor must be one of"),
    ("stage1:\n  number_obstacles: -3\n", "number_obstacles and base_steps must be >= 0"),
    ("stage1:\n  colour: red\n", r"unknown environment setting\(s\): \['colour'\]"),
    ("stage1:\n  reward: {gain: high}\n", "gain must be a float, got 'high'"),
    ("- name: [a, b]\n  size: 5\n", "name must be a str"),
    ("stage1:\n", "expected a mapping of environment names to settings"),
])
def test_load_config_bad_files(tmp_path, text, problem):
    path = tmp_path / "stages.yaml"
    path.write_text(text)
    one_line_value_error(gw.load_config, str(path), match="^" + re.escape(str(path)) + ": .*" + problem)


@pytest.mark.parametrize("name,problem", [("binary", "not a text file"), ("dataset.npz", "not a text file"),
                                          ("missing.yaml", "cannot read config"), (".", "cannot read config")])
def test_load_config_unreadable_files(files, tmp_path, name, problem):
    path = files.get(name, tmp_path / name)
    one_line_value_error(gw.load_config, path, match="^" + re.escape(str(path)) + ": " + problem)


def test_load_config_names_become_strings(tmp_path):
    path = tmp_path / "stages.yaml"
    path.write_text("1:\n  size: 5\n2:\n  size: 6\n")
    assert {name: c.name for name, c in gw.load_config(path).items()} == {"1": "1", "2": "2"}


@pytest.mark.parametrize("settings,problem", [
    (dict(size=1), "need 2 <= min_size <= size, got size=1"),
    (dict(size=6, random_size=True, min_size=1), "need 2 <= min_size <= size"),
    (dict(size=3, number_agents=9), "9 agent\\(s\\) do not fit a 3x3 map"),
    (dict(size=3, number_obstacles=8), "8 obstacles and 1 agent\\(s\\) do not fit a 3x3 map"),
    (dict(number_obstacles=-1), "number_obstacles and base_steps must be >= 0, got -1 and 0"),
    (dict(number_obstacles=-1, map_configuration=str(ROOT / "maps" / "external" / "empty-8-8.map")), "must be >= 0"),
    (dict(number_agents=0), "number_agents must be >= 1"),
    (dict(sensor="sonar"), "sensor must be one of"),
    (dict(observation="pixels"), "observation must be one of"),
    (dict(reward=gw.RewardParams(structure="selfish")), "reward structure must be one of"),
    (dict(size=10.0), "size must be an int, got 10.0"),
    (dict(size=True), "size must be an int, got True"),
    (dict(sensor_failure="often"), "sensor_failure must be a float"),
    (dict(faulty_agent=3, number_agents=2), "faulty_agent 3 is not one of the 2 agent"),
    (dict(faulty_agent_step=-1), "faulty_agent_step must be >= 0"),
    (dict(base_steps=-5), "base_steps must be >= 0"),
])
def test_envconfig_bad_values_are_one_line_value_errors(settings, problem):
    one_line_value_error(gw.EnvConfig(**settings).validate, match="^invalid environment configuration: .*" + problem)
    one_line_value_error(gw.GridWorldCore, gw.EnvConfig(**settings), match=problem)


@pytest.mark.parametrize("settings,problem", [
    (dict(map_configuration="no-such.map"), "no-such.map: cannot read map"),
    (dict(dataset_path="no-such.npz"), "no-such.npz: not a gridworld dataset \\(no such file"),
    (dict(size=3, number_obstacles=8, random_size=True, min_size=2, number_agents=4), "4 agent\\(s\\) do not fit a 2x2"),
])
def test_cores_refuse_unknown_maps_and_crowded_worlds(settings, problem):
    one_line_value_error(gw.GridWorldCore, gw.EnvConfig(**settings), match=problem)
    one_line_value_error(gw.GridWorldVectorEnv, 2, gw.EnvConfig(**settings), match=problem)
    one_line_value_error(gw.parallel_env, gw.EnvConfig(**settings), match=problem)


@pytest.mark.parametrize("name,problem", [
    ("empty", "not a tabular_q table \\(not an .npz file"), ("binary", "not a tabular_q table \\(not an .npz file"),
    ("half.npz", "not a tabular_q table \\(not an .npz file"), ("array.npz", "not a tabular_q table \\(not an .npz file"),
    ("missing.npz", "no such table"), ("dataset.npz", "not a tabular_q table \\(no 'keys' array"),
    ("string_q.npz", "not a tabular_q table \\(Q-values must be floats"),
    ("negative.npz", "not a tabular_q table \\(negative visit counts\\)"),
    ("zero_k.npz", "not a tabular_q table \\(K = 0, r = 3; both must be >= 1\\)"),
])
def test_qtable_load_bad_files(files, tmp_path, name, problem):
    path = files.get(name, tmp_path / name)
    one_line_value_error(tq.QTable.load, str(path), match="^" + re.escape(str(path)) + ": " + problem)


# ----------------------------------------------------------------------------- command lines
def test_gridworld_cli_refuses_unknown_arguments(tmp_path):
    cli_error(tmp_path, "gridworld.py", "--bnech", match="^error: gridworld.py: unknown argument.*--bnech.*--bench")
    cli_error(tmp_path, "gridworld.py", "--bench", "--seconds", "3", match="unknown argument")
    done = subprocess.run([sys.executable, str(ROOT / "gridworld.py")], cwd=tmp_path, capture_output=True, text=True,
                          timeout=60, env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"})
    assert done.returncode == 0 and done.stdout.splitlines()[-1] == "usage: python gridworld.py [--bench]"
    assert listing(tmp_path) == []


TABULAR_BAD = [
    (["--episodes", "-1"], dict(episodes=-1), "--episodes must be >= 1, got -1"),
    (["--num-worlds", "0"], dict(num_worlds=0), "--num-worlds must be >= 1, got 0"),
    (["--log-every", "-5"], dict(log_every=-5), "--log-every must be >= 0"),
    (["--time-limit", "-1"], dict(time_limit=-1.0), "--time-limit must be >= 0"),
    (["--size", "1"], dict(size=1), "--size must be >= 2, got 1"),
    (["--min-size", "1"], dict(min_size=1), "--min-size must be in 2..6 \\(--size\\), got 1"),
    (["--min-size", "8"], dict(min_size=8), "--min-size must be in 2..6"),
    (["--memory", "0"], dict(memory=0), "--memory must be >= 1"),
    (["--sensor-range", "0"], dict(sensor_range=0), "--sensor-range must be >= 1"),
    (["--memory", "4"], dict(memory=4), "K = 4 with r = 3 gives .* more than an int64 key holds"),
    (["--sensor", "sonar"], dict(sensor="sonar"), "--sensor must be one of full, camera, lidar, got 'sonar'"),
    (["--number-obstacles", "-2"], dict(number_obstacles=-2), "--number-obstacles must be >= 0"),
    (["--number-obstacles", "40"], dict(number_obstacles=40),
     "invalid environment configuration: 40 obstacles and 1 agent\\(s\\) do not fit a 6x6 map"),
    (["--algorithm", "td"], dict(algorithm="td"), "unknown algorithm 'td'"),
    (["--alpha", "0"], dict(alpha=0.0), "need 0 < alpha <= 1"),
    (["--table-path", "out/table.txt"], dict(table_path="out/table.txt"), "--table-path out/table.txt: must name an .npz"),
    (["--table-path", "."], dict(table_path="."), "--table-path \\.: must name an .npz"),
]


@pytest.mark.parametrize("flags,args,problem", TABULAR_BAD, ids=[" ".join(f) for f, _, _ in TABULAR_BAD])
def test_tabular_q_bad_flags(tmp_path, monkeypatch, flags, args, problem):
    monkeypatch.chdir(tmp_path)  # the default outputs would go to ./runs
    one_line_value_error(tq.main, tq.Args(**args), match=problem)
    cli_error(tmp_path, "tabular_q.py", *flags, match="^error: " + problem)
    assert listing(tmp_path) == []


@pytest.mark.parametrize("name,flags,problem", [
    ("text.npz", [], "not a tabular_q table \\(not an .npz file\\)"),
    ("half.npz", [], "not a tabular_q table \\(not an .npz file\\)"),
    ("dataset.npz", [], "not a tabular_q table \\(no 'keys' array"),
    ("missing.npz", [], "no such table"),
    ("string_q.npz", [], "not a tabular_q table \\(Q-values must be floats, counts integers"),
    ("table.npz", ["--memory", "2"], "trained with K = 3, r = 3; this run uses K = 2, r = 3"),
    ("table.npz", ["--sensor-range", "4"], "trained with K = 3, r = 3; this run uses K = 3, r = 4"),
    ("table.npz", ["--algorithm", "double-q"], "holds 1 Q-table\\(s\\), double-q uses 2"),
    ("two_tables.npz", [], "holds 2 Q-table\\(s\\), q-learning uses 1"),
])
def test_tabular_q_bad_init_tables(files, tmp_path, name, flags, problem):
    path = files.get(name, tmp_path / name)
    before = listing(tmp_path)
    work = tmp_path / "work"
    work.mkdir()
    cli_error(work, "tabular_q.py", "--init-table", str(path), *flags, match="^error: " + re.escape(str(path)) + ": " + problem)
    assert listing(work) == [] and listing(tmp_path) == sorted(before + ["work"])


@pytest.mark.parametrize("table_path", ["taken/t.npz", "/proc/t.npz"])  # /proc: os.access says yes to root
def test_tabular_q_unwritable_table_path(tmp_path, table_path):
    (tmp_path / "taken").write_text("a file, not a folder")
    cli_error(tmp_path, "tabular_q.py", "--table-path", table_path,
              match=f"^error: --table-path {table_path}: cannot write under")
    assert listing(tmp_path) == ["taken"]


@pytest.mark.parametrize("flags,problem", [
    (["--per-size", "0"], "--per-size must be >= 1, got 0"),
    (["--p2p-total", "-1"], "--p2p-total must be >= 1"),
    (["--ch5-per-setting", "0"], "--ch5-per-setting must be >= 1"),
    (["--marl-agents", "0"], "--marl-agents must be >= 1"),
    (["--marl-agents", "25"], "marl_eval: invalid environment configuration: 25 agent\\(s\\) do not fit a 5x5 map"),
    (["--crops", "nothing.map"], "nothing.map: cannot read map"),
    (["--crops", "nothing.map", "--crops-per-map", "0"], "--crops-per-map must be >= 1, got 0"),
    (["--crops", "nothing.map", "--pictures"], "--pictures and --crops write different files: give one of them$"),
])
def test_make_datasets_bad_flags_write_nothing(tmp_path, flags, problem):
    out = tmp_path / "maps"
    cli_error(tmp_path, "maps/make_datasets.py", "--out", str(out), *flags, match="^error: " + problem)
    assert listing(tmp_path) == []


def test_make_datasets_crops_need_room_for_the_starts(tmp_path):
    (tmp_path / "tiny.txt").write_text("....\n.@@@\n")
    cli_error(tmp_path, "maps/make_datasets.py", "--out", "runs", "--crops", "tiny.txt",
              match="^error: --crops tiny.txt: no crop of it in 1,000 draws has room for 15 starts$")
    assert listing(tmp_path) == ["tiny.txt"]


def test_make_datasets_replaces_files_only_with_overwrite(tmp_path):
    """A dataset already in --out (the committed maps/ by default) is an error, and nothing is written, unless
    --overwrite is given."""
    (tmp_path / "cpp_eval.npz").write_bytes(b"mine")
    cli_error(tmp_path, "maps/make_datasets.py", "--out", ".", "--per-size", "1",
              match=r"^error: --out \./cpp_eval\.npz: there already; --overwrite replaces it$")
    assert listing(tmp_path) == ["cpp_eval.npz"] and (tmp_path / "cpp_eval.npz").read_bytes() == b"mine"
    crop = ["--crops", str(ROOT / "maps" / "external" / "random-8-8-20.map"), "--crops-per-map", "1",
            "--marl-agents", "2"]
    (tmp_path / "crops.npz").write_bytes(b"mine")
    cli_error(tmp_path, "maps/make_datasets.py", "--out", ".", *crop, match=r"crops\.npz: there already; --overwrite")
    assert (tmp_path / "crops.npz").read_bytes() == b"mine"
    done = subprocess.run([sys.executable, str(ROOT / "maps" / "make_datasets.py"), "--out", ".", *crop,
                           "--overwrite"], cwd=tmp_path, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert len(gw.load_dataset(str(tmp_path / "crops.npz"))) == 1


def test_make_datasets_out_must_be_a_folder(tmp_path):
    (tmp_path / "file").write_text("")
    cli_error(tmp_path, "maps/make_datasets.py", "--out", str(tmp_path / "file"), match="--out .*file: not a folder")
    assert listing(tmp_path) == ["file"]


# ----------------------------------------------------------------------------- every script's flags
@pytest.mark.parametrize("script,flags,problem", [
    ("evaluate.py", ["--agents", "abc"], "Error parsing --agents: invalid literal for int\\(\\)"),
    ("classical_cpp.py", ["--bogus", "1"], "Unrecognized options: --bogus"),
    ("rainbow_cpp.py", ["--total-steps"], "Missing value for argument '--total-steps'"),
    ("rainbow_marl.py", ["--network", "bogus"], "invalid choice 'bogus' for argument '--network'"),
    ("tabular_q.py", ["--alpha", "xyz"], "Error parsing --alpha"),
    ("report.py", ["bogus"], "Unrecognized options: bogus"),
    ("maps/make_datasets.py", ["--per-size", "abc"], "Error parsing --per-size"),
    ("benchmarks/rollout_planner.py", ["--bogus"], "Unrecognized options: --bogus"),
    ("benchmarks/train_speed.py", ["--threads", "one"], "Error parsing --threads"),
    ("benchmarks/team_rollout.py", ["--agents", "x"], "Error parsing --agents"),
])
def test_a_flag_the_parser_refuses_is_one_error_line(tmp_path, script, flags, problem):
    cli_error(tmp_path, script, *flags, match=f"^error: {problem}.*\\(see {os.path.basename(script)} --help\\)$")
    assert listing(tmp_path) == []


@pytest.mark.parametrize("script", ["rainbow_cpp.py", "rainbow_marl.py", "tabular_q.py"])
@pytest.mark.parametrize("name", ["../models", "/tmp/elsewhere", "..", "a/b"])
def test_a_run_name_is_one_folder_under_runs(tmp_path, script, name):
    cli_error(tmp_path, script, "--run-name", name, match="^error: --run-name must be a folder name under runs/")
    assert listing(tmp_path) == []


@pytest.mark.parametrize("script,made", [("rainbow_cpp.py", "checkpoint.pt"), ("rainbow_marl.py", "checkpoint.pt"),
                                         ("tabular_q.py", "tabular_q.npz")])
def test_a_trainer_never_overwrites_an_earlier_run(tmp_path, script, made):
    (tmp_path / "runs" / "earlier").mkdir(parents=True)
    (tmp_path / "runs" / "earlier" / made).write_bytes(b"the earlier run")
    cli_error(tmp_path, script, "--run-name", "earlier", match="^error: runs/earlier holds a run already")
    assert (tmp_path / "runs" / "earlier" / made).read_bytes() == b"the earlier run"
    assert listing(tmp_path) == ["runs", "runs/earlier", f"runs/earlier/{made}"]


@pytest.mark.parametrize("script", ["rainbow_cpp.py", "rainbow_marl.py"])
@pytest.mark.parametrize("export,problem", [("models", "must name a .pt file"), ("model.npz", "must name a .pt file"),
                                            ("taken/model.pt", "cannot write under .*taken"),
                                            ("/proc/model.pt", "cannot write under /proc")])
def test_a_bad_export_fails_before_training(tmp_path, script, export, problem):
    (tmp_path / "models").mkdir()
    (tmp_path / "taken").write_text("a file, not a folder")
    cli_error(tmp_path, script, "--export", export, match=f"^error: --export .*{problem}")
    assert listing(tmp_path) == ["models", "taken"]


@pytest.mark.parametrize("script,other", [("rainbow_cpp.py", "rainbow_marl"), ("rainbow_marl.py", "rainbow_cpp")])
def test_an_export_never_replaces_the_other_trainers_model(tmp_path, script, other):
    (tmp_path / "models").mkdir()
    for ext in (".pt", ".json"):
        shutil.copy(ROOT / "models" / f"{other}{ext}", tmp_path / "models")
    before = {p: p.read_bytes() for p in (tmp_path / "models").iterdir()}
    cli_error(tmp_path, script, "--export", f"models/{other}.pt",
              match=f"^error: --export models/{other}.pt holds a model of {other}.py: export this run elsewhere$")
    assert {p: p.read_bytes() for p in (tmp_path / "models").iterdir()} == before


def test_a_checkpoint_resumes_only_in_its_own_trainer(tmp_path):
    import torch


    state = {"model": {}, "optimizer": {}, "global_step": 0, "stage": 0, "wall": 0.0, "numpy_rng": {},
             "torch_rng": torch.zeros(1, dtype=torch.uint8)}
    torch.save({**state, "script": "rainbow_marl"}, tmp_path / "marl.pt")
    torch.save(state, tmp_path / "older.pt")  # before checkpoints said which trainer wrote them: either may resume it
    one_line_value_error(gw.load_checkpoint, str(tmp_path / "marl.pt"), "rainbow_cpp",
                         match="marl.pt: a rainbow_marl.py run; resume it with rainbow_marl.py")
    assert gw.load_checkpoint(str(tmp_path / "marl.pt"), "rainbow_marl")["script"] == "rainbow_marl"
    assert gw.load_checkpoint(str(tmp_path / "older.pt"), "rainbow_cpp")["global_step"] == 0


def test_evaluate_refuses_flags_that_would_be_ignored_or_write_among_other_files(tmp_path, monkeypatch):
    import evaluate

    monkeypatch.chdir(tmp_path)
    (tmp_path / "folder").mkdir()
    (tmp_path / "folder" / "model.pt").write_bytes(b"not ours")
    (tmp_path / "earlier").mkdir()
    (tmp_path / "earlier" / "summary.json").write_text("{}")
    one_line_value_error(evaluate.main, evaluate.Args(policy="greedy", checkpoint="missing.pt"),
                         match="--checkpoint is for the learned policies .*not greedy")
    one_line_value_error(evaluate.main, evaluate.Args(policy="greedy", out="folder"),
                         match="--out folder: a folder of other files")
    one_line_value_error(evaluate.main, evaluate.Args(policy="greedy", compare="wavefront,,lkh"),
                         match="--compare wavefront,,lkh: an empty name in the list")
    one_line_value_error(evaluate.main, evaluate.Args(policy="greedy", dataset="folder"),
                         match="--dataset folder: a folder, not a dataset file")
    assert listing(tmp_path) == ["earlier", "earlier/summary.json", "folder", "folder/model.pt"]
    one_line_value_error(evaluate.main, evaluate.Args(policy="greedy", maps=(str(ROOT / "maps/external/empty-8-8.map"),),
                                                      out="earlier"), match="summary.json: there already; --overwrite")
    evaluate.main(evaluate.Args(policy="greedy", maps=(str(ROOT / "maps/external/empty-8-8.map"),), out="earlier",
                                quiet=True, overwrite=True))  # an earlier --out is written again with --overwrite
    assert sorted(os.listdir(tmp_path / "earlier")) == ["episodes.csv", "summary.json"]


def test_evaluate_finds_the_shipped_models_from_another_folder(tmp_path, monkeypatch):
    import evaluate

    monkeypatch.chdir(tmp_path)  # no models/ here: the default checkpoints are the ones beside evaluate.py
    room = str(ROOT / "maps/external/empty-8-8.map")
    for policy, agents in (("rainbow", 1), ("marl", 2), ("tabular", 1)):
        summary = evaluate.main(evaluate.Args(policy=policy, agents=agents, maps=(room,), out=policy, quiet=True))
        assert summary["all"]["completion_rate"] == 1.0
    assert sorted(os.listdir(tmp_path)) == ["marl", "rainbow", "tabular"]


def test_classical_cpp_overwrites_metrics_only_with_overwrite(tmp_path):
    import classical_cpp as cc

    (tmp_path / "model.json").write_text('{\n "args": {}\n}\n')
    one_line_value_error(cc.main, cc.Args(maps=(str(ROOT / "maps/external/empty-8-8.map"),), out=str(tmp_path / "model.json")),
                         match="model.json: there already; --overwrite replaces it")
    assert (tmp_path / "model.json").read_text() == '{\n "args": {}\n}\n'
    one_line_value_error(cc.main, cc.Args(report=True, maps=("x.map",), out=str(tmp_path / "report")),
                         match="--report plans its own maps")
    out = tmp_path / "metrics.jsonl"
    for overwrite in (False, True):  # the second run writes over the first's metrics, as --overwrite asks
        cc.main(cc.Args(maps=(str(ROOT / "maps/external/empty-8-8.map"),), out=str(out), quiet=True,
                        overwrite=overwrite))
    assert len(out.read_text().splitlines()) == 1
    assert listing(tmp_path) == ["metrics.jsonl", "model.json"]
