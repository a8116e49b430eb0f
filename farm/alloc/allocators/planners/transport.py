"""The `transport` planner (Transport): intercept whose defenders commit to rows, by 1-D optimal transport."""

from __future__ import annotations

import numpy as np

from farm.alloc.allocators.planners.core import _Planner, _positive_number
from farm.alloc.game.config import AllocConfig
from farm.core.errors import ConfigError

__all__ = ["Transport", "apportion"]

TIE_DECIMALS = 9  # apportion's remainders equal to this many decimals are a tie


def apportion(units: int, weights: np.ndarray) -> np.ndarray:
    """Whole units shared in proportion to weights by largest remainders (Hamilton's method).

    units: int >= 0; weights: (n,) float64 >= 0, not all zero -> (n,) int64 summing to units;
    ties of the remainders (equal to TIE_DECIMALS decimals, so that rounding in the quotas does
    not decide them) go to the lower index.
    """
    quota = units * weights / weights.sum()
    whole = np.floor(quota).astype(np.int64)
    left = units - int(whole.sum())
    rest = np.round(quota - whole, TIE_DECIMALS)
    order = np.lexsort((np.arange(len(weights)), -rest))  # largest remainder first
    whole[order[:left]] += 1
    return whole


class Transport(_Planner):
    """Intercept whose defenders are assigned to the intruders' rows once, by optimal transport.

    Intercept re-splits each cell's defenders every step among all the intruder cells it can
    meet earliest, in proportion to their mass. From the base of a 32 x 32 map every row
    can be met at the same step, so each part of the mass is split again at the next step
    among the rows still reachable as early: the defenders spread by diffusion, about
    sqrt(t) rows in t steps, and the outer rows of a wide front are never met (intercept
    against receding_horizon on theatre_32x32: docs/results.md, "A theatre at scale").

    Transport fixes where each defender goes instead:
    1. the defenders are counted in whole units (density times n_defenders, rounded), and
       the units are shared among the rows in proportion to the rows' intruder mass raised
       to `power` (apportion: largest remainders), so every part of the front with mass
       gets its share; the masses are taken relative to the heaviest row's before the power,
       so that a large power cannot underflow every weight to 0 (it gives every unit to the
       heaviest rows);
    2. the defenders, ordered by row (then column), are matched to those row quotas in
       order: the monotone matching, which is the optimal transport in one dimension (no
       two parts of the mass cross, and the total rows travelled is the least);
    3. each part heads, one king move a step, for the earliest cell where it can meet the
       intruders of its row (the intruders' cell k steps on, within k moves, as in
       intercept); once with them it moves with them, engaging every step. A part whose
       row it can no longer meet (the intruders have passed its column) follows
       intercept's rule, as does mass below `min_count` defenders.
    The order is kept from step to step, so a part keeps its row unless the rows' quotas
    change (captures thin a row: its defenders move on to the rows that need them).
    It asks no statistics, and costs O(N^2 K m) like intercept (K the steps, m the
    intruder cells).

    config: AllocConfig; client: accepted and unused; power: > 0, the exponent on a row's
    mass in its quota (default 1: in proportion to the mass); min_count: > 0, the least
    defender count a cell must hold to be assigned (default 0.5: the softmax map leaks a
    few 1e-4 of each cell's mass, which is no defender), at most n_defenders (more would
    leave every cell unassigned). Bad options are a ConfigError naming them.
    """

    name = "transport"

    def __init__(self, config: AllocConfig, client=None, *, power: float = 1.0, min_count: float = 0.5, **unknown):
        super().__init__(config, client, unknown)
        self.power = _positive_number(self.name, "power", power)
        self.min_count = _positive_number(self.name, "min_count", min_count)
        if self.min_count > config.n_defenders:
            raise ConfigError(f"transport: min_count {self.min_count:g} is more than the {config.n_defenders} "
                              f"defenders there are: no cell could ever be assigned (it would act as intercept)")

    def probabilities(self, D, I):
        """Transport's move probabilities (see the class): D, I: (N^2,) float64 -> (A,) float64."""
        n = self.n
        p = self.intercept_probabilities(I)
        counts = D * self.config.n_defenders
        S = np.flatnonzero(counts >= self.min_count)
        J = np.flatnonzero(I > self.config.engage_min_mass)
        if len(S) == 0 or len(J) == 0 or n < 2:
            return p
        row_of_j, col_of_j = divmod(J, n)
        row_mass = np.bincount(row_of_j, I[J], minlength=n)
        units = int(round(counts[S].sum()))
        if units == 0:
            return p
        quota = apportion(units, (row_mass / row_mass.max()) ** self.power)  # relative to the heaviest row: no 0/0
        # 2. the monotone matching of the defenders (by row, then column) onto the row quotas
        S = S[np.lexsort((S % n, S // n))]
        scale = units / counts[S].sum()
        hi = np.cumsum(counts[S]) * scale
        lo = hi - counts[S] * scale
        q_hi = np.cumsum(quota).astype(np.float64)
        q_lo = q_hi - quota
        part = np.clip(np.minimum(hi[:, None], q_hi[None, :]) - np.maximum(lo[:, None], q_lo[None, :]), 0.0, None)
        part = part / (hi - lo)[:, None]  # (|S|, N) the share of cell S[i]'s defenders assigned to each row
        # 3. each part's earliest meeting with its row's intruders
        steps = np.arange(1, n)[:, None]  # (K, 1)
        cells = self.expected_row[steps, row_of_j[None, :]] * n + np.maximum(col_of_j[None, :] - steps, 0)  # (K, m)
        ok = (col_of_j[None, :] - steps >= 0)[None] & (self.cheb[S][:, cells] <= steps[None])  # (|S|, K, m)
        k_first = np.where(ok.any(axis=1), np.argmax(ok, axis=1), n)  # (|S|, m) the earliest step index, n: never
        in_row_of = {t: np.flatnonzero(row_of_j == t) for t in np.unique(row_of_j)}  # row -> its intruder cells in J
        for i, s in enumerate(S):
            taken = 0.0
            moves = []
            for t in np.flatnonzero(part[i] > 1e-12):
                in_row = in_row_of[t]
                k = k_first[i, in_row]
                if k.min() >= n:
                    continue  # its row's intruders cannot be met: that part follows intercept
                best = in_row[np.lexsort((-I[J[in_row]], k))[0]]
                goal = cells[k_first[i, best], best]
                moves.append((self.move_index(s, self.toward[s, goal]), part[i, t]))
                taken += part[i, t]
            if not moves:
                continue
            lo_a, hi_a = self.start[s], self.ends[s]
            p[lo_a:hi_a] *= 1.0 - taken
            for a, w in moves:
                p[a] += w
        return p
