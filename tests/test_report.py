"""report.py: collect -> JSON, render (pure) -> RESULTS.md, plot -> PNG; --out honoured everywhere, nothing
half-written, provenance from the JSON, bad input a one-line error.

Collecting runs on a few small maps (the report's subsets monkeypatched) with tiny untrained models, so that
every part runs in seconds; rendering and plotting run on the committed results/*.json.
"""
from __future__ import annotations

import ast
import dataclasses
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from conftest import one_line_error as _one_line_error  # noqa: E402

import classical_cpp as cc  # noqa: E402
import evaluate  # noqa: E402
import gridworld as gw  # noqa: E402
import report  # noqa: E402

RESULTS = ROOT / "results"


def _hashes(folder: Path) -> dict:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _committed() -> dict:
    return report.load_results(str(RESULTS))


def _table_rows(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.startswith("| ")]


def _copy_results(tmp_path: Path) -> Path:
    out = tmp_path / "results"
    shutil.copytree(RESULTS, out)
    return out


WITH_ITS_PART = ("sensors", "td_finetune")  # figures drawn only once their part is collected


def _drawn(results: dict) -> list[str]:
    """The figures `results` give: each but those of WITH_ITS_PART whose part is not collected."""
    return [f for key, f in report.FIGURES.items() if key not in WITH_ITS_PART or results[key] is not None]


def _leftovers(folder: Path) -> list[str]:
    return [p.name for p in folder.iterdir() if p.name.startswith(".report-") or ".tmp-" in p.name]


def _cli(script: str, *args, timeout=120):
    return subprocess.run([sys.executable, script, *args], cwd=ROOT, capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, "OMP_NUM_THREADS": "1"})


# ----------------------------------------------------------------------------- render: pure, from the JSON
def test_render_keeps_every_table_row_of_the_committed_results_md():
    results = _committed()
    text = report.render(results)
    committed = (RESULTS / "RESULTS.md").read_text()
    rewards = committed[committed.index("| reward |"):].split("\n\n")[0] if "| reward |" in committed else ""
    lost = set(_table_rows(committed)) - set(_table_rows(text)) - set(_table_rows(rewards))  # rewards: + a column
    assert not lost, sorted(lost)[:5]
    headings = [ln for ln in committed.splitlines() if ln.startswith("## ")]
    assert all(h in text.splitlines() for h in headings)
    for figure in report.FIGURES.values():  # a figure of WITH_ITS_PART comes with its part
        assert (f"({figure})" in text) == (figure in _drawn(results))


def test_render_is_a_pure_function_of_the_json(monkeypatch):
    results = _committed()
    first = report.render(results)

    def forbidden(*a, **k):
        raise AssertionError("render must not run anything, read the clock or ask git")

    monkeypatch.setattr(report.subprocess, "run", forbidden)
    monkeypatch.setattr(report.time, "time", forbidden)
    monkeypatch.setattr(report, "datetime", None)
    monkeypatch.setattr(report.classical_cpp, "compare", forbidden)
    monkeypatch.setattr(report, "open", forbidden, raising=False)
    assert report.render(results) == first
    assert report.render(json.loads(json.dumps(results))) == first  # the same JSON, the same text


def test_render_types_no_provenance_by_hand():
    text = report.render(_committed())
    for typed in ("issue #", "on a 2-core CPU machine", "one core of a 2-core CPU", "evaluate.py report",
                  "15,000 steps each", "K = 0.25", "no camera stages trained"):
        assert typed not in text
    # a results JSON from before provenance was recorded: every cell of its row says so
    results = _committed()
    results["classical"].pop("provenance")
    rows = [r for r in _table_rows(report.render(results)) if r.startswith("| `classical_cpp.json` |")]
    assert len(rows) == 1 and rows[0].count("not recorded") == 7


def test_lower_bound_column_and_the_sizes_no_walk_meets_the_target():
    results = _committed()
    sizes = list(results["rainbow_cpp"]["full"])
    results["rainbow_cpp"]["lower_bound"] = {z: 0.0577 if z == "5" else 0.01 for z in sizes}
    text = report.render(results)
    lines = text.splitlines()
    header = next(i for i, ln in enumerate(lines) if ln.startswith("| size | rainbow + heuristic |"))
    assert lines[header].endswith("| lower bound |")
    assert lines[header + 2].startswith("| 5 |") and lines[header + 2].endswith("| 0.058 |")
    assert "At 5x5 no walk meets 0.05 on these maps: the lower bound is 0.058." in text
    assert "At 6x6" not in text
    results["rainbow_cpp"].pop("lower_bound")  # a JSON from before the bound: no column, no sentence
    assert "lower bound is" not in report.render(results).split("## ")[3]


def test_provenance_and_model_keys_are_read_back():
    results = _committed()
    results["classical"]["provenance"] = {"git_commit": "abcdef0123456789", "git_dirty": True, "cpu": "Test CPU 9000",
                                          "cores": 7, "torch_threads": None, "date": "2030-01-02T03:04:05+00:00",
                                          "wall_seconds": 1234.4, "flags": {"per_size": 3, "reuse": False,
                                                                           "parts": ["classical"]}}
    model = results["rainbow_marl"]["model"]
    model["provenance"] = {"git_commit": "1234567deadbeef", "git_dirty": False, "cpu": "Trainer CPU", "cores": 3,
                           "torch_threads": 2, "date": "2029-05-06T00:00:00+00:00", "wall_seconds": 600.0}
    model["parent"] = {"path": "models/rainbow_cpp.pt", "sha256": "0123456789abcdef" * 4, "global_step": 42000,
                       "stage": "n2", "provenance": {"git_commit": "feedfacecafe", "git_dirty": False},
                       "parent": {"path": "runs/first/rainbow_cpp.pt", "global_step": 7}}
    model["init_from_note"] = "a note of an older trainer"
    text = report.render(results)
    row = next(r for r in _table_rows(text) if r.startswith("| `classical_cpp.json`"))
    assert row == ("| `classical_cpp.json` | 2030-01-02T03:04:05+00:00 | abcdef0 (with uncommitted changes) | "
                   "Test CPU 9000 | 7 | not recorded | 1,234 s | `--per-size 3 --no-reuse --parts classical` |")
    assert ("Trained on machine: Trainer CPU (3 cores); torch threads: 2; git commit: 1234567; "
            "date: 2029-05-06T00:00:00+00:00. Parent: `models/rainbow_cpp.pt` (sha256 0123456789ab, 42,000 steps, "
            "last stage n2, git commit feedfac) ← `runs/first/rainbow_cpp.pt` (7 steps, git commit not recorded). "
            "Training: a note of an older trainer.") in text  # then the trainer's note, from the same JSON
    tabular = results["tabular"]["model"]
    tabular.update(git_commit="89abcdef01", git_dirty=False, cpu="Table CPU", cores=5, date="2028-01-01")
    assert ("Trained on machine: Table CPU (5 cores); git commit: 89abcde; date: 2028-01-01. Greedy on"
            in report.render(results))  # tabular_q keeps them at the top level, and has no torch
    assert "10 min of training" in text  # the trainer's wall time first


def test_reference_numbers_come_from_the_one_constant():
    results = _committed()
    text = report.render(results)
    mr = results["rainbow_marl"]["agents"]
    for n, target in report.REFERENCE["rainbow_marl_time_save"].items():
        verdict = "met" if mr[n]["time_save"] <= target else "not met"
        assert f"N = {n}: {mr[n]['time_save']:.3f} against ≤ {target} ({verdict})" in text
    seconds = report.REFERENCE["table_5_1_seconds"]["watkins"]
    assert f"| watkins | 125 / {seconds[0]} | 126 / {seconds[1]} |" in text
    changed = json.loads(json.dumps(results))
    old = report.REFERENCE["rainbow_cpp_overlap"]
    report.REFERENCE["rainbow_cpp_overlap"] = 0.04
    try:
        assert "mean overlap ≤ 0.04 at" in report.render(changed)
    finally:
        report.REFERENCE["rainbow_cpp_overlap"] = old


