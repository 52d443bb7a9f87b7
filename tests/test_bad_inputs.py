"""Issue 44's bad inputs to the command lines that are not trainers (tabular_q.py, classical_cpp.py, evaluate.py,
the benchmarks) and to gridworld's loaders: each is one `error: ...` line on stderr, a non-zero exit, no traceback,
and nothing committed changes (sha256 of the file, and `git status` of the repository, before and after). Ctrl-C
(SIGINT) exits 130 and SIGTERM 143, with one line.
"""
from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

import gridworld as gw
import tabular_q as tq

ROOT = Path(__file__).resolve().parent.parent
ENV = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONDONTWRITEBYTECODE": "1"}


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def git_status() -> str:
    return subprocess.run(["git", "status", "--porcelain", "--untracked-files=all"], cwd=ROOT, capture_output=True,
                          text=True, check=True).stdout


@pytest.fixture
def repo_untouched():
    """The repository's `git status` is the same after the test."""
    before = git_status()
    yield
    assert git_status() == before


def run(script: str, *flags: str, cwd: Path = ROOT, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / script), *flags], cwd=cwd, env=ENV, capture_output=True,
                          text=True, timeout=timeout)


def one_line_error(done: subprocess.CompletedProcess, *words: str) -> str:
    """A refused run: non-zero, stderr one `error:` line (naming every word given), no traceback."""
    assert done.returncode != 0, done.stdout
    assert "Traceback" not in done.stderr, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), done.stderr
    for w in words:
        assert w in lines[0], lines[0]
    return lines[0]


def catches_sigterm(pid: int) -> bool:
    """Whether process `pid` has a handler for SIGTERM (Linux: the SigCgt mask of /proc/PID/status). The scripts
    install one on entering gridworld.cli_errors, after their imports: from then on a signal is theirs to report."""
    try:
        with open(f"/proc/{pid}/status") as f:
            mask = next(int(line.split()[1], 16) for line in f if line.startswith("SigCgt:"))
    except (OSError, StopIteration):
        return True  # no /proc: fall back on the wait alone
    return bool(mask >> (signal.SIGTERM - 1) & 1)


