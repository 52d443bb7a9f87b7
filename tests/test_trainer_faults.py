"""Faults and bad inputs of the two trainers (issue 44): each a one-line ValueError, nothing lost.

- A full disk during a checkpoint leaves the previous checkpoint and no temporary file.
- A second run in a run folder that a run holds is refused (the lock); the folder's checkpoint is untouched.
- --export into results/ or maps/ is refused; over a model that was there before the run it needs --overwrite.
- A diverged network (weights not finite) is never saved.
"""
from __future__ import annotations

import errno
import hashlib
import os

import pytest
import torch
from conftest import tiny_trainer_args as tiny

import gridworld as gw
import rainbow_cpp as rc
import rainbow_marl as rm

TRAINERS = {"rainbow_cpp": rc, "rainbow_marl": rm}


def digest(path) -> str:
    return hashlib.sha256(open(path, "rb").read()).hexdigest()


@pytest.mark.parametrize("name", TRAINERS)
def test_a_full_disk_keeps_the_previous_checkpoint(name, tmp_path, monkeypatch, restore_sigint):
    t = TRAINERS[name]
    monkeypatch.chdir(tmp_path)
    t.main(tiny(t))
    ckpt = tmp_path / "runs" / "t" / "checkpoint.pt"
    before = digest(ckpt)

    def full(obj, f, *a, **k):
        open(f, "wb").write(b"half a checkpoint")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(torch, "save", full)
    with pytest.raises(ValueError, match=r"cannot write \(No space left on device\); any earlier file there stays"):
        t.main(tiny(t, total_steps=64, resume=True))
    assert digest(ckpt) == before and not (tmp_path / "runs" / "t" / "checkpoint.pt.tmp").exists()


@pytest.mark.parametrize("name", TRAINERS)
def test_a_second_run_in_a_held_run_folder_is_refused(name, tmp_path, monkeypatch, restore_sigint):
    t = TRAINERS[name]
    monkeypatch.chdir(tmp_path)
    held = gw.lock_run(str(tmp_path / "runs" / "t"))
    try:
        with pytest.raises(ValueError, match="is in use by another run"):
            t.main(tiny(t))
    finally:
        held.close()
    assert not (tmp_path / "runs" / "t" / "checkpoint.pt").exists()
    t.main(tiny(t))  # free again
    assert (tmp_path / "runs" / "t" / "checkpoint.pt").exists()


@pytest.mark.parametrize("name", TRAINERS)
def test_exports_never_land_among_results_or_maps_or_over_a_model_without_overwrite(name, tmp_path, monkeypatch,
                                                                                   restore_sigint):
    t = TRAINERS[name]
    monkeypatch.chdir(tmp_path)
    for folder in ("results", "maps"):
        with pytest.raises(ValueError, match="which holds committed"):
            t.check_flags(tiny(t, export=os.path.join(t.HERE, folder, f"{name}.pt")))
    model = tmp_path / "m.pt"
    t.main(tiny(t, export=str(model)))
    before = digest(model)
    with pytest.raises(ValueError, match="m.pt: there already; --overwrite replaces it"):
        t.main(tiny(t, run_name="u", export=str(model)))
    assert digest(model) == before
    t.main(tiny(t, run_name="v", export=str(model), overwrite=True, seed=2))
    assert digest(model) != before


@pytest.mark.parametrize("name", TRAINERS)
def test_a_diverged_network_is_never_saved(name, tmp_path, monkeypatch, restore_sigint):
    t = TRAINERS[name]
    monkeypatch.chdir(tmp_path)
    t.main(tiny(t))
    ckpt = tmp_path / "runs" / "t" / "checkpoint.pt"
    before = digest(ckpt)
    original = t.learn

    def diverging(q, *a, **k):
        out = original(q, *a, **k)
        with torch.no_grad():
            next(q.parameters()).fill_(float("nan"))
        return out

    monkeypatch.setattr(t, "learn", diverging)
    with pytest.raises(ValueError, match="not finite at step"):
        t.main(tiny(t, total_steps=200, resume=True))
    assert digest(ckpt) == before


@pytest.mark.parametrize("name", TRAINERS)
def test_a_model_with_weights_that_are_not_finite_is_refused_at_load(name, tmp_path, monkeypatch, restore_sigint):
    t = TRAINERS[name]
    monkeypatch.chdir(tmp_path)
    t.main(tiny(t, export=str(tmp_path / "m.pt")))
    blob = torch.load(tmp_path / "m.pt", weights_only=True)
    first = next(iter(blob["weights"]))
    blob["weights"][first] = torch.full_like(blob["weights"][first], float("inf"))
    torch.save(blob, tmp_path / "bad.pt")
    with pytest.raises(ValueError, match="bad.pt: its weights are not finite"):
        t.load_policy(str(tmp_path / "bad.pt"))
