"""Copy, modify, evaluate: a copy of rainbow_cpp.py with exactly the edits docs/rainbow_cpp.md's "How to change
things" names (the observation's window, one more convolution, the reward) trains a few hundred steps and
evaluate.py scores its model with no edit to evaluate.py; the shipped trainer refuses that model in one line that
names what differs."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SHARED = [  # (what the docs name, the text in the trainer, its replacement)
    ("DEEP", 'DEEP = {"view_size": gridworld.VIEW_SIZE}', 'DEEP = {"view_size": 21}'),
    ("QNetwork", "nn.Conv2d(64, 64, 3, 2), nn.ReLU(), nn.Flatten())",
     "nn.Conv2d(64, 64, 3, 2), nn.ReLU(), nn.Conv2d(64, 64, 3, 1, 1), nn.ReLU(), nn.Flatten())"),
]
EDITS = {
    "rainbow_cpp": SHARED + [("stage_config", "    if stage.random_coverage and args.uncommon_patterns > 0:",
                              "    stage = stage.replace(reward=replace(stage.reward, revisit=-0.5))\n"
                              "    if stage.random_coverage and args.uncommon_patterns > 0:")],
    "rainbow_marl": SHARED + [("stage_config", '"structure": args.reward_structure,',
                               '"structure": args.reward_structure, "revisit": -0.5,')],
}
RUN = ["--no-cuda", "--threads", "1", "--total-steps", "300", "--learning-starts", "100", "--buffer-size", "4096",
       "--num-envs", "4", "--hidden", "16", "--eval-every", "0", "--save-every", "0", "--stage-steps-scale", "0.001",
       "--run-name", "v", "--quiet"]
POLICY = {"rainbow_cpp": ["--policy", "rainbow"], "rainbow_marl": ["--policy", "marl", "--agents", "2"]}


def run(*command: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1", "PYTHONDONTWRITEBYTECODE": "1"}
    return subprocess.run([sys.executable, *command], cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("trainer", EDITS)
def test_the_documented_edits_are_the_places_to_change(trainer):
    docs = (ROOT / "docs" / "rainbow_cpp.md").read_text() + (ROOT / "docs" / f"{trainer}.md").read_text()
    source = (ROOT / f"{trainer}.py").read_text()
    for name, before, _ in EDITS[trainer]:
        assert f"`{name}`" in docs and source.count(before) == 1, name


@pytest.mark.parametrize("trainer", EDITS)
def test_a_modified_copy_trains_and_is_evaluated(trainer, tmp_path):
    source = (ROOT / f"{trainer}.py").read_text()
    for _, before, after in EDITS[trainer]:
        source = source.replace(before, after)
    (tmp_path / "my_variant.py").write_text(source)
    (tmp_path / "maps").symlink_to(ROOT / "maps")
    (tmp_path / "models").symlink_to(ROOT / "models")  # rainbow_marl warm-starts from the shipped single agent
    trained = run("my_variant.py", *RUN, *(["--no-camera-stages"] if trainer == "rainbow_cpp" else ["--init-from", ""]),
                  cwd=tmp_path)
    assert trained.returncode == 0, trained.stderr[-2000:]
    model = tmp_path / "runs" / "v" / "my_variant.pt"
    info = json.loads(model.with_suffix(".json").read_text())
    assert info["provenance"]["script"] == "my_variant.py" and info["network"]["view"] == 21
    flags = [*POLICY[trainer], "--checkpoint", str(model), "--maps", str(ROOT / "maps/external/empty-8-8.map")]
    scored = run(str(ROOT / "evaluate.py"), *flags, "--out", "eval", cwd=tmp_path)
    assert scored.returncode == 0, scored.stderr[-2000:]
    summary = json.loads((tmp_path / "eval" / "summary.json").read_text())
    assert summary["all"]["completion_rate"] == 1.0  # with the fallback, as every learned evaluation
    refused = run(str(ROOT / "evaluate.py"), *flags, "--trainer", str(ROOT / f"{trainer}.py"), "--out", "e2",
                  cwd=tmp_path)
    lines = refused.stderr.strip().splitlines()
    assert refused.returncode == 1 and len(lines) == 1 and lines[0].startswith("error: "), refused.stderr
    assert f"{trainer}.py gives it deep, view 41" in lines[0] and "--trainer" in lines[0], lines[0]


def test_weights_of_another_network_name_what_differs_in_one_line():
    import torch

    import rainbow_cpp as rc

    q = rc.QNetwork(3, rc.VIEW, 16, 0.5)
    weights = {k: v for k, v in q.state_dict().items() if "sigma" not in k and "eps" not in k}
    weights["conv.6.weight"] = torch.zeros(64, 64, 3, 3)
    weights["value.0.weight_mu"] = torch.zeros(8, 3)
    with pytest.raises(ValueError) as refused:
        rc.policy_from({"weights": weights, **q.network()}, "m.pt")
    message = str(refused.value)
    assert "\n" not in message and message.startswith("m.pt: weights do not match rainbow_cpp.py's network (")
    assert "conv.6.weight only in the file" in message and "value.0.weight_mu (8, 3) in the file, (16, " in message