def interrupted(script: str, *flags: str, signum: int, cwd: Path, ready=None, wait: float = 1.5):
    """Run a script, send it `signum` once `ready(first stdout line)` holds, or `wait` seconds after it catches
    SIGTERM (its imports done), and return (exit status, stderr, stdout). SIGINT is set back to its default in the
    child, since a shell's background job (as pytest may be one) ignores it and the child would inherit that."""
    p = subprocess.Popen([sys.executable, str(ROOT / script), *flags], cwd=cwd, env=ENV, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        if ready is not None:
            line = p.stdout.readline()
            assert ready(line), line
            time.sleep(0.5)
        else:
            deadline = time.monotonic() + 60
            while not catches_sigterm(p.pid) and p.poll() is None and time.monotonic() < deadline:
                time.sleep(0.05)
            time.sleep(wait)
        assert p.poll() is None, "finished before the signal"
        p.send_signal(signum)
        out, err = p.communicate(timeout=60)
    finally:
        if p.poll() is None:
            p.kill()
    return p.returncode, err, out


# ----------------------------------------------------------------------------- tabular_q.py
@pytest.mark.parametrize("path", ["maps/cpp_eval.npz", "results/rainbow_cpp.npz", "results/classical_cpp.npz"])
def test_tabular_q_never_writes_into_maps_or_results(path, repo_untouched):
    guarded = [ROOT / path, (ROOT / path).with_suffix(".json")]
    before = {p: sha(p) for p in guarded if p.exists()}
    err = one_line_error(run("tabular_q.py", "--episodes", "10", "--num-worlds", "4", "--quiet", "--table-path", path,
                             "--overwrite"), path)
    assert "maps/" in err or "results/" in err
    assert {p: sha(p) for p in guarded if p.exists()} == before


def test_tabular_q_replaces_only_its_own_tables_and_only_with_overwrite(tmp_path):
    flags = ["--episodes", "8", "--num-worlds", "4", "--size", "4", "--quiet"]
    dataset = tmp_path / "data.npz"
    gw.save_dataset(str(dataset), [gw.Scenario(np.zeros((4, 4), bool), np.array([[0, 0]]))])
    foreign = tmp_path / "model.json"
    foreign.write_text('{"args": {}}\n')
    kept = {p: sha(p) for p in (dataset, foreign)}
    one_line_error(run("tabular_q.py", *flags, "--table-path", "data.npz", "--overwrite", cwd=tmp_path),
                   "data.npz exists and is not a tabular_q table")
    one_line_error(run("tabular_q.py", *flags, "--table-path", "model.npz", "--overwrite", cwd=tmp_path),
                   "model.json exists and is not a tabular_q table's .json")
    assert {p: sha(p) for p in kept} == kept
    done = run("tabular_q.py", *flags, "--table-path", "t.npz", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    table = sha(tmp_path / "t.npz")
    one_line_error(run("tabular_q.py", *flags, "--table-path", "t.npz", "--seed", "2", cwd=tmp_path), "--overwrite")
    assert sha(tmp_path / "t.npz") == table
    done = run("tabular_q.py", *flags, "--table-path", "t.npz", "--seed", "2", "--overwrite", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert json.loads((tmp_path / "t.json").read_text())["args"]["seed"] == 2
    assert sorted(os.listdir(tmp_path)) == ["data.npz", "model.json", "t.json", "t.npz"]  # no temporary file left
    assert (tmp_path / "t.npz").stat().st_mode & 0o777 == 0o666 & ~gw.UMASK  # not mkstemp's 0600


def test_tabular_q_save_is_atomic(tmp_path, monkeypatch):
    path = tmp_path / "t.npz"
    table = tq.QTable(3, 3)
    table.rows(np.array([11, 22]))
    table.save(str(path))
    before = sha(path)

    def full_disk(file, **arrays):
        with open(file, "wb") as f:
            f.write(b"PK\x03\x04 half a table")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(np, "savez_compressed", full_disk)
    table.rows(np.array([33]))
    with pytest.raises(ValueError, match="No space left on device"):
        table.save(str(path))
    assert sha(path) == before and os.listdir(tmp_path) == ["t.npz"]
    assert tq.QTable.load(str(path)).size == 3  # the never-seen row and the two keys of the first save


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_tabular_q_interrupted_saves_the_table_so_far(tmp_path, signum):
    code, err, _ = interrupted("tabular_q.py", "--episodes", "100000000", "--num-worlds", "8", "--size", "4",
                               "--quiet", "--log-every", "0", "--table-path", "t.npz", signum=signum, cwd=tmp_path,
                               ready=lambda line: "-> t.npz" in line)
    name = signal.Signals(signum).name
    assert code == 128 + signum and "Traceback" not in err, err
    (line,) = err.strip().splitlines()
    assert line.startswith(f"error: interrupted by {name} after ") and "the table so far is saved -> t.npz" in line
    info = json.loads((tmp_path / "t.json").read_text())
    assert info["interrupted"] == name and info["episodes"] > 0
    assert tq.QTable.load(str(tmp_path / "t.npz")).size - 1 == info["states"]


def test_tabular_q_huge_size_is_refused_before_allocating(tmp_path):
    one_line_error(run("tabular_q.py", "--size", "100000", cwd=tmp_path), "--size must be at most 256")
    assert os.listdir(tmp_path) == []


# ----------------------------------------------------------------------------- classical_cpp.py
def test_classical_report_needs_overwrite(tmp_path, repo_untouched):
    committed = ROOT / "results" / "classical_cpp.json"
    before = sha(committed)
    one_line_error(run("classical_cpp.py", "--report", "--quiet", timeout=60), "--overwrite", "classical_cpp.json")
    assert sha(committed) == before
    (tmp_path / "classical_cpp.json").write_text("{}")
    one_line_error(run("classical_cpp.py", "--report", "--quiet", "--out", str(tmp_path), timeout=60), "--overwrite")
    assert (tmp_path / "classical_cpp.json").read_text() == "{}"


def npz_claiming(path: Path, shape: tuple[int, ...]) -> None:
    """An .npz whose `obstacles` header says `shape` (its data cut short: only the header may be read), with
    small `sizes` and `starts`: what a 30000x30000 map looks like to a loader before it decompresses anything."""
    header = Path(str(path) + ".npy")
    with open(header, "wb") as f:
        np.lib.format.write_array_header_1_0(f, {"descr": "|b1", "fortran_order": False, "shape": shape})
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        z.write(header, "obstacles.npy")
        for name, a in (("sizes", np.array([[shape[1], shape[2]]])), ("starts", np.zeros((1, 1, 2), int))):
            np.save(header, a)
            z.write(header, f"{name}.npy")
    header.unlink()


@pytest.mark.parametrize("rows,shape", [(["." * 500] * 500, "500x500"), (["." * 3000], "1x3000")])
def test_classical_refuses_maps_past_the_largest_side(tmp_path, rows, shape):
    h, w = len(rows), len(rows[0])
    (tmp_path / "big.map").write_text(f"type octile\nheight {h}\nwidth {w}\nmap\n" + "\n".join(rows) + "\n")
    start = time.perf_counter()
    one_line_error(run("classical_cpp.py", "--quiet", "--maps", "big.map", cwd=tmp_path), f"a {shape} map", "256")
    assert time.perf_counter() - start < 30  # not minutes of silent planning
    (tmp_path / "big.txt").write_text("\n".join(rows) + "\n")  # the plain ASCII format too
    one_line_error(run("classical_cpp.py", "--quiet", "--maps", "big.txt", cwd=tmp_path), f"a {shape} map")


def test_classical_and_evaluate_refuse_a_huge_dataset_before_loading_it(tmp_path):
    npz_claiming(tmp_path / "huge.npz", (1, 30000, 30000))
    one_line_error(run("classical_cpp.py", "--quiet", "--dataset", "huge.npz", cwd=tmp_path), "30000x30000", "256")
    one_line_error(run("evaluate.py", "--policy", "greedy", "--dataset", "huge.npz", "--out", "o", cwd=tmp_path),
                   "30000x30000")
    npz_claiming(tmp_path / "many.npz", (10 ** 6, 256, 256))
    one_line_error(run("classical_cpp.py", "--quiet", "--dataset", "many.npz", cwd=tmp_path), "MAX_DATASET_CELLS")
    assert sorted(os.listdir(tmp_path)) == ["huge.npz", "many.npz"]


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_classical_interrupted(tmp_path, signum):
    code, err, _ = interrupted("classical_cpp.py", "--planner", "rollout", "--quiet", "--dataset",
                               str(ROOT / "maps" / "cpp_eval.npz"), "--out", "rows.jsonl", signum=signum, cwd=tmp_path)
    assert code == 128 + signum and "Traceback" not in err, err
    assert err.strip() == f"error: interrupted by {signal.Signals(signum).name}; nothing written"
    assert os.listdir(tmp_path) == []


# ----------------------------------------------------------------------------- evaluate.py
@pytest.mark.parametrize("start", ["[1000000000000000000000000000000, 1]", "[1e30, 1]", "[-99999999999999999999, 0]"])
def test_evaluate_refuses_a_start_too_large_for_any_map(tmp_path, start):
    (tmp_path / "starts.json").write_text(f'{{"empty-8-8.map": [{start}]}}')
    one_line_error(run("evaluate.py", "--policy", "greedy", "--maps", str(ROOT / "maps/external/empty-8-8.map"),
                       "--starts", "starts.json", "--out", "o", cwd=tmp_path), "is not a [row, col] start")
    assert os.listdir(tmp_path) == ["starts.json"]


@pytest.mark.parametrize("policy,model", [("rainbow", "rainbow_cpp.pt"), ("marl", "rainbow_marl.pt")])
def test_evaluate_refuses_a_model_with_non_finite_weights(tmp_path, policy, model):
    torch = pytest.importorskip("torch")
    state = torch.load(ROOT / "models" / model, weights_only=False)
    name = next(k for k, v in state["weights"].items() if v.is_floating_point())
    state["weights"][name] = torch.full_like(state["weights"][name], float("nan"))
    torch.save(state, tmp_path / "nan.pt")
    one_line_error(run("evaluate.py", "--policy", policy, "--agents", "2" if policy == "marl" else "1",
                       "--checkpoint", "nan.pt", "--maps", str(ROOT / "maps/external/empty-8-8.map"), "--out", "o",
                       cwd=tmp_path), "nan.pt", "not finite")
    assert os.listdir(tmp_path) == ["nan.pt"]


def test_evaluate_refuses_a_table_with_non_finite_values(tmp_path):
    table = tq.QTable(3, 3)
    table.rows(np.array([11, 22]))
    table.q[0, 1, 2] = np.inf
    table.save(str(tmp_path / "inf.npz"))
    one_line_error(run("evaluate.py", "--policy", "tabular", "--checkpoint", "inf.npz", "--maps",
                       str(ROOT / "maps/external/empty-8-8.map"), "--out", "o", cwd=tmp_path), "not finite")
    assert os.listdir(tmp_path) == ["inf.npz"]


def test_evaluate_refuses_non_finite_flags(tmp_path):
    one_line_error(run("evaluate.py", "--policy", "frontier", "--sensor-failure", "nan", "--maps",
                       str(ROOT / "maps/external/empty-8-8.map"), "--out", "o", cwd=tmp_path),
                   "--sensor-failure must be a finite number")


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_evaluate_interrupted(tmp_path, signum):
    code, err, _ = interrupted("evaluate.py", "--policy", "frontier-rollout", "--quiet", "--dataset",
                               str(ROOT / "maps" / "cpp_eval.npz"), "--out", "o", signum=signum, cwd=tmp_path)
    assert code == 128 + signum and "Traceback" not in err, err
    assert err.strip() == f"error: interrupted by {signal.Signals(signum).name}; nothing written"
    assert os.listdir(tmp_path) == []


# ----------------------------------------------------------------------------- gridworld's configs and maps
@pytest.mark.parametrize("text,problem", [
    ("a: {size: 8, battery_factor: .nan}\n", "battery_factor must be a finite number, got nan"),
    ("a: {size: 8, battery_factor: .inf}\n", "battery_factor must be a finite number, got inf"),
    ("a: {size: 8, sensor_failure: .nan}\n", "sensor_failure must be a finite number"),
    ("a: {size: 8, random_coverage_max: -.inf}\n", "random_coverage_max must be a finite number"),
    ("a: {size: 8, reward: {new_cell: .nan}}\n", "new_cell must be a finite number"),
    ("a: {size: 8, map_family: clutter, family: {block_count: [1, .inf]}}\n", "pair of finite numbers"),
    ("a: {size: 8, map_family: maze, family: {braid: .nan}}\n", "braid must be a number in \\[0, 1\\]"),
    ("a: {size: 100000}\n", "size must be at most 256"),
    ("a: {size: 8}\nb: {size: 9}\na: {size: 10}\n", "duplicate name: 'a' is given twice \\(again at line 3\\)"),
    ("a: {size: 8, size: 9}\n", "duplicate name: 'size' is given twice"),
    ("- {name: a, size: 8}\n- {name: a, size: 9}\n", "duplicate name: 'a' names two list items"),
])
def test_config_refuses_non_finite_huge_and_duplicate_settings(tmp_path, text, problem):
    path = tmp_path / "stages.yaml"
    path.write_text(text)
    with pytest.raises(ValueError, match=problem) as info:
        gw.load_config(str(path))
    assert type(info.value) is ValueError and "\n" not in str(info.value)


def test_committed_stage_files_still_load():
    for path in sorted((ROOT / "models").glob("*.yaml")):
        assert gw.load_config(str(path))


def test_loaders_check_the_side_before_reading_the_cells(tmp_path):
    (tmp_path / "header.map").write_text("type octile\nheight 100000\nwidth 100000\nmap\n....\n")
    with pytest.raises(ValueError, match="a 100000x100000 map is larger than the largest map side allowed, 256"):
        gw.load_map(str(tmp_path / "header.map"))
    with open(tmp_path / "huge.txt", "wb") as f:
        f.truncate(gw.MAX_MAP_FILE_BYTES + 1)
    with pytest.raises(ValueError, match="over 16 MB"):
        gw.load_map(str(tmp_path / "huge.txt"))
    ok = np.zeros((gw.MAX_MAP_SIDE, 3), bool)  # the bound itself is allowed
    gw.save_map(str(tmp_path / "ok.txt"), gw.Scenario(ok))
    assert gw.load_map(str(tmp_path / "ok.txt")).obstacles.shape == (gw.MAX_MAP_SIDE, 3)


# ----------------------------------------------------------------------------- benchmarks
@pytest.mark.parametrize("script,flags,problem", [
    ("team_rollout.py", ["--agents", "0"], "the team rollout needs >= 2 agents"),
    ("team_rollout.py", ["--marl-every", "0"], "marl_every must be >= 1"),
    ("rollout_planner.py", ["--per-size", "-1"], "--per-size must be >= 0, got -1"),
])
def test_benchmark_bad_flags(tmp_path, script, flags, problem):
    one_line_error(run(f"benchmarks/{script}", *flags, "--cpu", "-1", cwd=tmp_path, timeout=60), problem)
    assert os.listdir(tmp_path) == []