def test_missing_learned_parts_say_not_collected():
    results = _committed()
    results["rainbow_cpp"] = results["rainbow_marl"] = results["tabular"] = results["sensors"] = None
    text = report.render(results)
    structured = "structured_eval" not in report.planners(results)  # "Not collected" too while it is missing
    team, td = results["team_rollout"] is None, results["td_finetune"] is None  # "Not collected" too while missing
    assert text.count("*Not collected:*") == 3 + 1 + 1 + structured + team + 1 + td  # rainbow's 3, marl's, 5.5, sensors
    assert "`python report.py collect --parts rainbow_marl`" in text
    assert "**Fig. 5.4**" in text  # the training runs are there all the same


# ----------------------------------------------------------------------------- structured_eval and rollout
def _structured(overlap: dict) -> dict:
    """A planners_structured.json: per planner the mean overlap of each family (rooms, corridors, clutter, maze)."""
    families = list(gw.STRUCTURED_FAMILIES)

    def entry(o, ms):
        return {"overlap": o, "completion": 1.0, "plan_ms_per_map": ms, "by_band": {"10-15": o, "16-20": o}}

    return {"structured_eval": {"per_band": 3, "bands": [[10, 15], [16, 20]], "lkh_time_limit_s": 10.0,
                                "maps": dict.fromkeys(families, 6), "planners": {
        name: {**{f: entry(v, 1.0) for f, v in zip(families, o)}, "all": entry(round(float(np.mean(o)), 4), 1.0)}
        for name, o in overlap.items()}}}


STRUCTURED = _structured({"greedy": [0.2, 0.1, 0.3, 0.6], "wavefront": [0.15, 0.0, 0.2, 0.5],
                          "rollout": [0.1, 0.0, 0.25, 0.45], "lkh": [0.05, 0.0, 0.02, 0.21]})


def _with_new_parts(results: dict, structured: dict = STRUCTURED) -> dict:
    """`results` with a planners_structured.json and a rollout.json (rollout: half greedy's overlap everywhere)."""
    results = json.loads(json.dumps(results))
    c = results["classical"]
    results["structured"] = json.loads(json.dumps(structured))
    results["rollout"] = {"per_size": c["per_size"], "planners": ["rollout"], "cpp_eval": {"rollout": {
        k: v if k == "plan_ms_per_map" else round(v / 2, 4) for k, v in c["cpp_eval"]["greedy"].items()}},
        "external": {m: {"rollout": [x / 2 for x in per["greedy"]]} for m, per in c["external"].items()}}
    results["paths"].update(structured="x/planners_structured.json", rollout="x/rollout.json")
    return results


def _without_new_parts(results: dict) -> dict:
    results = json.loads(json.dumps(results))
    results["structured"] = results["rollout"] = results["team_rollout"] = None
    if results["rainbow_cpp"] is not None:
        results["rainbow_cpp"].pop("structured_eval", None)
    results["classical"].pop("structured_eval", None)
    for per in (results["classical"]["cpp_eval"], *results["classical"]["external"].values()):
        per.pop("rollout", None)
    return results


def test_headline_is_unchanged_without_the_new_parts():
    old = _without_new_parts(_committed())
    lines = report.headline(old)
    assert lines[0].startswith("| mean overlap $O_v$ (lower is better) | cpp_eval (20 maps a size, 5-30) | "
                               "MovingAI (9 maps, 3 starts each) |\n|---|---|---|\n")
    assert "structured_eval" not in "\n".join(lines) and "| rollout |" not in "\n".join(lines)
    # what the headline was before the new parts: the same rows from classical_cpp.json alone
    legacy = {k: v for k, v in old.items() if k not in ("structured", "rollout")}
    assert report.headline(legacy) == lines
    with_rollout = _with_new_parts(old)
    with_rollout["structured"] = None
    assert report.headline(with_rollout) == lines  # rollout.json alone leaves the headline as it was


def test_headline_gets_a_structured_column_when_there_is_one():
    results = _with_new_parts(_without_new_parts(_committed()))
    table = report.headline(results)[0].splitlines()
    assert table[0].endswith("| structured_eval (24 maps, 4 families) |") and table[1] == "|---|---|---|---|"
    rows = {r.split(" | ")[0][2:]: r for r in table[2:]}
    assert rows["rainbow_cpp (shipped, + heuristic fallback)"].endswith(" | — |")  # not evaluated there
    assert rows["greedy-dead-ends"].endswith("| — | — |")  # not in this structured_eval
    assert "greedy-far-first (its teacher)" in rows  # the committed model takes far-first ties
    assert rows["greedy"].endswith(" | 0.300 |") and rows["lkh"].endswith(" | 0.070 |")
    assert list(rows)[-2:] == ["rollout", "lkh"] and rows["rollout"].endswith(" | 0.200 |")
    greedy = results["classical"]["cpp_eval"]["greedy"]["all"]
    assert rows["rollout"].startswith(f"| rollout | {round(greedy / 2, 4):.3f} |")
    results["rainbow_cpp"]["structured_eval"] = {"all": {"overlap": 0.1234}}
    assert report.headline(results)[0].splitlines()[2].endswith(" | 0.123 |")


def test_structured_table_and_rollouts_gap_to_lkh_are_generated_from_the_numbers():
    text = report.render(_with_new_parts(_without_new_parts(_committed())))
    section = text[text.index("## Structured maps (planners)"):text.index("## Sensor-based")]
    assert "| planner | rooms | corridors | clutter | maze | all | completed | plan ms/map |" in section
    assert "| rollout | 0.100 | 0.000 | 0.250 | 0.450 | 0.200 | 100% | 1.0 |" in section
    assert ("Rollout is below every other planner but LKH (greedy, wavefront) in 2 of 4 families; tied in corridors "
            "(wavefront also 0.000); above in clutter (wavefront 0.200 against 0.250); completion 100% in every "
            "family.") in section
    assert ("Rollout's gap to LKH (mean overlap, rollout − LKH): rooms +0.050 (0.100 against 0.050, 2.0×); "
            "corridors +0.000 (0.000 against 0.000); clutter +0.230 (0.250 against 0.020, 12.5×); maze +0.240 "
            "(0.450 against 0.210, 2.1×); all maps +0.130. Largest in maze, smallest in corridors.") in section
    assert "| planner | 10-15 | 16-20 | all |" in section and "| lkh | 0.070 | 0.070 | 0.070 |" in section
    assert f"({report.FIGURES['planners_structured']})" in section
    comparison = text[text.index("## Comparison with classical"):]
    assert "| rollout | " in comparison and "rollout: from `rollout.json`" in comparison
    assert "| map | greedy | boustrophedon | spiral-stc | wavefront | rollout | lkh |" in comparison
    bare = report.render(_without_new_parts(_committed()))
    assert "*Not collected:* no `structured_eval`" in bare and "| rollout |" not in bare


