"""Two-player zero-sum matrix games: the value and optimal mixed strategies by linear programming
(scipy's HiGHS), and how far a pair of strategies is from an equilibrium (nash_conv).

The row player maximises x^T A y, the column player minimises it. solve() finds an optimal x by
the LP max v s.t. A^T x >= v 1, sum x = 1, x >= 0, and an optimal y by the column player's LP
min w s.t. A y <= w 1, sum y = 1, y >= 0; both LPs have the game's value as optimum (von
Neumann's minimax theorem), so v and w agree to the solver's tolerance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Solution", "solve", "nash_conv", "best_reply_gains"]


@dataclass(frozen=True)
class Solution:
    """A zero-sum matrix game solved: row: (m,) float64 and column: (n,) float64 optimal mixed
    strategies (each summing to 1); value: the game's value for the row player."""

    row: np.ndarray
    column: np.ndarray
    value: float


def _optimal_mix(A: np.ndarray) -> tuple[np.ndarray, float]:
    """The maximising player's optimal mix of the rows of A: (m, n) and its guaranteed value."""
    from scipy.optimize import linprog

    m, n = A.shape
    # variables (x_1..x_m, v): minimise -v s.t. v - (A^T x)_j <= 0, sum x = 1, x >= 0, v free
    c = np.zeros(m + 1)
    c[-1] = -1.0
    A_ub = np.hstack([-A.T, np.ones((n, 1))])
    A_eq = np.append(np.ones(m), 0.0)[None]
    res = linprog(c, A_ub=A_ub, b_ub=np.zeros(n), A_eq=A_eq, b_eq=[1.0],
                  bounds=[(0, None)] * m + [(None, None)], method="highs")
    if res.status != 0:
        raise RuntimeError(f"the matrix game's LP failed: {res.message}")
    x = np.maximum(res.x[:m], 0.0)
    return x / x.sum(), float(res.x[-1])


def solve(A) -> Solution:
    """The value and optimal mixed strategies of the zero-sum game A: (m, n) finite (row player
    maximises). ValueError for an empty or non-finite matrix."""
    A = np.asarray(A, dtype=np.float64)
    if A.ndim != 2 or A.size == 0 or not np.all(np.isfinite(A)):
        raise ValueError(f"payoffs: expected a non-empty 2-D matrix of finite numbers, got shape {A.shape}")
    x, v = _optimal_mix(A)
    y, w = _optimal_mix(-A.T)
    return Solution(x, y, 0.5 * (v - w))


def best_reply_gains(A, row, column) -> tuple[float, float]:
    """What each player gains by its best pure reply to the other's mix: (max_i (A y)_i - x^T A y,
    x^T A y - min_j (x^T A)_j), each >= 0 up to rounding. A: (m, n); row: (m,); column: (n,)."""
    A = np.asarray(A, dtype=np.float64)
    x, y = np.asarray(row, dtype=np.float64), np.asarray(column, dtype=np.float64)
    value = float(x @ A @ y)
    return float((A @ y).max()) - value, value - float((x @ A).min())


def nash_conv(A, row, column) -> float:
    """NashConv of a pair of mixes in the game A: the sum of both players' best-reply gains
    (0 exactly at an equilibrium)."""
    return float(sum(best_reply_gains(A, row, column)))
