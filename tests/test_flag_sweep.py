"""Every numeric flag of the two trainers, generated from their Args dataclasses (a new flag is covered without anyone
remembering to): nan, inf and -1 are refused with a one-line ValueError before anything is allocated or written.
main() is stopped right after its checks (start_run, the first thing that reads files or builds networks, raises
a sentinel), so nothing trains."""
from __future__ import annotations

import dataclasses
import math

import pytest

import rainbow_cpp as rc
import rainbow_marl as rm

TRAINERS = {"rainbow_cpp": rc, "rainbow_marl": rm}


class Accepted(Exception):
    """main got past its checks."""


def numeric_fields(t) -> list[tuple[str, type]]:
    hints = {f.name: f.type for f in dataclasses.fields(t.Args)}
    return [(name, float if "float" in str(kind) else int) for name, kind in hints.items()
            if ("int" in str(kind) or "float" in str(kind)) and "bool" not in str(kind)]


def cases():
    for name, t in TRAINERS.items():
        for field, kind in numeric_fields(t):
            values = [-1] if kind is int else [math.nan, math.inf, -math.inf, -1.0]
            for value in values:
                yield pytest.param(name, field, value, id=f"{name}-{field}-{value}")


@pytest.mark.parametrize("name, field, value", list(cases()))
def test_bad_numbers_are_refused_before_anything_happens(name, field, value, tmp_path, monkeypatch):
    t = TRAINERS[name]
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(t, "start_run", lambda *a, **k: (_ for _ in ()).throw(Accepted()))
    args = t.Args(**{field: value, "run_name": "sweep", "cuda": False})
    with pytest.raises(ValueError) as refused:
        t.main(args)
    message = str(refused.value)
    assert "\n" not in message and message
    assert not (tmp_path / "runs").exists()


def test_the_sweep_covers_every_numeric_flag():
    for t in TRAINERS.values():
        names = {n for n, _ in numeric_fields(t)}
        assert {"learning_rate", "seed", "total_steps", "curve_every" if t is rc else "seed"} <= names
