"""gridworld's one write rule, which every script's output goes through: each folder of committed artefacts holds
only its own kind of file, an existing file is replaced only with --overwrite (runs/ is the scripts' scratch),
and a write is staged (all or nothing, a one-line error on a full disk). Then each CLI that writes, refused."""
from __future__ import annotations

import ast
import errno
import json
import os
from pathlib import Path

import pytest
from test_bad_inputs import one_line_error, repo_untouched, run  # noqa: F401 (a fixture)

import gridworld as gw

ROOT = Path(__file__).resolve().parent.parent
WRITERS = ("rainbow_cpp.py", "rainbow_marl.py", "tabular_q.py", "evaluate.py", "classical_cpp.py", "report.py",
           "maps/make_datasets.py", *(f"benchmarks/{p.name}" for p in sorted((ROOT / "benchmarks").glob("*.py"))))


@pytest.mark.parametrize("folder, kind", [("models", "result"), ("models", "dataset"), ("results", "model"),
                                          ("results", "video"), ("maps", "model"), ("maps", "result")])
def test_a_committed_folder_holds_only_its_own_kind(folder, kind):
    with pytest.raises(ValueError, match=rf"--x .*{folder}/new\.bin: inside {folder}/, which holds committed") as e:
        gw.check_output(str(ROOT / folder / "new.bin"), kind, overwrite=True, flag="--x")
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("folder, kind", [("models", "model"), ("results", "result"), ("maps", "dataset")])
def test_its_own_kind_is_welcome_when_new(folder, kind):
    assert gw.check_output(str(ROOT / folder / "not-there-yet.bin"), kind) == str(ROOT / folder / "not-there-yet.bin")


def test_an_existing_file_is_replaced_only_with_overwrite(tmp_path):
    mine = tmp_path / "mine.json"
    mine.write_text("{}")
    with pytest.raises(ValueError, match=r"mine\.json: there already; --overwrite replaces it"):
        gw.check_output(str(mine), "result")
    assert gw.check_output(str(mine), "result", overwrite=True)
    with pytest.raises(ValueError, match="a folder, not a file"):
        gw.check_output(str(tmp_path), "result", overwrite=True)


def test_runs_is_scratch_where_files_are_replaced(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "runs" / "x").mkdir(parents=True)
    (tmp_path / "runs" / "x" / "summary.json").write_text("{}")
    assert gw.check_output("runs/x/summary.json", "result")


def test_staged_output_is_all_or_nothing(tmp_path):
    target = tmp_path / "table.json"
    target.write_text("old")
    with pytest.raises(RuntimeError), gw.staged_output(str(target), "model", overwrite=True) as tmp:
        Path(tmp).write_text("half")
        raise RuntimeError("killed mid-write")
    assert target.read_text() == "old" and os.listdir(tmp_path) == ["table.json"]
    with gw.staged_output(str(target), "model", overwrite=True) as tmp:
        assert tmp.endswith(".json") and Path(tmp).parent == tmp_path  # the format shows; one rename away
        Path(tmp).write_text("new")
    assert target.read_text() == "new" and os.listdir(tmp_path) == ["table.json"]


def test_a_full_disk_is_one_line_and_keeps_the_old_file(tmp_path, monkeypatch):
    target = tmp_path / "model.pt"
    target.write_text("old")

    def full(*_):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "replace", full)
    with pytest.raises(ValueError, match=r"^--export .*model\.pt: cannot write \(No space left on device\); any ") as e:
        with gw.staged_output(str(target), "model", overwrite=True, flag="--export") as tmp:
            Path(tmp).write_text("new")
    assert "\n" not in str(e.value)
    assert target.read_text() == "old" and os.listdir(tmp_path) == ["model.pt"]


def test_write_json_refuses_numbers_json_cannot_hold(tmp_path):
    with pytest.raises(ValueError, match="not finite, which JSON cannot; nothing written"):
        gw.write_json(str(tmp_path / "r.json"), {"overlap": float("nan")}, "result")
    assert not os.listdir(tmp_path)
    gw.write_json(str(tmp_path / "r.json"), {"overlap": 0.5}, "result")
    assert json.loads((tmp_path / "r.json").read_text()) == {"overlap": 0.5}


