"""What rainbow_cpp.py and rainbow_marl.py share, and how both treat their files and flags.

- The code the two trainers share is repeated in each (every script is self-contained): the definitions
  listed in SHARED must be source-identical, so a fix made in one file and not the other fails here.
- The observation constants come from gridworld (41-cell view, 5 + 8 extras a frame).
- Warm starts and resumes take the network's width and frame stack from the file they load; a flag that
  contradicts it is an error.
- Every bad input (a missing, truncated or foreign file, a bad stage YAML, a negative count) is a one-line
  ValueError (`error: ...` and a non-zero exit on the command line) and nothing is written.
- Each export's JSON records its provenance and its parent's, back to the first model.
- evaluate_policy(trajectories=[]) gives every agent's cells, step by step, as gridworld played them.
"""
from __future__ import annotations

import ast
import collections
import hashlib
import json
import os
import pickle
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

import gridworld as gw
import rainbow_cpp as rc
import rainbow_marl as rm

ROOT = Path(__file__).resolve().parent.parent
TRAINERS = {"rainbow_cpp": rc, "rainbow_marl": rm}

# every top-level definition meant to be equal in the two scripts
SHARED = [
    "SCRIPT", "HERE", "DEEP", "OBSERVATION", "VIEW", "CHANNELS", "LAST_ACTIONS", "OUT_OF_BOUNDS", "EXTRAS",
    "OUT_OF_BOUNDS_SCALE", "MOVES", "DISSERTATION", "NETWORKS", "SCALE_KEYS", "HINTS", "COMPACT",
    "NoisyLinear", "Dueling", "QNetwork", "CompactQNetwork", "build_network", "observation_settings",
    "SumTree", "Replay", "Stacker", "large_margin_loss", "learn", "diagnostics_of",
    "network_of", "policy_from", "load_policy", "check_flags", "with_network", "observed", "start_run", "hinted",
    "settle_flags",
]
# the Args fields that the shared code reads, equal in both (flag, default and docstring)
SHARED_FLAGS = ["exp_name", "seed", "run_name", "threads", "cuda", "torch_deterministic", "quiet",
                "capture_video", "network", "conv_width", "scales", "scale_factor", "scale_view",
                "hint", "time_limit", "td_weight",
                "heuristic_far_first", "overwrite"]


def definitions(source: str) -> dict[str, str]:
    """Top-level classes, functions and assignments of a module: name -> source text."""
    out = {}
    for node in ast.parse(source).body:
        if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            out[node.name] = ast.get_source_segment(source, node)
        elif isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
            out[node.targets[0].id] = ast.get_source_segment(source, node)
    return out


def drift(a: str, b: str, names: list[str]) -> list[str]:
    """The names whose definitions differ (or are missing) between two sources."""
    da, db = definitions(a), definitions(b)
    return [n for n in names if n not in da or n not in db or da[n] != db[n]]


def args_fields(source: str) -> dict[str, str]:
    """Args field name -> its annotation, default and docstring as written."""
    cls = next(n for n in ast.parse(source).body if isinstance(n, ast.ClassDef) and n.name == "Args")
    out, body = {}, cls.body
    for i, node in enumerate(body):
        if isinstance(node, ast.AnnAssign):
            doc = body[i + 1] if i + 1 < len(body) and isinstance(body[i + 1], ast.Expr) else None
            out[node.target.id] = ast.get_source_segment(source, node) + (ast.get_source_segment(source, doc) if doc else "")
    return out


def sources():
    return (ROOT / "rainbow_cpp.py").read_text(), (ROOT / "rainbow_marl.py").read_text()


# ----------------------------------------------------------------------------- no drift
def test_shared_definitions_are_source_identical():
    cpp, marl = sources()
    assert drift(cpp, marl, SHARED) == []


def test_the_shared_section_holds_exactly_the_listed_definitions():
    cpp, marl = sources()
    start, end = "# " + "=" * 77 + " shared by the two trainers", "# " + "=" * 77 + " end of the shared code"
    sections = [s[s.index(start):s.index(end)] for s in (cpp, marl)]
    assert sections[0] == sections[1]  # comments included
    listed = set(definitions(sections[0].split("\n", 1)[1]))
    assert listed == set(SHARED)


