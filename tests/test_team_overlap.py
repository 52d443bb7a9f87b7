"""benchmarks/team_overlap.py: a plan's time-save split into work, overlap and idle steps, by hand."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
import team_overlap  # noqa: E402

import classical_cpp as cc  # noqa: E402
from gridworld import Scenario  # noqa: E402


def test_shares_of_a_corridor_plan():
    """1x5 corridor, agents at both ends (covered): 3 points of interest. Agent A walks 1, 2 and back onto 1 (one
    overlap, at step 3 of 3: the seventh tenth); agent B covers 3 and waits two steps. T = 3: t_sf = 1 =
    (1 + 1/3 overlap + 2/3 idle) / 2. Last new cells: A's at step 2, B's at step 1 (of 3)."""
    s = cc.with_starts(Scenario(np.zeros((1, 5), bool), np.array([[0, 0], [0, 4]])))
    a = np.array([[0, 0], [0, 1], [0, 2], [0, 1]])
    b = np.array([[0, 4], [0, 3], [0, 3], [0, 3]])
    tsf, overlap, idle, by_tenth, last_new = team_overlap.shares(s, [a, b])
    assert (tsf, overlap, idle) == (1.0, 1 / 3, 2 / 3)
    assert by_tenth.tolist() == [0] * 6 + [1 / 3] + [0] * 3
    assert tsf == (1 + overlap + idle) / 2
    assert last_new.tolist() == [2 / 3, 1 / 3]
