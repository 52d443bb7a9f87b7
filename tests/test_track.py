"""CleanRL's --track: Weights & Biases mirrors a trainer's TensorBoard logs; wandb is an optional dependency."""
from __future__ import annotations

import importlib.util

import pytest
from conftest import tiny_trainer_args as tiny

import rainbow_cpp as rc
import rainbow_marl as rm

TRAINERS = {"rainbow_cpp": rc, "rainbow_marl": rm}


@pytest.mark.parametrize("name", TRAINERS)
def test_track_without_wandb_is_a_one_line_error(name, monkeypatch):
    t = TRAINERS[name]
    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda n, *a: None if n == "wandb" else find_spec(n, *a))
    with pytest.raises(ValueError, match=r"^--track needs Weights & Biases: pip install wandb$"):
        t.check_flags(tiny(t, track=True))


@pytest.mark.skipif(importlib.util.find_spec("wandb") is None, reason="wandb is optional and not installed")
def test_track_logs_offline(tmp_path, monkeypatch, restore_sigint):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_SILENT", "true")
    rc.main(tiny(rc, track=True, wandb_project_name="test"))
    assert list((tmp_path / "runs" / "t" / "wandb").glob("offline-run-*"))