def test_imports_entry_point_and_shared_flags_are_identical():
    cpp, marl = sources()

    def imports(src):
        return [ast.get_source_segment(src, n) for n in ast.parse(src).body if isinstance(n, (ast.Import, ast.ImportFrom))]

    def entry(src):
        return next(ast.get_source_segment(src, n) for n in ast.parse(src).body if isinstance(n, ast.If))

    assert imports(cpp) == imports(marl)
    assert entry(cpp) == entry(marl)
    fc, fm = args_fields(cpp), args_fields(marl)
    assert all(fc[k] == fm[k] for k in SHARED_FLAGS)


def test_a_one_character_drift_is_caught():
    cpp, marl = sources()
    changed = cpp.replace("self.tree = np.zeros(2 * self.size)", "self.tree = np.zeros(2 * self.size + 1)")
    assert changed != cpp and drift(changed, marl, SHARED) == ["SumTree"]


def test_marl_sumtree_and_noisy_layer_behave():
    """The identity above makes rainbow_cpp's unit tests cover rainbow_marl's copies; one check of each here."""
    tree = rm.SumTree(5)
    tree.update(np.arange(5), np.array([0.0, 1.0, 0.0, 3.0, 0.0]))
    assert tree.total() == 4.0 and set(tree.sample(400, np.random.default_rng(0)).tolist()) == {1, 3}
    layer = rm.NoisyLinear(4, 2, 0.5)
    layer.reset_noise(False)
    x = torch.randn(3, 4)
    assert torch.allclose(layer(x), x @ layer.weight_mu.T + layer.bias_mu)


# ----------------------------------------------------------------------------- constants from gridworld
@pytest.mark.parametrize("name", TRAINERS)
def test_observation_constants_come_from_gridworld(name):
    t = TRAINERS[name]
    assert t.VIEW == gw.EnvConfig().view_size == 41 and t.CHANNELS == 4
    assert t.EXTRAS == 5 + 4 * 2 and t.MOVES == 4 and t.OUT_OF_BOUNDS_SCALE == 100
    q = t.QNetwork(2, t.VIEW, 16, 0.5)
    assert q.value[0].n_in == 64 * 9 * 9 + 1 + 2 * 13  # conv features, battery, 13 extras per frame
    assert q.conv[0].in_channels // 4 == q.frames == 2  # evaluate.py reads the frame count either way
    assert q.network() == {"network": "fig6.8", "frames": 2, "hidden": 16, "view": 41, "extras": 13,
                           "observation": "deep", "hint": False, "far_first": False}
    assert t.QNetwork(2, t.VIEW, 16, 0.5, hint=True).value[0].n_in == 64 * 9 * 9 + 1 + 2 * 13 + 5  # + the hint one-hot


# ----------------------------------------------------------------------------- run names, widths
def test_run_names():
    assert re.fullmatch(r"rainbow_cpp__7__\d+", gw.run_folder(None, "rainbow_cpp", 7, False))
    assert gw.run_folder("mine", "rainbow_cpp", 1, True) == "mine"
    with pytest.raises(ValueError, match="--resume needs --run-name"):
        gw.run_folder(None, "rainbow_cpp", 1, True)
    with pytest.raises(ValueError, match="--run-name must not be empty"):
        gw.run_folder(" ", "rainbow_cpp", 1, False)


@pytest.mark.parametrize("name", TRAINERS)
def test_width_and_frames_from_the_model_else_the_flags_else_the_dissertation(name):
    t = TRAINERS[name]
    model = {"frames": 3, "hidden": 256}
    chosen = t.with_network(t.Args(), None, None)
    assert (chosen.hidden, chosen.frame_stack) == (512, 3)
    chosen = t.with_network(t.Args(hidden=64, frame_stack=2), None, None)
    assert (chosen.hidden, chosen.frame_stack) == (64, 2)
    chosen = t.with_network(t.Args(), model, "m.pt")
    assert (chosen.hidden, chosen.frame_stack) == (256, 3)
    assert t.with_network(t.Args(hidden=256, frame_stack=3), model, "m.pt").hidden == 256
    with pytest.raises(ValueError) as e:
        t.with_network(t.Args(hidden=512), model, "models/rainbow_cpp.pt")
    assert str(e.value) == "--hidden 512 contradicts models/rainbow_cpp.pt (hidden 256)"
    with pytest.raises(ValueError, match=r"--frame-stack 4 contradicts m.pt \(frame stack 3\)"):
        t.with_network(t.Args(frame_stack=4), model, "m.pt")