def test_classical_cpp_json_wins_over_the_separate_files():
    results = _with_new_parts(_committed())
    c = results["classical"]
    c["structured_eval"] = _structured({"greedy": [0.5, 0.5, 0.5, 0.5]})["structured_eval"]
    c["cpp_eval"]["rollout"] = dict(c["cpp_eval"]["lkh"])
    for per in c["external"].values():
        per["rollout"] = list(per["lkh"])
    merged = report.planners(results)
    assert merged["structured_eval"] == c["structured_eval"] and merged["cpp_eval"]["rollout"] == c["cpp_eval"]["lkh"]
    assert "filled_in" not in merged and "filled_in" not in c  # nothing taken from rollout.json; results untouched
    filled = report.planners(_with_new_parts(_without_new_parts(_committed())))
    assert list(filled["cpp_eval"])[-2:] == ["rollout", "lkh"] and filled["filled_in"]["planners"] == ["rollout"]


def test_render_with_the_new_parts_is_pure_and_they_plot(tmp_path, monkeypatch):
    results = _with_new_parts(_without_new_parts(_committed()))
    before = json.dumps(results)
    first = report.render(results)
    assert json.dumps(results) == before  # render reads, never edits, the results

    def forbidden(*a, **k):
        raise AssertionError("render must not run anything, read the clock or ask git")

    for name in ("compare", "compare_structured", "compare_rollout"):
        monkeypatch.setattr(report.classical_cpp, name, forbidden)
    monkeypatch.setattr(report.time, "time", forbidden)
    monkeypatch.setattr(report, "open", forbidden, raising=False)
    assert report.render(json.loads(before)) == first
    monkeypatch.undo()
    written = report.plot(results, str(tmp_path))
    assert str(tmp_path / report.FIGURES["planners_structured"]) in written
    assert (tmp_path / report.FIGURES["planners_structured"]).stat().st_size > 10_000
    bare = tmp_path / "bare"
    bare.mkdir()
    assert not any("planners_structured" in w for w in report.plot(_without_new_parts(_committed()), str(bare)))


def test_bad_new_part_json_is_a_value_error_naming_it(tmp_path):
    results = _with_new_parts(_without_new_parts(_committed()))
    del results["rollout"]["external"]
    with pytest.raises(ValueError, match=re.escape("x/rollout.json") + ".*KeyError: 'external'"):
        report.render(results)
    results = _with_new_parts(_without_new_parts(_committed()))
    del results["structured"]["structured_eval"]["maps"]
    with pytest.raises(ValueError, match=re.escape("x/planners_structured.json") + ".*KeyError: 'maps'"):
        report.render(results)


def test_structured_and_rollout_parts_are_collected_with_classical(tmp_path, capsys):
    parts = report.parts_to_collect(report.Collect(out=str(tmp_path), parts=("structured", "classical", "rollout")))
    assert parts == ["classical"] and "structured: collected with classical" in capsys.readouterr().out
    c = _without_new_parts(_committed())["classical"]
    (tmp_path / "classical_cpp.json").write_text(json.dumps(c))
    reuse = report.Collect(out=str(tmp_path), parts=("classical", "structured", "rollout"), reuse=True)
    assert report.parts_to_collect(reuse) == ["structured", "rollout"]  # classical is there, without them
    c["structured_eval"] = {}
    c["cpp_eval"]["rollout"] = {}
    (tmp_path / "classical_cpp.json").write_text(json.dumps(c))
    assert report.parts_to_collect(reuse) == []


def test_a_part_whose_json_is_there_needs_overwrite(tmp_path):
    """Collecting into a folder that holds a part's JSON (the committed results/ by default) is an error before
    anything runs, unless --overwrite replaces it or --reuse keeps it."""
    (tmp_path / "tabular").mkdir()
    for rel in ("rollout.json", os.path.join("tabular", "fig5_5.json")):
        (tmp_path / rel).write_text("{}")
    args = report.Collect(out=str(tmp_path), parts=("tabular", "team_rollout", "rollout"))
    with pytest.raises(ValueError, match=f"^--out {tmp_path} already holds tabular/fig5_5.json, rollout.json: "
                                         "--overwrite replaces them, --reuse keeps them, or give another --out$"):
        report.parts_to_collect(args)
    with pytest.raises(ValueError, match="holds rollout.json: --overwrite replaces it, --reuse keeps it"):
        report.main(dataclasses.replace(args, parts=("rollout",)))
    assert (tmp_path / "rollout.json").read_text() == "{}" and sorted(p.name for p in tmp_path.iterdir()) == [
        "rollout.json", "tabular"]
    assert report.parts_to_collect(dataclasses.replace(args, overwrite=True)) == ["tabular", "team_rollout", "rollout"]
    assert report.parts_to_collect(dataclasses.replace(args, reuse=True)) == ["team_rollout"]


def test_collect_structured_and_rollout_on_tiny_maps(tmp_path, small_report_maps):
    small_report_maps(7, 1, structured=1)
    out = tmp_path / "new"
    written = report.main(report.Collect(out=str(out), parts=("structured", "rollout"), per_size=1, quiet=True))
    assert written == ["planners_structured.json", "rollout.json"]
    st = json.loads((out / "planners_structured.json").read_text())
    assert st["structured_eval"]["maps"] == dict.fromkeys(gw.STRUCTURED_FAMILIES, 1)
    assert list(st["structured_eval"]["planners"]) == list(cc.STRUCTURED_PLANNERS)
    assert st["provenance"]["flags"]["structured_per_band"] == cc.STRUCTURED_PER_BAND
    ro = json.loads((out / "rollout.json").read_text())
    assert list(ro["cpp_eval"]) == ["rollout"] and ro["external"] == {"empty-8-8.map": {"rollout": [0.0, 0.0]}}
    text = "\n".join(report.structured_lines(st["structured_eval"]))
    assert "\n| rollout | " in text and "Rollout's gap to LKH" in text


def test_collect_team_rollout_on_tiny_maps(tmp_path, small_report_maps):
    small_report_maps(7, 2, structured=1)
    out = tmp_path / "team"
    assert report.main(report.Collect(out=str(out), parts=("team_rollout",), quiet=True)) == ["team_rollout.json"]
    t = json.loads((out / "team_rollout.json").read_text())
    assert list(t["marl_eval"]) == [str(n) for n in cc.TEAM_AGENTS] and list(t["structured_eval"]) == ["5"]
    for e in [*t["marl_eval"].values(), *t["structured_eval"].values()]:
        ts = {name: e[name]["time_save"] for name in cc.TEAM_PLANNERS}
        assert e["rollout_longer_than_base"] == 0
        assert e["lower_bound_time_save"] <= ts["rollout"] <= ts["greedy-dead-ends"] + 1e-9
    assert t["provenance"]["flags"]["parts"] == ["team_rollout"]
    rows = _table_rows("\n".join(report.team_rollout_lines(t)))
    assert len(rows) == 1 + len(cc.TEAM_AGENTS) + 1 and rows[1].startswith("| marl_eval | 2 | 2 | ")
    results = report.load_results(str(out), str(RESULTS))
    assert results["paths"]["team_rollout"] == str(out / "team_rollout.json")
    assert "The multiagent rollout planner" in report.render(results)


def test_team_rollout_missing_says_how_to_collect_it():
    assert "`python report.py collect --parts team_rollout`" in report.team_rollout_lines(None)[0]


# ----------------------------------------------------------------------------- render / plot commands
def test_render_and_plot_write_into_out_only(tmp_path):
    committed = _hashes(RESULTS)
    out = _copy_results(tmp_path)
    (out / "RESULTS.md").unlink()
    for figure in report.FIGURES.values():
        (out / figure).unlink(missing_ok=True)
    assert report.main(report.Render(out=str(out))) == ["RESULTS.md"]
    assert (out / "RESULTS.md").read_text() == report.render(_committed())
    written = report.main(report.Plot(out=str(out)))
    assert sorted(written) == sorted(_drawn(_committed()))
    for figure in written:
        assert (out / figure).stat().st_size > 10_000
    assert _hashes(RESULTS) == committed and not _leftovers(tmp_path)


