"""The bad-input sweep, generated from every CLI's own Args dataclass (a new flag is covered without anyone
remembering to): for each numeric field 0, -1, nan, inf and a huge value, for each path field a missing, empty,
binary, truncated, folder and guarded path. Each case runs the CLI's main in this process up to the point where
its work would begin (a stub there raises Accepted): the outcome must be a one-line ValueError (the CLI prints it
as `error: ...` and exits 1) or Accepted, never another exception, and the repository's files stay as they were.
The test runs a third of the cases, a different third each day (SWEEP_SHARDS=1: all of them);
`PYTHONPATH=. python tests/test_input_sweep.py` runs all and prints the counts (tried / clean error / accepted /
traceback)."""
from __future__ import annotations

import dataclasses
import datetime
import math
import os
import shutil
import subprocess
import zlib
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

import classical_cpp
import evaluate
import gridworld as gw
import rainbow_cpp
import rainbow_marl
import tabular_q

ROOT = Path(__file__).resolve().parent.parent
HUGE_INT, HUGE_FLOAT = 10**12, 1e12


class Accepted(Exception):
    """main got past every check to where its work begins."""


def accept(*_, **__):
    raise Accepted


def stop_trainer(t):
    return {"lock_run": accept}  # after the stages, the networks and the replay memory are made, before any write


def stop_evaluate(t):
    made = evaluate._runner
    return {"_runner": lambda *a, **k: (made(*a, **k), accept)[1]}  # models loaded, maps read next, nothing run


CLIS = {  # module, the tiny run every case starts from, where its work begins
    "rainbow_cpp": (rainbow_cpp, dict(run_name="sweep", cuda=False, network="compact", quiet=True), stop_trainer),
    "rainbow_marl": (rainbow_marl, dict(run_name="sweep", cuda=False, network="compact", quiet=True), stop_trainer),
    "tabular_q": (tabular_q, dict(episodes=8, num_worlds=2, size=4, quiet=True), lambda t: {"play": accept}),
    "evaluate": (evaluate, dict(maps=("room.txt",), out="out", quiet=True), stop_evaluate),
    "classical_cpp": (classical_cpp, dict(maps=("room.txt",), quiet=True), lambda t: {"evaluate": accept,
                                                                                      "report": accept}),
}
INPUTS = {  # path fields read, with a valid file of their kind (truncated for one case) and the flags they need
    ("rainbow_cpp", "init_from"): ("models/rainbow_cpp.pt", {}),
    ("rainbow_cpp", "stages"): ("stages.yaml", {}),
    ("rainbow_marl", "init_from"): ("models/rainbow_marl.pt", {}),
    ("rainbow_marl", "stages"): ("stages.yaml", {}),
    ("tabular_q", "init_table"): ("table.npz", {}),
    ("evaluate", "checkpoint"): ("models/rainbow_cpp.pt", {"policy": "rainbow"}),
    ("evaluate", "maps"): ("room.txt", {}),
    ("evaluate", "dataset"): ("maps/cpp_eval.npz", {"maps": ()}),
    ("evaluate", "starts"): ("starts.json", {}),
    ("classical_cpp", "maps"): ("room.txt", {}),
    ("classical_cpp", "dataset"): ("maps/cpp_eval.npz", {"maps": ()}),
}
FINE = {("evaluate", "out", "folder"), ("evaluate", "video", "folder")}  # an empty folder is a good place for them
OUTPUTS = {("rainbow_cpp", "export"): ".pt", ("rainbow_marl", "export"): ".pt", ("tabular_q", "table_path"): ".npz",
           ("evaluate", "out"): "", ("evaluate", "video"): "", ("classical_cpp", "out"): ".jsonl"}


def numeric_fields(t) -> list[tuple[str, type]]:
    return [(f.name, float if "float" in str(f.type) else int) for f in dataclasses.fields(t.Args)
            if ("int" in str(f.type) or "float" in str(f.type)) and "bool" not in str(f.type)
            and "tuple" not in str(f.type)]