def tiny(t, **kw):
    """A few steps, no learning, no evaluation: what a run writes, quickly."""
    base = dict(run_name="t", total_steps=8, num_envs=2, learning_starts=10 ** 6, buffer_size=2000, hidden=16,
                eval_every=0, save_every=0, quiet=True)
    if t is rm:
        base["init_from"] = ""
    return t.Args(**{**base, **kw})


def files(root: Path) -> dict:
    return {p.relative_to(root): hashlib.sha256(p.read_bytes()).hexdigest() for p in root.rglob("*") if p.is_file()}


def test_warm_start_takes_the_width_of_the_shipped_model(tmp_path, monkeypatch, restore_sigint):
    """rainbow_marl's default --init-from is models/rainbow_cpp.pt, whatever its width (256 today)."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "models").mkdir()
    shipped = rc.QNetwork(3, rc.VIEW, 24, 0.0)
    gw.export_model(shipped, rc.Args(hidden=24, export="models/rainbow_cpp.pt"), {})
    rm.main(tiny(rm, hidden=None, init_from="models/rainbow_cpp.pt", run_name=None))
    run = next((tmp_path / "runs").iterdir())
    info = json.loads((run / "rainbow_marl.json").read_text())
    assert info["args"]["hidden"] == 24 and info["network"]["hidden"] == 24 and info["args"]["frame_stack"] == 3
    assert info["parent"]["path"] == "models/rainbow_cpp.pt"


@pytest.mark.parametrize("name", TRAINERS)
def test_resume_takes_the_width_of_the_checkpoint(name, tmp_path, monkeypatch, restore_sigint):
    t = TRAINERS[name]
    monkeypatch.chdir(tmp_path)
    t.main(tiny(t, run_name="r"))
    t.main(tiny(t, run_name="r", resume=True, hidden=None, total_steps=16))
    state = torch.load(tmp_path / "runs" / "r" / "checkpoint.pt", weights_only=True)
    assert state["global_step"] == 16 and state["hidden"] == 16 and state["args"]["hidden"] == 16
    before = files(tmp_path)
    with pytest.raises(ValueError, match=r"--hidden 32 contradicts runs/r/checkpoint.pt \(hidden 16\)"):
        t.main(tiny(t, run_name="r", resume=True, hidden=32, total_steps=24))
    assert files(tmp_path) == before


# ----------------------------------------------------------------------------- bad input
def write_bad(tmp_path: Path, kind: str) -> str:
    """A file that must be refused as a model or checkpoint."""
    path = tmp_path / f"{kind}.pt"
    if kind == "truncated":
        path.write_bytes((ROOT / "models" / "rainbow_cpp.pt").read_bytes()[:5000])
    elif kind == "npz":
        np.savez(open(path, "wb"), a=np.zeros(3))
    elif kind == "text":
        path.write_text("not a model\n")
    elif kind == "tabular":
        path = tmp_path / "tabular_q.npz"
        path.write_bytes((ROOT / "models" / "tabular_q.npz").read_bytes())
    elif kind == "wrong_shapes":
        q = rc.QNetwork(3, rc.VIEW, 16, 0.0)
        torch.save({"weights": q.state_dict(), "frames": 3, "hidden": 32}, path)
    elif kind == "pickle":  # a pickle of arbitrary objects: refused unread, silently
        with open(path, "wb") as f:
            pickle.dump({"weights": collections.Counter(a=1)}, f, protocol=4)
    elif kind == "other_view":
        torch.save({"weights": {}, "frames": 3, "hidden": 16, "view": 21}, path)
    return str(path)


BAD_MODELS = ["missing", "truncated", "npz", "text", "tabular", "pickle", "wrong_shapes", "other_view"]


@pytest.mark.parametrize("name", TRAINERS)
@pytest.mark.parametrize("kind", BAD_MODELS)
def test_bad_init_from_is_a_one_line_error(name, kind, tmp_path, monkeypatch, restore_sigint):
    t = TRAINERS[name]
    monkeypatch.chdir(tmp_path)
    path = str(tmp_path / "missing.pt") if kind == "missing" else write_bad(tmp_path, kind)
    before = files(tmp_path)
    with pytest.raises(ValueError) as e:
        t.main(tiny(t, init_from=path, hidden=None))
    assert "\n" not in str(e.value) and str(e.value).startswith(path)
    assert files(tmp_path) == before  # nothing under runs/ or models/


@pytest.mark.parametrize("name", TRAINERS)
@pytest.mark.parametrize("kind", ["truncated", "text", "tabular", "export"])
def test_bad_checkpoint_to_resume_is_a_one_line_error(name, kind, tmp_path, monkeypatch, restore_sigint):
    t = TRAINERS[name]
    monkeypatch.chdir(tmp_path)
    (tmp_path / "runs" / "r").mkdir(parents=True)
    checkpoint = tmp_path / "runs" / "r" / "checkpoint.pt"
    if kind == "export":  # deployable weights are no training state
        checkpoint.write_bytes((ROOT / "models" / "rainbow_cpp.pt").read_bytes())
    else:
        os.replace(write_bad(tmp_path, kind), checkpoint)
    before = files(tmp_path)
    with pytest.raises(ValueError) as e:
        t.main(tiny(t, run_name="r", resume=True, hidden=None))
    assert "\n" not in str(e.value) and str(e.value).startswith("runs/r/checkpoint.pt: ")
    assert files(tmp_path) == before


@pytest.mark.parametrize("name", TRAINERS)
@pytest.mark.parametrize("yaml, message", [
    (None, "cannot read"),
    ("a: [1, 2\n", "not valid YAML"),
    ("a: {size: 5, base_steps: 10, colour: red}\n", "unknown environment setting"),
    ("a: {size: 5, base_steps: 0}\n", "base_steps"),
    ("a: {size: 5, base_steps: 1.5}\n", "base_steps"),
    ("{}\n", "no stages"),
])
def test_bad_stages_are_one_line_errors(name, yaml, message, tmp_path, monkeypatch, restore_sigint):
    t = TRAINERS[name]
    monkeypatch.chdir(tmp_path)
    stages = tmp_path / "stages.yaml"
    if yaml is not None:
        stages.write_text(yaml)
    before = files(tmp_path)
    with pytest.raises(ValueError, match=message) as e:
        t.main(tiny(t, stages=str(stages)))
    assert "\n" not in str(e.value)
    assert files(tmp_path) == before


@pytest.mark.parametrize("name", TRAINERS)
@pytest.mark.parametrize("flag, value", [("total_steps", -1), ("num_envs", 0), ("num_envs", -2),
                                         ("buffer_size", -5), ("batch_size", 0), ("learning_starts", -1),
                                         ("hidden", 0), ("frame_stack", -1), ("eval_every", -1),
                                         ("imitation", 1.5), ("gamma", -0.1)])
def test_bad_counts_are_one_line_errors(name, flag, value, tmp_path, monkeypatch, restore_sigint):
    t = TRAINERS[name]
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match=f"--{flag.replace('_', '-')} must be"):
        t.main(tiny(t, **{flag: value}))
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("name", TRAINERS)
@pytest.mark.parametrize("flags, message", [
    (["--total-steps", "-1"], "--total-steps must be >= 0, got -1"),
    (["--init-from", "tabular_q.npz"], "tabular_q.npz: not a rainbow_cpp / rainbow_marl model"),
    (["--resume"], "--resume needs --run-name"),
    (["--init-from", "pickle.pt"], "pickle.pt: not a rainbow_cpp / rainbow_marl model (not a torch file"),
    (["--stages", "stages.yaml"], "stages.yaml: not valid YAML"),
])
def test_command_line_errors(name, flags, message, tmp_path):
    (tmp_path / "tabular_q.npz").write_bytes((ROOT / "models" / "tabular_q.npz").read_bytes())
    (tmp_path / "stages.yaml").write_text("a: [1, 2\n")
    write_bad(tmp_path, "pickle")
    before = files(tmp_path)
    result = subprocess.run([sys.executable, str(ROOT / f"{name}.py"), *flags], cwd=tmp_path, capture_output=True,
                            text=True, env={**os.environ, "OMP_NUM_THREADS": "1"})
    assert result.returncode != 0 and "Traceback" not in result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0]
    assert files(tmp_path) == before


# ----------------------------------------------------------------------------- provenance and lineage
def test_each_export_records_its_provenance_and_its_parents(tmp_path, monkeypatch, restore_sigint):
    monkeypatch.chdir(tmp_path)
    rc.main(tiny(rc, run_name="a"))
    a = json.loads((tmp_path / "runs" / "a" / "rainbow_cpp.json").read_text())
    assert a["args"]["export"] == "runs/a/rainbow_cpp.pt" and a["args"]["run_name"] == "a"
    assert a["global_step"] == 8 and a["stage"] == "fi1" and a["parent"] is None  # the keys evaluate.py reads
    assert {"wall_seconds", "machine", "torch_threads"} <= set(a)
    p = a["provenance"]
    assert p["script"] == "rainbow_cpp.py" and p["env_steps"] == 8 and p["cores"] == os.cpu_count()
    assert p["torch_version"] == torch.__version__ and p["torch_threads"] == torch.get_num_threads()
    assert {"git_commit", "git_dirty", "cpu", "date", "wall_seconds"} <= set(p)
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\+00:00", p["date"])

    rm.main(tiny(rm, run_name="b", init_from="runs/a/rainbow_cpp.pt", hidden=None))  # transfer, as §7.4.2.2
    rc.main(tiny(rc, run_name="c", init_from="runs/b/rainbow_marl.pt", hidden=None))
    b = json.loads((tmp_path / "runs" / "b" / "rainbow_marl.json").read_text())
    c = json.loads((tmp_path / "runs" / "c" / "rainbow_cpp.json").read_text())
    sha = hashlib.sha256((tmp_path / "runs" / "a" / "rainbow_cpp.pt").read_bytes()).hexdigest()
    assert b["parent"]["path"] == "runs/a/rainbow_cpp.pt" and b["parent"]["sha256"] == sha
    assert b["parent"]["provenance"] == p and b["parent"]["global_step"] == 8 and b["parent"]["parent"] is None
    assert c["parent"]["provenance"] == b["provenance"]
    assert c["parent"]["parent"]["provenance"] == p and c["parent"]["parent"]["sha256"] == sha  # the whole chain

    rc.main(tiny(rc, run_name="c", resume=True, hidden=None, total_steps=16))  # a resumed run keeps its parent
    c2 = json.loads((tmp_path / "runs" / "c" / "rainbow_cpp.json").read_text())
    assert c2["global_step"] == 16 and c2["parent"] == c["parent"]


def test_a_bad_parent_record_is_a_one_line_error(tmp_path, monkeypatch, restore_sigint):
    monkeypatch.chdir(tmp_path)
    gw.export_model(rc.QNetwork(3, rc.VIEW, 16, 0.0), rc.Args(hidden=16, export="p.pt"), {})
    (tmp_path / "p.json").write_text("{not json")
    with pytest.raises(ValueError, match="p.json: not a model record"):
        rc.main(tiny(rc, init_from="p.pt", hidden=None))
    assert not (tmp_path / "runs").exists()


# ----------------------------------------------------------------------------- evaluation
def test_heuristic_baseline_by_hand():
    """A 1x4 corridor from its west end: three steps east, no revisit; a 2x2 room from a corner: three."""
    corridor = gw.Scenario(np.zeros((1, 4), bool), np.array([[0, 0]]))
    room = gw.Scenario(np.zeros((2, 2), bool), np.array([[0, 0]]))
    m = gw.heuristic_walk(gw.replay_config([corridor, room]), [corridor, room], False, True)
    assert m["steps"].tolist() == [3, 3] and m["overlap"].tolist() == [0, 0] and m["completed"].all()
    assert m["time_save"].tolist() == [1.0, 1.0]
    two = gw.Scenario(np.zeros((1, 4), bool), np.array([[0, 0], [0, 3]]))  # one agent at each end
    m = gw.heuristic_walk(gw.replay_config([two]), [two], False, True)
    assert m["steps"].tolist() == [1] and m["completed"].all()


def check_paths(scenarios, paths, m):
    for s, path, steps, new, done in zip(scenarios, paths, m["steps"], m["new_cells"], m["completed"]):
        assert path.dtype == np.int64 and path.shape == (steps + 1, len(s.starts), 2)
        assert (path[0] == s.starts).all()
        assert (np.abs(np.diff(path, axis=0)).sum(-1) <= 1).all()  # one move (or none) a step
        assert not s.obstacles[path[..., 0], path[..., 1]].any()
        known = np.zeros(s.obstacles.shape, bool) if s.covered is None else s.covered.copy()
        known[s.starts[:, 0], s.starts[:, 1]] = True
        seen = np.zeros_like(known)
        seen[path[..., 0].ravel(), path[..., 1].ravel()] = True
        assert (seen & ~known).sum() == new  # every new cell is on the path, and only those
        assert ((seen | known | s.obstacles).all()) == done


def test_cpp_trajectories_are_the_cells_of_the_episode():
    scenarios = [s for s in gw.load_dataset(str(ROOT / "maps" / "cpp_eval.npz")) if s.obstacles.shape[0] <= 6][:3]
    torch.manual_seed(0)
    q = rc.QNetwork(3, rc.VIEW, 16, 0.5)
    paths: list = []
    m = rc.evaluate_policy(q, scenarios, 3, trajectories=paths)
    assert len(paths) == 3
    check_paths(scenarios, paths, m)
    again = rc.evaluate_policy(q, scenarios, 3)  # recording changes nothing
    assert (again["steps"] == m["steps"]).all()
    frames = gw.replay_frames(scenarios[0], paths[0])  # gridworld replays them move for move
    assert len(frames) == m["steps"][0] + 1


def test_marl_trajectories_are_the_cells_of_every_agent():
    data = gw.load_dataset(str(ROOT / "maps" / "marl_eval.npz"))
    sizes = np.load(ROOT / "maps" / "marl_eval.npz")["size"]
    scenarios = [gw.Scenario(data[i].obstacles, data[i].starts[:n]) for i, n in zip(np.flatnonzero(sizes <= 8)[:3],
                                                                                    (3, 2, 3))]
    torch.manual_seed(0)
    q = rm.QNetwork(3, rm.VIEW, 16, 0.5)
    paths: list = []
    m = rm.evaluate_policy(q, scenarios, 3, trajectories=paths)
    assert [p.shape[1] for p in paths] == [3, 2, 3]  # each world's own agents
    check_paths(scenarios, paths, m)
    assert len(gw.replay_frames(scenarios[1], paths[1])) == m["steps"][1] + 1


@pytest.mark.parametrize("name", TRAINERS)
def test_capture_video_writes_one_mp4_per_evaluation(name, tmp_path, monkeypatch, restore_sigint, capsys):
    t = TRAINERS[name]
    monkeypatch.chdir(tmp_path)
    t.main(tiny(t, total_steps=8, eval_every=4, eval_maps=2, capture_video=True))
    videos = sorted(p.name for p in (tmp_path / "runs" / "t" / "videos").iterdir())
    assert videos == ["step_4.mp4", "step_8.mp4"]
    assert all((tmp_path / "runs" / "t" / "videos" / v).read_bytes()[4:8] == b"ftyp" for v in videos)  # MP4
    out = capsys.readouterr().out
    stat = "overlap" if t is rc else "time-save"
    line = rf"step 4  eval {stat} \d+\.\d{{3}}.* \(heuristic \d+\.\d{{3}} on the same maps\), completed \d+%, .*"
    assert re.search(line, out), out
    assert "SPS" not in out  # no progress lines with --quiet


def test_progress_bar_is_off_when_quiet_or_not_a_terminal(monkeypatch):
    assert gw.progress_bar(10, 0, quiet=True).disable
    monkeypatch.setattr(sys.stdout, "isatty", lambda: False)
    assert gw.progress_bar(10, 0, quiet=False).disable
    monkeypatch.setattr(sys.stdout, "isatty", lambda: True)
    assert not gw.progress_bar(10, 0, quiet=False).disable


def test_the_learning_rate_flag_names_the_default_it_falls_back_to():
    """--learning-rate defaults to None (the table's rate, or a resumed run's); its help gives LEARNING_RATE's value."""
    for module, source in zip((rc, rm), sources()):
        named = re.search(r"Table [\d.]+'s ([\d.e-]+), or a resumed run's own", args_fields(source)["learning_rate"])
        assert named and float(named.group(1)) == module.LEARNING_RATE
