"""The drift frontier of a meta-game against brute force over mixes of its rows."""

import itertools

import numpy as np
import pytest

from farm.core.matrix_game import solve
from farm.studies.robust.frontier import drift_frontier, pure_points


def test_the_frontier_is_the_best_worst_case_for_each_floor():
    rng = np.random.default_rng(3)
    M = rng.uniform(size=(4, 5))
    M[0, 0] = M[:, 0].max() + 0.01  # the reference alone does best against drift
    margins = [0.0, 0.05, 0.1, 0.3, 1.0]
    points = drift_frontier(M, 0, 0, margins)
    grid = [np.array(w) / sum(w) for w in itertools.product(range(8), repeat=4) if sum(w)]
    for p in points:
        assert p["drift"] >= p["target"] - 1e-9 and sum(p["weights"]) == pytest.approx(1.0)
        assert p["worst"] == pytest.approx(float((np.asarray(p["weights"]) @ M).min()))
        held = [x for x in grid if x @ M[:, 0] >= p["target"]]
        assert max(float((x @ M).min()) for x in held) <= p["worst"] + 1e-9
    worst = [p["worst"] for p in points]
    assert worst == sorted(worst)  # a lower floor never guarantees less
    assert points[0]["worst"] == pytest.approx(M[0].min())  # margin 0: the reference alone keeps the floor
    assert points[-1]["worst"] == pytest.approx(solve(M).value, abs=1e-7)  # a floor below every row: no floor
    assert pure_points(M, 0) == [(pytest.approx(M[i, 0]), pytest.approx(M[i].min())) for i in range(4)]