def cases():
    for cli, (t, _, _) in CLIS.items():
        for field, kind in numeric_fields(t):
            values = [0, -1, HUGE_INT] if kind is int else [0.0, -1.0, math.nan, math.inf, HUGE_FLOAT]
            for value in values:
                yield pytest.param(cli, field, value, id=f"{cli}-{field}-{value}")
    for (cli, field) in INPUTS:
        for case in ("missing", "empty", "binary", "truncated", "folder", "guarded"):
            yield pytest.param(cli, field, case, id=f"{cli}-{field}-{case}")
    for (cli, field) in OUTPUTS:
        for case in ("folder", "guarded", "binary", "empty"):
            yield pytest.param(cli, field, case, id=f"{cli}-{field}-{case}")


def files(folder: Path) -> None:
    """The valid inputs the cases start from, in the case's working folder."""
    (folder / "room.txt").write_text("....\n.@..\n....\n")
    (folder / "starts.json").write_text('{"room.txt": [[0, 0]]}\n')
    (folder / "stages.yaml").write_text("tiny:\n  size: 5\n  number_obstacles: 2\n  base_steps: 100\n")
    table = tabular_q.QTable(3, 3)
    table.rows(np.array([7, 9]))
    table.save(str(folder / "table.npz"))


def path_value(cli: str, field: str, case: str, folder: Path):
    """The path a case gives `field` (a tuple for the maps fields)."""
    read = INPUTS.get((cli, field))
    if read:
        valid = ROOT / read[0] if read[0].startswith(("models/", "maps/")) else folder / read[0]
        suffix = valid.suffix
    else:
        suffix = OUTPUTS[cli, field]
    path = folder / f"{case}{suffix}"
    if case == "empty":
        path.write_bytes(b"")
    elif case == "binary":
        path.write_bytes(bytes(range(256)) * 8)
    elif case == "truncated":
        data = valid.read_bytes()
        path.write_bytes(data[:len(data) // 2])
    elif case == "folder":
        path.mkdir()
    elif case == "guarded":  # read: a committed file of another kind; written: a new file in maps/
        path = ROOT / "results" / "classical_cpp.json" if read else ROOT / "maps" / f"new{suffix}"
    return (str(path),) if field == "maps" else str(path)


def outcome(cli: str, field: str, value, folder: Path, monkeypatch) -> str:
    t, base, stop = CLIS[cli]
    monkeypatch.chdir(folder)
    files(folder)
    for name, stub in stop(t).items():  # the trainers lock their run folder through gridworld
        monkeypatch.setattr(t if hasattr(t, name) else gw, name, stub)
    flags = dict(base)
    if isinstance(value, str):
        flags.update(INPUTS.get((cli, field), ("", {}))[1])
        value = path_value(cli, field, value, folder)
    try:
        t.main(t.Args(**{**flags, field: value}))
    except Accepted:
        return "accepted"
    except ValueError as e:
        assert str(e) and "\n" not in str(e), f"a ValueError of {len(str(e).splitlines())} lines: {e}"
        return "clean error"
    except BaseException as e:  # noqa: BLE001 (a traceback is the finding)
        return f"traceback: {type(e).__name__}: {str(e)[:200]}"
    return "ran"


def git_status() -> str:
    return subprocess.run(["git", "status", "--porcelain", "--untracked-files=all"], cwd=ROOT, capture_output=True,
                          text=True, check=True).stdout


@pytest.fixture(scope="module", autouse=True)
def repo_untouched():
    before = git_status()
    yield
    assert git_status() == before


def todays_share(params: list) -> list:
    """A third of the cases, a different third each day (CI's budget); SWEEP_SHARDS=1 runs them all."""
    shards = int(os.environ.get("SWEEP_SHARDS", "3"))
    today = datetime.date.today().toordinal() % shards
    return [p for p in params if zlib.crc32(p.id.encode()) % shards == today]


@pytest.mark.parametrize("cli, field, value", todays_share(list(cases())))
def test_bad_input_is_refused_in_one_line_or_accepted(cli, field, value, tmp_path, monkeypatch):
    result = outcome(cli, field, value, tmp_path, monkeypatch)
    assert not result.startswith("traceback"), result
    if isinstance(value, str) and (cli, field, value) not in FINE or isinstance(value, float) and not math.isfinite(value):
        assert result == "clean error", f"{value} accepted"  # a bad file, nan, inf: never taken as if it were fine


@pytest.mark.parametrize("t", [rainbow_cpp, rainbow_marl])
@pytest.mark.parametrize("channels, hint", [(None, False), (15, True)])
def test_the_replay_memory_estimate_is_what_it_allocates(t, channels, hint):
    r = t.Replay(64, 4, 11, 2, 3, 0.9, 0.5, channels, hint)
    arrays = [r.frames, r.oob, r.last, r.battery, r.action, r.label, r.reward, r.terminal, r.final, r.age]
    assert r.bytes_per_transition() == sum(a.nbytes for a in arrays + [r.hint] * hint) // 64 + 16
    with pytest.raises(ValueError, match=r"^--buffer-size 1,000,000,000,000: the replay memory needs [\d,.]+ GiB, this"):
        t.Replay(10**12, 4, 11, 2, 3, 0.9, 0.5, channels, hint)


def test_the_worlds_memory_is_checked_before_allocating():
    core = gw.GridWorldCore(dict(size=20), 8)
    core.reset()
    owned = sum(v.nbytes for v in vars(core).values() if isinstance(v, np.ndarray) and v.base is None)
    assert gw.CANVAS_BYTES <= owned / (8 * core.Ph * core.Pw) < gw.CANVAS_BYTES + 0.5  # the estimate is what it holds
    with pytest.raises(ValueError, match=r"^the canvas of 1,000,000,000,000 worlds of 46x46 cells needs [\d,.]+ GiB, this"):
        gw.GridWorldCore(dict(size=6), HUGE_INT)


def test_the_sweep_covers_every_cli_and_its_paths():
    assert {cli for cli, *_ in (p.values for p in cases())} == set(CLIS)
    assert {"learning_rate", "total_steps", "buffer_size", "curve_every"} <= {n for n, _ in numeric_fields(rainbow_cpp)}
    for cli, (t, _, _) in CLIS.items():
        paths = {f.name for f in dataclasses.fields(t.Args) if f.name in ("init_from", "stages", "export", "out",
                                                                          "checkpoint", "dataset", "maps", "starts",
                                                                          "video", "table_path", "init_table")}
        assert paths == {f for c, f in [*INPUTS, *OUTPUTS] if c == cli}, cli


if __name__ == "__main__":
    import signal
    import tempfile
    import time

    class Hung(BaseException):
        pass

    def hung(*_):
        raise Hung

    counts, slow = Counter(), []

    class Patch:
        def __init__(self):
            self.undo = []

        def chdir(self, path):
            self.undo.append((os, "chdir", os.getcwd()))
            os.chdir(path)

        def setattr(self, obj, name, value):
            self.undo.append((obj, name, getattr(obj, name)))
            setattr(obj, name, value)

    for param in cases():
        cli, field, value = param.values
        folder = Path(tempfile.mkdtemp())
        patch, start = Patch(), time.perf_counter()
        signal.signal(signal.SIGALRM, hung)
        signal.alarm(30)
        try:
            result = outcome(cli, field, value, folder, patch)
        except AssertionError as e:
            result = f"traceback: {e}"
        except Hung:
            result = "hang: over 30 s"
        finally:
            signal.alarm(0)
            for obj, name, old in reversed(patch.undo):
                os.chdir(old) if name == "chdir" else setattr(obj, name, old)
            shutil.rmtree(folder, ignore_errors=True)
        must_refuse = isinstance(value, str) and (cli, field, value) not in FINE or isinstance(value, float) and not \
            math.isfinite(value)
        counts["wrong success" if must_refuse and result == "accepted" else result.split(":")[0]] += 1
        if time.perf_counter() - start > 2:
            slow.append(f"{cli} --{field.replace('_', '-')} {value}: {time.perf_counter() - start:.0f} s")
            print("slow:", slow[-1], flush=True)
        if result.startswith("traceback"):
            print(f"{cli} --{field.replace('_', '-')} {value}: {result}")
    print(f"tried {sum(counts.values())}: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
    print("slower than 2 s:", *slow, sep="\n  ")
