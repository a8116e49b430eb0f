"""Zero-sum matrix games solved by LP, against analytic values and a brute-force check."""

import itertools

import numpy as np
import pytest

from farm.core.matrix_game import best_reply_gains, nash_conv, solve


def test_matching_pennies_and_rock_paper_scissors():
    s = solve([[1, -1], [-1, 1]])
    assert np.allclose(s.row, [0.5, 0.5]) and np.allclose(s.column, [0.5, 0.5]) and abs(s.value) < 1e-9
    rps = np.array([[0, -1, 1], [1, 0, -1], [-1, 1, 0]])
    s = solve(rps)
    assert np.allclose(s.row, 1 / 3) and np.allclose(s.column, 1 / 3) and abs(s.value) < 1e-9
    assert nash_conv(rps, s.row, s.column) < 1e-9
    assert nash_conv(rps, [1, 0, 0], [1, 0, 0]) == pytest.approx(2.0)  # rock v rock: paper gains 1 on each side


def test_a_saddle_point_is_found():
    A = np.array([[3, 5, 4], [2, 1, 0], [4, 6, 7]])  # row 3's minimum 4 = column 1's maximum 4
    s = solve(A)
    assert s.value == pytest.approx(4.0) and np.allclose(s.row, [0, 0, 1]) and np.allclose(s.column, [1, 0, 0])


def test_the_two_by_two_formula():
    a, b, c, d = 2.0, -1.0, -3.0, 4.0  # no saddle point
    s = solve([[a, b], [c, d]])
    p = (d - c) / (a - b - c + d)
    assert s.row[0] == pytest.approx(p) and s.value == pytest.approx((a * d - b * c) / (a - b - c + d))


def test_random_games_against_brute_force():
    rng = np.random.default_rng(7)
    for m, n in ((2, 3), (3, 3), (4, 2), (5, 6)):
        A = rng.normal(size=(m, n))
        s = solve(A)
        gains = best_reply_gains(A, s.row, s.column)
        assert max(gains) < 1e-7 and s.value == pytest.approx(float(s.row @ A @ s.column), abs=1e-7)
        # no mix on a grid guarantees the row player more than the value
        grid = [np.array(w) / sum(w) for w in itertools.product(range(4), repeat=m) if sum(w)]
        assert max(float((x @ A).min()) for x in grid) <= s.value + 1e-9


def test_a_bad_matrix_is_refused():
    with pytest.raises(ValueError, match="payoffs"):
        solve([[1.0, np.nan]])
    with pytest.raises(ValueError, match="payoffs"):
        solve(np.zeros((0, 2)))