@pytest.mark.parametrize("script", WRITERS)
def test_no_script_writes_a_file_around_the_rule(script):
    """Every call that creates a file in the CLIs (open for writing, torch.save, np.savez*, savefig, the video
    writer) writes to a path given by gridworld.staged_output, i.e. sits in a function that uses the rule, or is a
    writer that evaluate's and report's staging hand a temporary path."""
    tree = ast.parse((ROOT / script).read_text())
    given_a_temporary_path = {"_write_csv", "_write_json", "_write_text", "_write_video", "_write_panels",  # evaluate
                              "_save"}  # report's figures, drawn into its staging folder
    not_an_output = {"lock_run", "write_stage", "batched_trainer"}  # a lock file; benchmarks: a stage in a temporary folder

    def writes(node: ast.Call) -> bool:
        f = node.func
        name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
        if name == "open":
            mode = node.args[1] if len(node.args) > 1 else next((k.value for k in node.keywords if k.arg == "mode"), None)
            return isinstance(mode, ast.Constant) and any(c in mode.value for c in "wax")
        return (name in ("savez", "savez_compressed", "savefig", "write_videofile", "write_text")
                or name in ("save", "dump") and len(node.args) >= 2)

    around = []
    for function in ast.walk(tree):
        if not isinstance(function, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        for node in ast.walk(function):
            if (isinstance(node, ast.Call) and writes(node) and "staged_output" not in ast.unparse(function)
                    and "tmp" not in ast.unparse(node) and function.name not in given_a_temporary_path | not_an_output):
                around.append(f"{script}:{node.lineno} {function.name}: {ast.unparse(node)[:70]}")
    assert not around, "\n".join(around)


def test_classical_out_replaces_an_earlier_file_only_with_overwrite(tmp_path, repo_untouched):  # noqa: F811
    (tmp_path / "room.txt").write_text("....\n....\n")
    out = tmp_path / "metrics.jsonl"
    out.write_text("precious\n")
    one_line_error(run("classical_cpp.py", "--maps", str(tmp_path / "room.txt"), "--out", str(out), "--quiet"),
                   "--out", "there already; --overwrite replaces it")
    assert out.read_text() == "precious\n"
    done = run("classical_cpp.py", "--maps", str(tmp_path / "room.txt"), "--out", str(out), "--quiet", "--overwrite")
    assert done.returncode == 0, done.stderr
    assert '"overlap"' in out.read_text()


def test_evaluate_keeps_an_earlier_out_outside_runs_unless_overwrite(tmp_path):
    (tmp_path / "room.txt").write_text("....\n....\n")
    flags = ("--maps", str(tmp_path / "room.txt"), "--out", str(tmp_path / "eval"))
    assert run("evaluate.py", *flags).returncode == 0
    summary = (tmp_path / "eval" / "summary.json").read_text()
    one_line_error(run("evaluate.py", *flags, "--seed", "3"), "episodes.csv: there already; --overwrite")
    assert (tmp_path / "eval" / "summary.json").read_text() == summary
    assert run("evaluate.py", *flags, "--seed", "3", "--overwrite").returncode == 0
    assert json.loads((tmp_path / "eval" / "summary.json").read_text())["seed"] == 3


def test_evaluate_under_runs_replaces_its_earlier_out(tmp_path):
    (tmp_path / "room.txt").write_text("....\n....\n")
    for seed in ("1", "2"):
        done = run("evaluate.py", "--maps", str(tmp_path / "room.txt"), "--seed", seed, cwd=tmp_path)
        assert done.returncode == 0, done.stderr
    assert json.loads((tmp_path / "runs" / "eval" / "summary.json").read_text())["seed"] == 2


@pytest.mark.parametrize("script", ["benchmarks/recipe_speed.py", "benchmarks/train_speed.py"])
def test_benchmark_outputs_are_refused_before_measuring(script, tmp_path):
    kept = tmp_path / "figures.json"
    kept.write_text("{}")
    one_line_error(run(script, "--json", str(kept)), "--json", "there already; --overwrite replaces it")
    one_line_error(run(script, "--json", str(ROOT / "models" / "figures.json")), "inside models/")
    assert kept.read_text() == "{}"
