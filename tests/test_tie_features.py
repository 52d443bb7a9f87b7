"""benchmarks/tie_features.py: the local features of a neighbouring cell and the judge of a ranking, by hand."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
import tie_features as tf  # noqa: E402


def test_cell_features_of_a_3x3_map_with_its_centre_covered():
    todo = np.ones((1, 3, 3), bool)
    todo[0, 1, 1] = False
    free = np.ones((1, 3, 3), bool)
    from_start = np.array([[[2, 1, 2], [1, 0, 1], [2, 1, 2]]])
    f = tf.cell_features(todo, free, from_start)
    degree, hole, _, pieces, blocked, diagonals, window, _, _, far = f
    # corner (0, 0): two uncovered neighbours, not joined around it (the centre is covered), two sides off the map
    assert (degree[0, 0, 0], hole[0, 0, 0], pieces[0, 0, 0], blocked[0, 0, 0]) == (2, 0, 2, 2)
    assert diagonals[0, 0, 0] == 0 and window[0, 0, 0] == 8  # its only diagonal is the centre
    # edge (0, 1): the corners either side, split by the covered centre below
    assert (degree[0, 0, 1], pieces[0, 0, 1], blocked[0, 0, 1], diagonals[0, 0, 1]) == (2, 2, 1, 2)
    assert far[0, 0, 0] == 1.0 and far[0, 0, 1] == 0.5  # steps from the start over the farthest (2)


def test_judge_counts_cheapest_picks_and_extra_steps():
    score = np.array([[0.9, 0.1, 0.0, 0.0], [0.2, 0.8, 0.5, 0.0]])
    mask = np.array([[True, True, False, False], [True, False, True, False]])  # state 2: move 1 is not a candidate
    cost = np.array([[10.0, 12.0, 0.0, 0.0], [7.0, 0.0, 9.0, 0.0]])
    result = tf.judge(score, mask, cost)
    assert result["best"] == 0.5  # state 1 picks move 0 (cheapest); state 2 picks move 2 (two steps more)
    assert result["extra_steps"] == 1.0
