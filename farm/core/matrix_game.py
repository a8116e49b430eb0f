"""Two-player zero-sum matrix games: the value and optimal mixed strategies by linear programming
(scipy's HiGHS), and how far a pair of strategies is from an equilibrium (nash_conv).

The row player maximises x^T A y, the column player minimises it. solve() finds an optimal x by
the LP max v s.t. A^T x >= v 1, sum x = 1, x >= 0, and an optimal y by the column player's LP
min w s.t. A y <= w 1, sum y = 1, y >= 0; both LPs have the game's value as optimum (von
Neumann's minimax theorem), so v and w agree to the solver's tolerance.

With a floor (j, f) the row player must also keep at least f against column j (x^T A e_j >= f,
the drift case beside the worst case): solve() then maximises the guaranteed value under that
constraint, and the columns' optimal mix and the floor's price lam come from the dual LP
min u - lam f s.t. A y + lam A e_j <= u 1, sum y = 1, y >= 0, lam >= 0. A row best reply then
maximises (A y)_i + lam ((A e_j)_i - f): the row payoff against the column mix reply_column().
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Solution", "solve", "nash_conv", "best_reply_gains"]


@dataclass(frozen=True)
class Solution:
    """A zero-sum matrix game solved: row: (m,) float64 and column: (n,) float64 optimal mixed
    strategies (each summing to 1); value: the game's value for the row player (under the floor,
    when there is one); floor: (j, f), the row player's floor against column j, or None; price:
    the floor's price lam (the value's rise per unit the floor is lowered; 0 without a floor)."""

    row: np.ndarray
    column: np.ndarray
    value: float
    floor: tuple[int, float] | None = None
    price: float = 0.0

    def row_worth(self, payoffs) -> np.ndarray:
        """What rows are worth to the row player against the solution: payoffs: (k, n) float64, k
        rows' payoffs against the n columns; (k,) float64: (P y)_i + price ((P e_j)_i - f), the
        payoff against the column mix and the floor's price on its margin (P y without a floor)."""
        P = np.atleast_2d(np.asarray(payoffs, dtype=np.float64))
        worth = P @ self.column
        if self.floor is not None:
            j, f = self.floor
            worth = worth + self.price * (P[:, j] - f)
        return worth

    def reply_column(self) -> np.ndarray:
        """(n,) float64: the column mix a row best reply answers, (y + price e_j) / (1 + price): a
        row's payoff against it is its row_worth plus price f, over 1 + price (y without a floor)."""
        if self.price == 0.0:
            return self.column
        tilted = self.column.copy()
        tilted[self.floor[0]] += self.price
        return tilted / (1.0 + self.price)


def _optimal_mix(A: np.ndarray, floor: tuple[int, float] | None = None) -> tuple[np.ndarray, float]:
    """The maximising player's optimal mix of the rows of A: (m, n) and its guaranteed value; with
    floor (j, f), among the mixes keeping at least f against column j."""
    from scipy.optimize import linprog

    m, n = A.shape
    # variables (x_1..x_m, v): minimise -v s.t. v - (A^T x)_j <= 0, sum x = 1, x >= 0, v free
    c = np.zeros(m + 1)
    c[-1] = -1.0
    A_ub = np.hstack([-A.T, np.ones((n, 1))])
    b_ub = np.zeros(n)
    if floor is not None:  # and -(A^T x)_j <= -f
        A_ub = np.vstack([A_ub, np.append(-A[:, floor[0]], 0.0)[None]])
        b_ub = np.append(b_ub, -floor[1])
    A_eq = np.append(np.ones(m), 0.0)[None]
    res = linprog(c, A_ub=A_ub, b_ub=b_ub, A_eq=A_eq, b_eq=[1.0],
                  bounds=[(0, None)] * m + [(None, None)], method="highs")
    if res.status != 0:
        raise RuntimeError(f"the matrix game's LP failed: {res.message}")
    x = np.maximum(res.x[:m], 0.0)
    return x / x.sum(), float(res.x[-1])


def _floored_column_mix(A: np.ndarray, j: int, f: float) -> tuple[np.ndarray, float, float]:
    """The dual of _optimal_mix with a floor: the columns' mix y, the floor's price lam and the value
    u - lam f of min u - lam f s.t. A y + lam A e_j <= u 1, sum y = 1, y >= 0, lam >= 0."""
    from scipy.optimize import linprog

    m, n = A.shape
    # variables (y_1..y_n, lam, u)
    c = np.zeros(n + 2)
    c[n], c[n + 1] = -f, 1.0
    A_ub = np.hstack([A, A[:, j:j + 1], -np.ones((m, 1))])
    A_eq = np.append(np.ones(n), [0.0, 0.0])[None]
    res = linprog(c, A_ub=A_ub, b_ub=np.zeros(m), A_eq=A_eq, b_eq=[1.0],
                  bounds=[(0, None)] * (n + 1) + [(None, None)], method="highs")
    if res.status != 0:
        raise RuntimeError(f"the matrix game's LP failed: {res.message}")
    y = np.maximum(res.x[:n], 0.0)
    return y / y.sum(), float(max(res.x[n], 0.0)), float(res.fun)


def solve(A, floor: tuple[int, float] | None = None) -> Solution:
    """The value and optimal mixed strategies of the zero-sum game A: (m, n) finite (row player
    maximises); floor: (j, f), the row player keeping at least f against column j (see the module
    doc), or None. ValueError for an empty or non-finite matrix, a column j out of range, or a floor
    no row reaches."""
    A = np.asarray(A, dtype=np.float64)
    if A.ndim != 2 or A.size == 0 or not np.all(np.isfinite(A)):
        raise ValueError(f"payoffs: expected a non-empty 2-D matrix of finite numbers, got shape {A.shape}")
    if floor is None:
        x, v = _optimal_mix(A)
        y, w = _optimal_mix(-A.T)
        return Solution(x, y, 0.5 * (v - w))
    j, f = int(floor[0]), float(floor[1])
    if not 0 <= j < A.shape[1]:
        raise ValueError(f"floor: column {j} is not one of the game's {A.shape[1]}")
    if A[:, j].max() < f:
        raise ValueError(f"floor: no row keeps {f} against column {j} (the most is {A[:, j].max()})")
    x, v = _optimal_mix(A, (j, f))
    y, price, w = _floored_column_mix(A, j, f)
    return Solution(x, y, 0.5 * (v + w), (j, f), price)


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