def test_all_with_reuse_runs_nothing_when_every_json_is_there(tmp_path, monkeypatch):
    out = _copy_results(tmp_path)

    def forbidden(*a, **k):
        raise AssertionError("--reuse must not re-run a part whose JSON is there")

    for name in ("compare", "compare_structured", "compare_rollout", "compare_team_rollout"):
        monkeypatch.setattr(cc, name, forbidden)
    for name in ("rainbow_results", "sensor_results", "marl_results", "tabular_results", "td_finetune_results"):
        monkeypatch.setattr(report, name, forbidden)
    monkeypatch.setitem(report.MODELS, "td_finetune", str(tmp_path / "nothing.pt"))  # skipped while not collected
    jsons = {k: v for k, v in _hashes(out).items() if k.endswith(".json")}
    written = report.main(report.All(out=str(out), reuse=True, quiet=True))
    assert written == sorted(["RESULTS.md", *_drawn(_committed())])
    assert {k: v for k, v in _hashes(out).items() if k.endswith(".json")} == jsons


def test_a_part_whose_model_is_not_trained_is_skipped(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(report.MODELS, "rainbow_marl", str(tmp_path / "nothing.pt"))
    args = report.Collect(out=str(tmp_path), parts=("rainbow_marl", "classical", "rainbow_marl"))
    assert report.parts_to_collect(args) == ["classical"]
    assert "rainbow_marl: skipped" in capsys.readouterr().out
    shutil.copy(RESULTS / "classical_cpp.json", tmp_path / "classical_cpp.json")
    scale = ["rainbow_cpp_scale", "scale_figures"] if (ROOT / report.MODELS["rainbow_cpp_scale"]).exists() else []
    td = ["td_finetune"] if (ROOT / report.MODELS["td_finetune"]).exists() else []
    assert report.parts_to_collect(report.Collect(out=str(tmp_path), reuse=True)) == [
        "team_rollout", "sensors", "rainbow_cpp", "tabular", "scale_references", *scale, *td]  # classical_cpp.json alone


# ----------------------------------------------------------------------------- collect, on tiny settings
def _tiny_model(module, path: Path, extra: dict) -> str:
    """An untrained export of `module`'s network (hidden 16) and the JSON a trainer writes beside it."""
    q = module.QNetwork(3, module.VIEW, 16, 0.5)
    gw.save_torch(str(path), {"weights": {k: v.half() for k, v in q.state_dict().items()
                                                   if "sigma" not in k and "eps" not in k}, "frames": 3, "hidden": 16})
    path.with_suffix(".json").write_text(json.dumps({"args": {"hidden": 16, "init_from": None, **extra},
                                                     "global_step": 10, "stage": "tiny", "wall_seconds": 60.0}))
    return str(path)


@pytest.fixture
def tiny(tmp_path, monkeypatch, small_report_maps):
    """The report's map subsets cut to a few small maps, and tiny models in place of the committed ones."""
    import rainbow_cpp
    import rainbow_marl
    import tabular_q
    small_report_maps(7, 2)
    monkeypatch.setattr(report, "MARL_AGENTS", range(1, 3))
    monkeypatch.setattr(report, "MARL_STRUCTURED_EVERY", 840)  # 2 of structured_eval's 1,680 maps
    monkeypatch.setattr(report, "MARL_STRUCTURED_AGENTS", range(2, 4))
    ch5 = np.load(ROOT / "maps" / "ch5_eval.npz")
    keep = np.flatnonzero((ch5["size"] <= 6) & (ch5["requested_obstacles"] <= 2))[::25]
    scenarios = gw.load_dataset(str(ROOT / "maps" / "ch5_eval.npz"))
    gw.save_dataset(str(tmp_path / "ch5.npz"), [scenarios[i] for i in keep], size=ch5["size"][keep],
                    requested_obstacles=ch5["requested_obstacles"][keep])
    monkeypatch.setattr(report, "CH5_EVAL", str(tmp_path / "ch5.npz"))
    models = tmp_path / "models"
    models.mkdir()
    table = models / "tabular_q.npz"
    tabular_q.QTable(3, 3).save(str(table))
    table.with_suffix(".json").write_text(json.dumps({
        "args": {"algorithm": "q-learning", "min_size": 4, "size": 6, "number_obstacles": 2, "obstacles_random": True,
                 "corner_starts": False}, "episodes": 5, "states": 0, "wall_seconds": 1.0, "episodes_per_second": 5.0,
        "machine": "a test machine", "curve_rho": [1.0]}))
    monkeypatch.setattr(report, "SENSOR_RANGES", (1, 3))
    rainbow = _tiny_model(rainbow_cpp, models / "rainbow_cpp.pt", {"heuristic_dead_ends": True})
    small = {name: [gw.Scenario(s.obstacles, s.starts[:1], s.covered) for s in gw.load_dataset(
        str(ROOT / "maps" / f"{name}.npz"))[:2]] for name in gw.CURVE_SLICES}
    monkeypatch.setattr(gw, "curve_maps", lambda: small)
    monkeypatch.setattr(report, "FIGURES_PER_SIZE", 2)
    scale_run = _tiny_scale_checkpoint(rainbow_cpp, models / "run.pt")
    monkeypatch.setattr(report, "FRESH_PER_SIZE", 1)
    monkeypatch.setattr(report, "FRESH_SIZES", range(10, 11))
    structured = report.structured_eval_episodes
    monkeypatch.setattr(report, "structured_eval_episodes", lambda: tuple(x[::420] for x in structured()))  # 1 a family
    monkeypatch.setattr(report, "MODELS", {
        "rainbow_cpp": rainbow, "sensors": rainbow,
        "rainbow_marl": _tiny_model(rainbow_marl, models / "rainbow_marl.pt", {}), "tabular": str(table),
        "scale_references": rainbow, "rainbow_cpp_scale": scale_run,
        "scale_figures": _tiny_model(rainbow_cpp, models / "rainbow_cpp_dissertation.pt", {}),  # an export
        "td_finetune": _tiny_finetune_checkpoint(scale_run, models / "td_run.pt", rainbow)})
    return tmp_path


def _tiny_scale_checkpoint(module, path: Path) -> str:
    """A training checkpoint as the scale run writes it, with one learning-curve point."""
    import torch
    q = module.build_network({"network": "compact", "frames": 3, "hidden": 16, "conv_width": 8, "scales": 3,
                              "scale_factor": 3, "scale_view": 11}, 0.5)
    row = {"maps": 2, "overlap": 0.1, "completion": 1.0, "outliers": 0}
    point = {"step": 1000, "stage": "fi1", "wall_seconds": 5, "sps": 300, "peak_rss_mb": 500, "eval_seconds": 1,
             "cpp_eval": {**row, "fallback_share": 0.0, "overlap_by_size": {"5": 0.1}},
             "cpp_eval_alone": {**row, "overlap_by_size": {"5": 0.1}},
             "structured_eval": {**row, "fallback_share": 0.0}, "structured_eval_alone": row}
    args = dataclasses.asdict(module.Args(network="compact", learning_rate=5e-4, stage_steps_scale=0.333,
                                          camera_stages=False, heuristic_dead_ends=False, heuristic_random_ties=True))
    gw.save_torch(str(path), {"model": q.state_dict(), "optimizer": {}, "global_step": 1000, "stage": 0,
                                       "wall": 5.0, "numpy_rng": {}, "torch_rng": torch.get_rng_state(), "args": args,
                                       "script": "rainbow_cpp", "curve": [point], **q.network()})
    return str(path)


def _tiny_finetune_checkpoint(run: str, path: Path, shipped: str) -> str:
    """The tiny scale run's checkpoint as a warm-started run writes it: with its parent's record."""
    parent = {"path": shipped, "sha256": hashlib.sha256(Path(shipped).read_bytes()).hexdigest(), "global_step": 10,
              "stage": "tiny", "provenance": {"git_commit": "abc"}}
    gw.save_torch(str(path), {**gw.load_checkpoint(run, "rainbow_cpp"), "parent": parent})
    return str(path)


def test_all_on_tiny_settings_writes_into_out_only(tiny):
    committed = _hashes(RESULTS)
    out = tiny / "report"
    written = report.main(report.All(out=str(out), per_size=1, p2p_maps=2, quiet=True))
    assert _hashes(RESULTS) == committed  # `--out DIR` never touches the committed results
    jsons = sorted(f for part, f in report.PARTS.items() if part not in report.IN_CLASSICAL)  # those: in classical
    assert written == sorted(["RESULTS.md", *jsons, *[f for k, f in report.FIGURES.items() if k != "fig5_4"]])
    assert not _leftovers(tiny) and not _leftovers(out)
    commit = report._git("rev-parse", "HEAD")
    for rel in jsons:
        data = json.loads((out / rel).read_text())
        p = data["provenance"]
        assert p["git_commit"] == commit and p["cores"] == os.cpu_count() and p["cpu"] == report._cpu()
        assert p["wall_seconds"] >= 0 and re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\+00:00", p["date"])
        assert p["flags"] == {"parts": list(report.PARTS), "reuse": False, "per_size": 1, "p2p_maps": 2,
                              "structured_per_band": cc.STRUCTURED_PER_BAND}
    classical = json.loads((out / "classical_cpp.json").read_text())
    assert list(classical["cpp_eval"]["greedy"]) == ["plan_ms_per_map", "all", "5-6", "7-7"]
    assert classical["structured_eval"]["maps"] == dict.fromkeys(gw.STRUCTURED_FAMILIES, 1)  # the fixture's
    rb = json.loads((out / "rainbow_cpp.json").read_text())
    assert sorted(rb["full"], key=int) == ["5", "6", "7"] and rb["p2p"]["maps"] == 2 and rb["model"]["stage"] == "tiny"
    assert all(v["completion"] == 1.0 for v in rb["full"].values())  # the heuristic finishes what the net cannot
    assert list(rb["lower_bound"]) == ["5", "6", "7"]
    assert all(0 <= rb["lower_bound"][z] <= rb[p][z]["overlap"] for z in rb["full"] for p in ("full", "greedy"))
    assert list(rb["structured_eval"]) == [*gw.STRUCTURED_FAMILIES, "all"]
    assert all(v["completion"] == 1.0 for v in rb["structured_eval"].values())
    sr = json.loads((out / "rainbow_sensors.json").read_text())
    keys = ["full", "camera_r1", "camera_r3", "lidar_r1", "lidar_r3", "camera_r3_failure25", "camera_r3_failure50"]
    assert list(sr["cpp_eval"]) == keys and list(sr["cpp_eval"]["full"]) == list(report.SENSOR_POLICIES)
    for name in ("cpp_eval", "structured_eval"):
        for setting in sr[name].values():
            assert all(p["completion"] == 1.0 for p in setting.values())  # the fallback finishes what the net cannot
        assert sr[name]["camera_r1"] == sr[name]["lidar_r1"]  # at K = 1 the two sensors see the same cells
    assert list(sr["structured_eval"]["full"]["frontier"]["by"]) == list(gw.STRUCTURED_FAMILIES)
    mr = json.loads((out / "rainbow_marl.json").read_text())
    assert list(mr["agents"]) == ["1", "2"] and list(mr["faulty"]) == ["2"] and mr["agents"]["2"]["maps"] == 2
    assert list(mr["agents"]["2"]) == ["maps", "time_save", "completion", "heuristic_share", "greedy", "greedy_dead_ends",
                                       "greedy_far_first", "partition", "by_size"]
    assert list(mr["structured_eval"]["agents"]) == ["2", "3"] and mr["structured_eval"]["maps"] == 2
    assert list(mr["structured_eval"]["agents"]["3"]) == ["time_save", "completion", "greedy", "greedy_dead_ends",
                                                          "greedy_far_first", "partition"]
    figs = json.loads((out / "rainbow_cpp_scale_figures.json").read_text())["model"]
    assert (figs["path"], figs["global_step"], figs["stage"]) == (  # an export's steps and stage: from its JSON
        os.path.relpath(tiny / "models" / "rainbow_cpp_dissertation.pt", ROOT), 10, "tiny")
    td = json.loads((out / "rainbow_cpp_td_finetune.json").read_text())
    assert td["curve"] == json.loads((out / "rainbow_cpp_scale.json").read_text())["curve"]
    assert td["parent"]["global_step"] == 10 and td["shipped"]["sha256"] == td["parent"]["sha256"]
    assert td["structured_eval"]["maps"] == dict.fromkeys(gw.STRUCTURED_FAMILIES, 1)
    assert td["fresh"]["maps"] == dict.fromkeys(("random", *gw.STRUCTURED_FAMILIES), 1)
    for name in ("structured_eval", "fresh"):
        assert list(td[name]) == ["maps", "fine_tuned", "fine_tuned_alone", "shipped", "shipped_alone",
                                  "greedy_far_first"]
        assert list(td[name]["shipped"]) == [*td[name]["maps"], "all"]
        for key in ("fine_tuned", "shipped", "greedy_far_first"):  # the fallback finishes what the net cannot
            assert all(v["completion"] == 1.0 for v in td[name][key].values())
    fig55 = json.loads((out / "tabular" / "fig5_5.json").read_text())
    assert {(s["size"], s["obstacles"]) for s in fig55["settings"]} == {(4, 0), (4, 2), (6, 0), (6, 2)}
    assert "curve_rho" not in fig55["model"]
    text = (out / "RESULTS.md").read_text()
    assert text == report.render(report.load_results(str(out)))
    for rel in jsons:  # the provenance table reads back what collect recorded
        p = json.loads((out / rel).read_text())["provenance"]
        row = next(r for r in _table_rows(text) if r.startswith(f"| `{rel}` |"))
        assert row.startswith(f"| `{rel}` | {p['date']} | {report._commit(p)} | {report.recorded(p['cpu'])} | {p['cores']} |")
    assert "**Fig. 5.4**" not in text and "machine: a test machine" in text


def test_a_collect_stopped_by_sigterm_leaves_no_staging_folder(tmp_path):
    """A report killed by SIGTERM (a job scheduler, `timeout`) says so in one line and removes its staging folder."""
    import signal
    import time

    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONDONTWRITEBYTECODE": "1"}
    run = subprocess.Popen([sys.executable, str(ROOT / "report.py"), "collect", "--parts", "classical", "--out",
                            str(tmp_path / "out"), "--quiet"], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                           text=True)
    deadline = time.time() + 60
    while not list(tmp_path.glob(".report-*")) and time.time() < deadline and run.poll() is None:
        time.sleep(0.1)
    assert list(tmp_path.glob(".report-*")), "the staging folder never appeared"
    run.send_signal(signal.SIGTERM)
    _, err = run.communicate(timeout=60)
    assert run.returncode != 0 and err.strip() == "error: stopped by SIGTERM; --out is as it was"
    assert list(tmp_path.iterdir()) == []


def test_a_failing_collect_leaves_out_as_it_was(tiny, monkeypatch):
    out = _copy_results(tiny)
    before = _hashes(out)

    def broken(*a, **k):
        raise ValueError("tabular broke")

    monkeypatch.setattr(report, "tabular_results", broken)
    with pytest.raises(ValueError, match="tabular broke"):  # classical ran, then tabular failed
        report.main(report.All(out=str(out), parts=("classical", "tabular"), per_size=1, quiet=True, overwrite=True))
    assert _hashes(out) == before and not _leftovers(tiny)
    with pytest.raises(ValueError, match="tabular broke"):
        report.main(report.Collect(out=str(tiny / "new" / "folder"), parts=("classical", "tabular"), quiet=True))
    assert not (tiny / "new").exists() and not _leftovers(tiny)


# ----------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("kw, message", [
    (dict(parts=("classical", "lkh")), "--parts: unknown part(s) lkh"),
    (dict(per_size=0), "--per-size must be >= 1, got 0"),
    (dict(per_size=-3), "--per-size must be >= 1"),
    (dict(p2p_maps=0), "--p2p-maps must be >= 1"),
    (dict(structured_per_band=0), "--structured-per-band must be >= 1, got 0"),
])
def test_bad_collect_flags_are_value_errors_and_write_nothing(tmp_path, kw, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        report.main(report.Collect(out=str(tmp_path / "out"), **kw))
    assert not list(tmp_path.iterdir())


def test_out_that_is_a_file_is_a_value_error(tmp_path):
    (tmp_path / "file").write_text("x")
    for command in (report.Collect, report.Render, report.Plot, report.All):
        with pytest.raises(ValueError, match="not a folder"):
            report.main(command(out=str(tmp_path / "file")))
    assert [p.name for p in tmp_path.iterdir()] == ["file"]


@pytest.mark.parametrize("content, message", [
    (b"", "not a JSON file"), (bytes(range(256)), "not a JSON file"), (b"[1, 2]", "not a JSON object"),
    (b'{"per_size": 20}', "unexpected content (KeyError: 'cpp_eval')"),
    (b'{"per_size": 20, "lkh_time_limit_s": 10, "cpp_eval": [], "external": {}, "marl_eval": {}}', "unexpected content"),
])
def test_bad_results_json_is_a_value_error_naming_it(tmp_path, content, message):
    out = _copy_results(tmp_path)
    (out / "classical_cpp.json").write_bytes(content)
    before = _hashes(out)
    for command in (report.Render, report.Plot):
        with pytest.raises(ValueError, match=re.escape(str(out / "classical_cpp.json")) + ".*" + re.escape(message)):
            report.main(command(out=str(out)))
    assert _hashes(out) == before and not _leftovers(tmp_path)


def test_bad_model_json_in_a_results_file_names_it(tmp_path):
    out = _copy_results(tmp_path)
    data = json.loads((out / "rainbow_marl.json").read_text())
    del data["model"]["global_step"]
    (out / "rainbow_marl.json").write_text(json.dumps(data))
    with pytest.raises(ValueError, match=re.escape(str(out / "rainbow_marl.json")) + ".*global_step"):
        report.main(report.Render(out=str(out)))


def test_render_without_results_is_a_value_error(tmp_path):
    with pytest.raises(ValueError, match="no classical_cpp.json; run `python report.py collect"):
        report.main(report.Render(out=str(tmp_path)))
    assert not list(tmp_path.iterdir())


# ----------------------------------------------------------------------------- the command lines
def test_cli_render_into_a_copy_matches_the_pure_render(tmp_path):
    committed = _hashes(RESULTS)
    out = _copy_results(tmp_path)
    (out / "RESULTS.md").unlink()
    r = _cli("report.py", "render", "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == f"wrote RESULTS.md into {out}"
    assert (out / "RESULTS.md").read_text() == report.render(_committed())
    assert _hashes(RESULTS) == committed


def test_cli_bad_inputs_are_one_line_errors(tmp_path):
    _one_line_error(_cli("report.py", "collect", "--parts", "nope", "--out", str(tmp_path / "a")), "--parts", "nope")
    _one_line_error(_cli("report.py", "--per-size", "0", "--out", str(tmp_path / "a")), "--per-size")
    _one_line_error(_cli("report.py", "render", "--out", str(tmp_path)), "no classical_cpp.json")
    (tmp_path / "classical_cpp.json").write_bytes(bytes(range(256)))
    _one_line_error(_cli("report.py", "plot", "--out", str(tmp_path)), str(tmp_path / "classical_cpp.json"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["classical_cpp.json"]


def test_cli_subcommands_and_help():
    r = _cli("evaluate.py", "--help")
    assert r.returncode == 0 and "--policy" in r.stdout
    r = _cli("report.py", "--help")
    assert r.returncode == 0 and "--per-size" in r.stdout and "(default: all)" in r.stdout


def test_cli_parses_subcommands_with_defaults():
    assert report.cli([]) == report.All()
    assert report.cli(["--reuse", "--per-size", "3"]) == report.All(reuse=True, per_size=3)
    assert report.cli(["collect", "--parts", "classical", "tabular"]) == report.Collect(parts=("classical", "tabular"))
    assert report.cli(["render", "--out", "x"]) == report.Render(out="x")
    assert report.cli(["plot"]) == report.Plot()


def test_evaluate_does_not_import_report(tmp_path):
    """The layers: report.py uses evaluate.py, never the reverse (no import of report, even in evaluate's CLI)."""
    assert "report" not in {n.names[0].name for n in ast.walk(ast.parse(Path(evaluate.__file__).read_text()))
                            if isinstance(n, ast.Import)}
    r = _cli("evaluate.py", "--policy", "greedy", "--maps", "maps/external/empty-8-8.map", "--out", str(tmp_path / "e"))
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "e" / "summary.json").exists()


def test_reward_structures_give_the_mean_over_seeds_with_a_t_interval():
    """Three seeds of one structure at t_sf 0.5, 0.6, 0.7: mean 0.6, sample std 0.1, half-width
    t(0.975, 2) * 0.1 / sqrt(3) = 4.303 * 0.0577 = 0.248; the untrained baselines have no interval."""
    def summary(t, model=None):
        s = {"policy": "marl", "dataset": "maps/marl_eval.npz", "agents": 2, "by_size": {"10": {}, "24": {}},
             "all": {"episodes": 150, "completion_rate": 1.0, "time_save": {"mean": t}}}
        return {**s, "model": model} if model else s

    def model(seed):
        return {"global_step": 30000, "args": {"reward_structure": "cooperative", "gain": 0.25, "seed": seed,
                                               "init_from": "models/rainbow_cpp.pt", "margin_loss": 0.0,
                                               "learning_rate": 1e-4, "replay_ratio": 4.0, "random_agents": False}}
    rewards = {"greedy": summary(0.604), **{f"cooperative_k0.25_s{i}": summary(t, model(i))
                                            for i, t in enumerate((0.5, 0.6, 0.7), 1)}}
    text = "\n".join(report.reward_lines(rewards))
    assert "| greedy | — | 1 | 150 | 0.604 | — | 100% |" in text
    assert "| cooperative | 0.25 | 3 | 150 | 0.600 | 0.352 – 0.848 | 100% |" in text
    assert "30,000 environment steps from `models/rainbow_cpp.pt`" in text


def test_the_faulty_agent_table_gives_the_time_save_over_the_maps_not_walled_off():
    """A walled-off map ends with only what its working agents reach covered: its time-save is not comparable, so
    the table has a column without those maps (by hand: two maps, one walled off)."""
    mr = json.loads((RESULTS / "rainbow_marl.json").read_text())
    mr["agents"] = {"1": {**mr["agents"]["1"], "time_save": 1.1}, "2": {**mr["agents"]["2"], "time_save": 0.55, "maps": 2}}
    mr["faulty"] = {"2": {"time_save": (0.8 + 9.0) / 2, "completion": 0.5, "walled_off": 1, "completion_reachable": 1.0,
                          "time_save_reachable": 0.8}}
    rows = [line for line in "\n".join(report.marl_lines(mr, {})).splitlines() if line.startswith("| 2 | 0.550 |")]
    assert rows == ["| 2 | 0.550 | 4.900 | 50% | 1.100 | 1 of 2 | 100% | 0.800 |"]
    mr["faulty"]["2"]["completion"] = 209 / 210  # rounds to 100% at no decimal: one decimal then
    rows = [line for line in "\n".join(report.marl_lines(mr, {})).splitlines() if line.startswith("| 2 | 0.550 |")]
    assert rows == ["| 2 | 0.550 | 4.900 | 99.5% | 1.100 | 1 of 2 | 100% | 0.800 |"]


def test_the_marl_targets_count_the_agent_counts_below_greedy_and_partition_on_both_sets():
    """By hand: on marl_eval N = 2 is below both planners and N = 3 only below greedy; on structured_eval N = 2 is
    below both and N = 3 below neither: 1 of 2 on each set, and structured_eval gets a table by N."""
    mr = json.loads((RESULTS / "rainbow_marl.json").read_text())
    one = {k: v for k, v in mr["agents"]["2"].items() if k in ("maps", "completion", "heuristic_share", "by_size")}
    mr["agents"] = {"1": {**one, "time_save": 1.0, "greedy": 1.1, "greedy_dead_ends": 1.0, "greedy_far_first": 1.0,
                          "partition": 1.0},
                    "2": {**one, "time_save": 0.5, "greedy": 0.6, "greedy_dead_ends": 0.6, "greedy_far_first": 0.5,
                          "partition": 0.7},
                    "3": {**one, "time_save": 0.4, "greedy": 0.45, "greedy_dead_ends": 0.4, "greedy_far_first": 0.4,
                          "partition": 0.35}}
    mr["faulty"] = {}
    planners = {"greedy_dead_ends": 0.5, "greedy_far_first": 0.4}
    mr["structured_eval"] = {"every": 21, "maps": 80, "agents": {
        "2": {"time_save": 0.6, "completion": 1.0, "greedy": 0.7, "partition": 0.8, **planners},
        "3": {"time_save": 0.5, "completion": 1.0, "greedy": 0.5, "partition": 0.6, **planners}}}
    text = "\n".join(report.marl_lines(mr, {}))
    assert "Below the greedy planner and partition at 1 of the 2 agent counts 2-3; on `structured_eval` at 1 of 2." in text
    assert "| 3 | 0.500 | 0.500 | 0.500 | 0.400 | 0.600 | 0.333 | 100% |" in text


def test_the_scale_figures_count_outliers_and_completion_by_hand():
    """Two 5x5 episodes: with the fallback overlaps 0 and 0.1; alone one completes at 0.6 (an outlier: > 0.5) and one
    is truncated (an outlier, not completed)."""
    figs = {"model": {"path": "models/x.pt", "sha256": "ab" * 32, "global_step": 1000, "stage": 0}, "per_size": 2,
            "fallback": {"5": {"overlap": [0.0, 0.1], "completed": [True, True], "truncated": [False, False]}},
            "alone": {"5": {"overlap": [0.6, 3.0], "completed": [True, False], "truncated": [False, True]}}}
    assert report._outliers(figs["alone"]["5"]) == 2 and report._outliers(figs["fallback"]["5"]) == 0
    text = "\n".join(report.scale_figure_lines(figs))
    assert "mean overlap ≤ 0.05 at 1 of 1 sizes" in text and "completion 100.0% (§6.5.2: 100%)" in text
    assert "Without it: completion 50.0% (§6.5.2: 99.3%), no outlier 0.0% (§6.5.2: 97.4%)" in text
    assert "| 5×5 | 0.050 | 0.050 | 0.100 | 100.0% | 0.600 | 50.0% | 2 |" in text
    assert report.scale_figure_lines(None)[0].startswith("*Not collected:*")
    figs |= {"structured_eval": {"rooms": {"overlap": 0.2}, "all": {"overlap": 0.2}}, "external": {"a.map": [0.1, 0.3]},
             "p2p": {"maps": 2, "optimal": 0.5, "completion": 1.0}}
    shipped = {"structured_eval": {"rooms": {"overlap": 0.1}, "all": {"overlap": 0.1}}, "external": {"a.map": [0.1]},
               "p2p": {"optimal": 1.0, "completion": 1.0}}
    text = "\n".join(report.scale_figure_lines(figs, shipped))
    assert "| structured_eval subset: rooms | 0.200 | 0.100 |" in text and "| MovingAI episodes | 0.200 | 0.100 |" in text
    assert "| p2p_eval (2): a shortest path | 50.0% | 100.0% |" in text


# ----------------------------------------------------------------------------- the TD fine-tuning
def test_the_td_finetuning_curve_and_warm_start_are_copied_from_its_checkpoint(tmp_path):
    import rainbow_cpp
    run = _tiny_scale_checkpoint(rainbow_cpp, tmp_path / "run.pt")
    shipped = _tiny_model(rainbow_cpp, tmp_path / "shipped.pt", {})
    finetune = _tiny_finetune_checkpoint(run, tmp_path / "td_run.pt", shipped)
    td = report.scale_curve(finetune)
    assert td["checkpoint"] == os.path.relpath(finetune, ROOT)
    assert td["sha256"] == hashlib.sha256(Path(finetune).read_bytes()).hexdigest()
    assert (td["global_step"], td["stage"], td["wall_seconds"]) == (1000, 0, 5)
    assert td["curve"] == gw.load_checkpoint(run, "rainbow_cpp")["curve"] and td["args"]["learning_rate"] == 5e-4
    assert td["parent"] == {"path": shipped, "sha256": hashlib.sha256(Path(shipped).read_bytes()).hexdigest(),
                            "global_step": 10}  # the warm start's record, not its whole chain
    assert "parent" not in report.scale_curve(run)  # a run from scratch


def test_fresh_maps_follow_the_experiments_logs_recipe(monkeypatch):
    monkeypatch.setattr(report, "FRESH_PER_SIZE", 2)
    monkeypatch.setattr(report, "FRESH_SIZES", range(10, 12))
    episodes, families = report.fresh_episodes()
    assert families == [f for f in ("random", *gw.STRUCTURED_FAMILIES) for _ in range(4)]
    maze = gw.generate_scenarios(1, seed=500_000 + 10_000 * 4 + 100 * 1 + 11, size=11, map_family="maze",
                                 number_obstacles=int(0.15 * 11 * 11), obstacles_random=True)[0]
    s = episodes[-1][1]  # the maze family's second map of size 11
    assert np.array_equal(s.obstacles, maze.obstacles) and np.array_equal(s.starts, maze.starts)
    assert s.covered[tuple(s.starts[0])] and episodes[-1][0] == "fresh[maze]"


def _td_finetune() -> dict:
    """A hand-made rainbow_cpp_td_finetune.json: one curve point; structured_eval with rooms (the fine-tuned model
    below both others, completion alone 100% against 50%) and fresh with random (above both, half its episodes
    completed even with the fallback)."""
    def row(overlap, completion=1.0):
        return {"overlap": overlap, "completion": completion, "heuristic_share": 0.0}

    def entry(fine, fine_alone, shipped, shipped_alone, far_first):
        return {"fine_tuned": fine, "fine_tuned_alone": fine_alone, "shipped": shipped, "shipped_alone": shipped_alone,
                "greedy_far_first": far_first}

    point = {"step": 1000, "stage": "mixed30", "sps": 300, "learning_rate": 1e-4,
             "cpp_eval": {"overlap": 0.04, "fallback_share": 0.0012}, "cpp_eval_alone": {"completion": 0.9, "outliers": 7},
             "structured_eval": {"overlap": 0.14}, "structured_eval_alone": {"completion": 0.75}}
    structured = entry(row(0.1), row(0.5), row(0.2), row(0.6, 0.5), row(0.15))
    fresh = entry(row(0.3, 0.5), row(0.9, 0.5), row(0.2), row(0.2), row(0.25))
    return {"checkpoint": "models/x_run.pt", "sha256": "ab" * 32, "global_step": 2000, "stage": 0,
            "wall_seconds": 7200, "args": {"stages": "s.yaml", "teacher": "heuristic", "td_weight": 1.0,
                                           "margin_loss": 0.0, "learning_rate": 1e-4, "heuristic_far_first": True},
            "parent": {"path": "models/rainbow_cpp.pt", "sha256": "cd" * 32, "global_step": 500},
            "slices": {"cpp_eval": 5, "structured_eval": 14},
            "shipped": {"path": "models/rainbow_cpp.pt", "sha256": "cd" * 32, "global_step": 500, "stage": "mixed30"},
            "fresh_recipe": {"seed": 500_000, "per_size": 3, "sizes": [10, 10], "obstacles": 0.15}, "curve": [point],
            "structured_eval": {"maps": {"rooms": 2}, **{k: {"rooms": v, "all": v} for k, v in structured.items()}},
            "fresh": {"maps": {"random": 3}, **{k: {"random": v, "all": v} for k, v in fresh.items()}}}


def test_the_td_finetuning_table_is_rendered_from_the_numbers(tmp_path):
    td = _td_finetune()
    refs = {"slices": {"cpp_eval": 5, "structured_eval": 14}, **{name: {
        "greedy": {"overlap": 0.5}, "greedy-far-first": {"overlap": 0.0378}, "lkh": {"overlap": 0.01},
        "rainbow": {"overlap": 0.1352}} for name in ("cpp_eval", "structured_eval")}}
    text = "\n".join(report.td_finetune_lines(td, refs))
    assert text.startswith("`rainbow_cpp.py --stages s.yaml --teacher heuristic --td-weight 1 --margin-loss 0 "
                           "--learning-rate 0.0001 --heuristic-far-first`, warm-started from `models/rainbow_cpp.pt` "
                           "(sha256 cdcdcdcdcdcd, 500 steps); the checkpoint `models/x_run.pt` (sha256 abababababab) "
                           "stands at 2,000 steps, stage index 0, 2.0 h of training. Each point: the greedy policy on "
                           "every 5th cpp_eval map and every 14th structured_eval map")
    assert "| 1,000 | mixed30 | 0.0001 | 0.040 | 90.0% | 7 | 0.140 | 75.0% | 0.0012 | 300 |" in text
    assert f"![the TD fine-tuning's learning curve]({report.FIGURES['td_finetune']})" in text
    assert "| greedy-far-first | 0.038 | 0.038 |" in text and "| shipped rainbow_cpp (+ fallback) | 0.135 | 0.135 |" in text
    assert "| lkh |" not in text and "| greedy |" not in text  # the scale run's other references
    assert "| structured_eval: rooms | 2 | 0.100 | 0.200 | 0.150 | 100% | 50% |" in text
    assert "| structured_eval: all | 2 | 0.100 | 0.200 | 0.150 | 100% | 50% |" in text
    assert "| fresh: random | 3 | 0.300 (50% completed) | 0.200 | 0.250 | 50% | 100% |" in text
    assert ("all of structured_eval (2 maps, each from its first stored start) and on the fresh per-family maps (3 a "
            "size 10-10 a family, 3 in all, 15% of the cells obstacles requested; drawn as the experiments log's fresh "
            "maps, with seeds from 500,000 on") in text
    assert ("The fine-tuned model's mean overlap is below the shipped model's in 2 of 4 rows and below "
            "greedy-far-first's in 2 of 4; its completion alone is at least the shipped model's in 2 of 4.") in text
    moved = {**refs, "slices": {"cpp_eval": 10, "structured_eval": 14}}  # references on other maps: left out
    assert "reference, same maps" not in "\n".join(report.td_finetune_lines(td, moved))
    assert report.same_maps(td, moved) is None and report.same_maps(td, None) is None
    written = report.plot_scale(td, refs, str(tmp_path), "td_finetune", "TD fine-tuning", report.TD_REFERENCES)
    assert written == [str(tmp_path / report.FIGURES["td_finetune"])] and Path(written[0]).stat().st_size > 10_000


def test_the_td_finetuning_has_its_section_and_a_bad_json_names_its_file():
    results = _committed()
    results["td_finetune"], results["paths"]["td_finetune"] = _td_finetune(), "x/td.json"
    text = report.render(results)
    section = text[text.index("## TD fine-tuning of the shipped model"):text.index("## Comparison with classical")]
    assert "| fresh: random | 3 |" in section and "*Not collected:*" not in section
    del results["td_finetune"]["fresh"]
    with pytest.raises(ValueError, match=re.escape("x/td.json") + ".*KeyError: 'fresh'"):
        report.render(results)


def test_the_td_finetuning_not_collected_says_how_to_collect_it():
    line = report.td_finetune_lines(None, None)
    assert line == [report.NOT_COLLECTED.format(file="rainbow_cpp_td_finetune.json", part="td_finetune",
                                                model="models/rainbow_cpp_td_finetune_run.pt", script="rainbow_cpp.py")]
    assert "`python report.py collect --parts td_finetune`" in line[0]
    results = _committed()
    results["td_finetune"] = None
    section = report.render(results).split("## TD fine-tuning of the shipped model\n\n", 1)[1].split("\n\n## ", 1)[0]
    assert section == line[0]


# ----------------------------------------------------------------------------- learning-rate sweeps
def _sweep(trainer: str | None, score: str) -> dict:
    """A hand-made benchmarks/learning_rate.py JSON: two rates, two evaluations each."""
    rate = {score: [(25000, 1.7), (50000, 1.65)], f"heuristic_{score}": [(25000, 0.2), (50000, 0.22)],
            "completion": [(25000, 1.0), (50000, 1.0)], "heuristic_share": [(25000, 0.4), (50000, 0.38)],
            "q_values": [(50000, -12.5)]}
    fast = {**rate, score: [(25000, 0.26), (50000, 0.1)], "q_values": []}
    return {**({"trainer": trainer} if trainer else {}), "flags": ["--network", "compact"], "stage_steps_scale": 0.05,
            "total_steps": 150000, "seed": 1, "rates": {"0.0005": fast, "5e-05": rate}}


@pytest.mark.parametrize("trainer, score, words", [(None, "overlap", "mean overlap of the greedy policy"),
                                                   ("rainbow_marl", "time_save", "mean time-save factor")])
def test_a_learning_rate_sweep_renders_one_row_a_rate(trainer, score, words):
    text = "\n".join(report.learning_rate_lines(_sweep(trainer, score)))
    assert words in text and ("--trainer rainbow_marl" in text) == (trainer is not None)
    assert "| 5e-05 | 1.700 | 1.650 | 0.220 | 0.38 | -12.50 |" in text  # the smaller rate first
    assert "| 0.0005 | 0.260 | 0.100 | 0.220 | 0.38 | — |" in text
    assert "| learning rate | 25,000 | 50,000 | heuristic, last maps |" in text
