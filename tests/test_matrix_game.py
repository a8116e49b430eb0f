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


def test_a_floor_on_the_row_players_payoff_against_one_column_by_hand():
    # row 0 does well against column 0 (the drift case) and nothing in the worst case; row 1 holds
    A = np.array([[0.8, 0.0], [0.7, 0.5]])
    assert solve(A).row == pytest.approx([0.0, 1.0])
    s = solve(A, floor=(0, 0.75))  # 0.8 x0 + 0.7 (1 - x0) >= 0.75: x0 >= 0.5; worst 0.5 (1 - x0)
    assert s.row == pytest.approx([0.5, 0.5]) and s.value == pytest.approx(0.25)
    assert s.column == pytest.approx([0.0, 1.0]) and s.price == pytest.approx(5.0)  # d value / d f = -5
    assert s.reply_column() == pytest.approx([5 / 6, 1 / 6])
    assert s.row_worth(A) == pytest.approx([0.25, 0.25])  # both rows in the support: equal worth


def test_a_floor_nobody_is_held_to_changes_nothing():
    A = np.array([[0.8, 0.0], [0.7, 0.5]])
    s = solve(A, floor=(0, 0.6))
    assert s.row == pytest.approx([0.0, 1.0]) and s.value == pytest.approx(0.5) and s.price == pytest.approx(0.0)
    assert s.reply_column() == pytest.approx(s.column)


def test_random_floored_games_against_brute_force():
    rng = np.random.default_rng(11)
    for m, n in ((2, 3), (3, 3), (4, 2), (4, 5)):
        A = rng.uniform(size=(m, n))
        j = int(rng.integers(n))
        f = float(np.quantile(A[:, j], 0.7))
        s = solve(A, floor=(j, f))
        assert float(s.row @ A[:, j]) >= f - 1e-9 and s.row.sum() == pytest.approx(1.0)
        assert float((s.row @ A).min()) == pytest.approx(s.value, abs=1e-7)
        # no row gains against the columns' mix and the floor's price (the dual's feasibility)
        assert s.row_worth(A).max() <= s.value + 1e-7 and s.reply_column().sum() == pytest.approx(1.0)
        # no mix on a grid keeping the floor guarantees more than the value
        grid = [np.array(w) / sum(w) for w in itertools.product(range(6), repeat=m) if sum(w)]
        held = [x for x in grid if x @ A[:, j] >= f]
        assert max(float((x @ A).min()) for x in held) <= s.value + 1e-9
        assert solve(A, floor=(j, float(A[:, j].min()))).value == pytest.approx(solve(A).value, abs=1e-7)


def test_a_bad_floor_is_refused():
    with pytest.raises(ValueError, match="floor"):
        solve([[0.1, 0.2]], floor=(2, 0.0))
    with pytest.raises(ValueError, match="floor"):
        solve([[0.1, 0.2], [0.3, 0.0]], floor=(0, 0.5))
