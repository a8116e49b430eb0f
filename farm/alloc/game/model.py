"""The allocation MDP's model, as functions: what the env does and what planners predict.

The env (farm.alloc.envs.defenders) steps through these functions, and the planners
(farm.alloc.allocators.planners) call the same ones to look ahead, so a planner's model of a
step is the env's step and never a copy that could drift from it:

- advance_intruders (advance_intruders_many for B episodes): the intruders' move under the
  drift law, known in advance; route_intruders_many under any routing (docs/model.md section 8);
- team_sizes: a cell's game, (n_p, n_e) from its densities (rounding, the lattice);
- EngagementModel: a cell's expected outcome from the capture-time client's statistics
  (docs/model.md section 5); engage_many answers B episodes' engaged cells in one lookup.

Every density is a vector over the N x N cells in cell order, c = row * N + col; a batch of
B episodes is a (B, N^2) array, one episode a row. The batched functions give each episode, to
the last bit, the numbers they give it alone (B = 1): see segment_sums.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from farm.alloc.game.config import AllocConfig
from farm.service.keys import LATTICE

__all__ = ["LATTICE", "snap", "snap_many", "row_sums", "segment_sums", "advance_intruders", "advance_intruders_many",
           "route_intruders_many", "drift_routing",
           "team_sizes", "Engagement", "Engagements", "EngagementModel"]

_LATTICE = np.array(LATTICE)
_LATTICE_MIDS = np.sqrt(_LATTICE[:-1] * _LATTICE[1:])  # geometric midpoints: never an integer


def snap_many(x: np.ndarray) -> np.ndarray:
    """Snap team sizes to the nearest size of LATTICE in log scale (team_sizes: lattice).

    x: (k,) int team sizes -> (k,) int64 lattice sizes. At a geometric midpoint of two
    lattice sizes the smaller would win, but no integer is one.
    """
    return _LATTICE[np.searchsorted(_LATTICE_MIDS, x)]


def snap(x: int) -> int:
    """Snap one team size to the nearest lattice size in log scale (snap_many for one)."""
    return int(snap_many(np.asarray([x]))[0])


def row_sums(X: np.ndarray) -> np.ndarray:
    """The sum of each row: X: (B, M) float64 -> (B,) float64, row k exactly X[k].sum().

    numpy reduces a C-contiguous array's last axis row by row with its 1-D pairwise
    summation, whatever B, so each row's sum is its 1-D sum bit for bit.
    """
    return np.ascontiguousarray(X).sum(axis=1)


_SHORT = 8  # numpy sums fewer entries than this one after another, from the first


def segment_sums(values: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Sums of consecutive segments, each exactly numpy's 1-D sum of the segment alone.

    values: (R, K) float64, R quantities of K entries laid out as B consecutive segments;
    counts: (B,) int64 the segments' lengths (summing to K, 0 allowed) -> (R, B) float64,
    [r, b] = values[r, segment b].sum() (0.0 for an empty segment). A single segment is summed
    by numpy (row_sums). Of several, those of fewer than 8 entries are summed one entry after
    another from 0, as numpy sums so few (np.bincount's order); longer ones by numpy, one
    (rows, length) array per distinct length, its rows summed as 1-D arrays (row_sums).

    Why: numpy sums a 1-D array pairwise (in blocks of 8 from 8 entries on), so a sum's last
    bit depends on how its entries are grouped. Summing each episode's entries exactly as numpy
    sums them alone gives a batch of B episodes the very numbers each gets with B = 1: the
    single env (farm.alloc.envs.defenders) and the batched one (farm.alloc.envs.vector) agree to the last
    bit (tests/test_vector_env.py checks the property).
    """
    values = np.asarray(values, dtype=np.float64)
    counts = np.asarray(counts, dtype=np.int64)
    R, B = values.shape[0], len(counts)
    if B == 1:  # one segment, the whole row: numpy's sum itself
        return row_sums(values)[:, None]
    K = values.shape[1]
    if B == 0 or K == 0:
        return np.zeros((R, B))
    bins = np.repeat(np.arange(B), counts) + (np.arange(R) * B)[:, None]
    out = np.bincount(bins.reshape(-1), weights=values.reshape(-1), minlength=R * B).reshape(R, B)
    if counts.max() >= _SHORT:
        starts = np.cumsum(counts) - counts
        for length in np.unique(counts[counts >= _SHORT]).tolist():
            rows = np.flatnonzero(counts == length)
            idx = starts[rows, None] + np.arange(length)
            out[:, rows] = row_sums(values[:, idx].reshape(R * len(rows), length)).reshape(R, len(rows))
    return out


def route_intruders_many(I: np.ndarray, n: int, up: np.ndarray, down: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The intruders' move of one step in B episodes: each cell's mass routed between rows, then one column left.

    I: (B, N^2) float64 intruder densities, one episode a row; n: the grid side N; up, down:
    (B, N^2) float64 the share of each cell's mass sent up-left and down-left (0 on the top
    row for up and on the bottom row for down), the rest going straight left. Returns (I':
    (B, N^2) float64 the densities after the advance, breach: (B,) float64 the mass that left
    the left edge). I is not changed. The routed masses are computed as up * I and down * I
    and moved in the order: up out, up in, down out, down in; so the routing (d, 1 - 2d, d)
    gives exactly what advance_intruders_many(I, n, d) gives.
    """
    grid = np.asarray(I).reshape(-1, n, n)
    rising = np.asarray(up).reshape(grid.shape)[:, 1:] * grid[:, 1:]
    falling = np.asarray(down).reshape(grid.shape)[:, :-1] * grid[:, :-1]
    grid = grid.copy()
    grid[:, 1:] -= rising
    grid[:, :-1] += rising
    grid[:, :-1] -= falling
    grid[:, 1:] += falling
    return _one_column_left(grid, n)


def _one_column_left(grid: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """grid: (B, N, N) float64 -> (the grid moved one column left as (B, N^2), breach: (B,) the
    mass of column 0, which leaves)."""
    breach = row_sums(grid[:, :, 0])
    moved = np.zeros_like(grid)
    moved[:, :, :-1] = grid[:, :, 1:]
    return moved.reshape(len(grid), n * n), breach


def drift_routing(n: int, drift: float, B: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """The drift law as a routing: (up, down): (B, N^2) float64 each, every row but the top
    sending the share `drift` up-left and every row but the bottom the same share down-left."""
    rows = np.repeat(np.arange(n), n)
    up = np.where(rows > 0, float(drift), 0.0)
    down = np.where(rows < n - 1, float(drift), 0.0)
    return np.tile(up, (B, 1)), np.tile(down, (B, 1))


def advance_intruders_many(I: np.ndarray, n: int, drift: float) -> tuple[np.ndarray, np.ndarray]:
    """The intruders' move of one step in B episodes under the drift law: vertical drift, then one column left.

    I: (B, N^2) float64 intruder densities, one episode a row; n: the grid side N; drift: the
    share d of each row's mass sent to each neighbouring row (`vertical_drift`). Returns (I':
    (B, N^2) float64 the densities after the advance, breach: (B,) float64 the mass that left
    the left edge). I is not changed. route_intruders_many with drift_routing(n, drift).
    """
    grid = np.asarray(I).reshape(-1, n, n)
    if drift > 0:
        up, down = drift_routing(n, drift, len(grid))
        return route_intruders_many(grid.reshape(len(grid), n * n), n, up, down)
    return _one_column_left(grid, n)


def advance_intruders(I: np.ndarray, n: int, drift: float) -> tuple[np.ndarray, float]:
    """The intruders' move of one step: vertical drift, then one column left.

    I: (N^2,) float64 intruder densities; n: the grid side N; drift: the share d of each
    row's mass sent to each neighbouring row (`vertical_drift`). Returns (I': (N^2,)
    float64 the densities after the advance, breach: float the mass that left the left
    edge). I is not changed. advance_intruders_many with B = 1.
    """
    moved, breach = advance_intruders_many(np.asarray(I)[None], n, drift)
    return moved[0], float(breach[0])


def team_sizes(config: AllocConfig, D: np.ndarray, I: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The games of cells: n_p = round(D n_defenders), n_e = max(1, round(I n_intruders)),
    both snapped to LATTICE under `team_sizes: lattice` (n_p = 0 stays 0: no game).

    D, I: (k,) float64 the cells' densities -> (n_p, n_e): (k,) int64 each.
    """
    n_p = np.rint(np.asarray(D) * config.n_defenders).astype(np.int64)
    n_e = np.maximum(1, np.rint(np.asarray(I) * config.n_intruders).astype(np.int64))
    if config.team_sizes == "lattice":
        n_p = np.where(n_p >= 1, snap_many(np.maximum(n_p, 1)), 0)
        n_e = snap_many(n_e)
    return n_p, n_e


@dataclass(frozen=True)
class Engagement:
    """The engaged cells of one step and their expected outcomes.

    cells: (k,) int64 the engaged cells; n_p, n_e: (k,) int64 their games' team sizes;
    removed: (k,) float64 the expected share of each cell's intruders removed
    (frac_captured_tau); score: (k,) float64 the capture score per unit of the cell's
    intruder mass; estimates: how many of the k answers were interpolations.
    """

    cells: np.ndarray
    n_p: np.ndarray
    n_e: np.ndarray
    removed: np.ndarray
    score: np.ndarray
    estimates: int


@dataclass(frozen=True)
class Engagements:
    """The engaged cells of one step in B episodes, episode by episode, each in cell order.

    episode: (k,) int64 each engaged cell's episode (ascending); cells: (k,) int64 the cell;
    counts: (B,) int64 the engaged cells of each episode; n_p, n_e: (k,) int64 the games'
    team sizes; removed, score: (k,) float64 as Engagement's; estimated: (k,) bool the answers
    that were interpolations.
    """

    episode: np.ndarray
    cells: np.ndarray
    counts: np.ndarray
    n_p: np.ndarray
    n_e: np.ndarray
    removed: np.ndarray
    score: np.ndarray
    estimated: np.ndarray


_DISTINCT_FROM = 64  # fewer pairs are asked as they come: a memo hit costs less than finding the distinct ones


class EngagementModel:
    """A config's engagements answered by a capture-time client: the env's and the planners' model.

    config: AllocConfig; client: a CaptureTimeClient of config.game_settings();
    estimates: False, True or "lattice": how a first visit may be interpolated
    (CaptureTimeClient.get_many's `estimate`; see SwarmAllocationEnv).
    """

    def __init__(self, config: AllocConfig, client, estimates: bool | str = False):
        self.config = config
        self.client = client
        self.estimates = estimates

    def engaged(self, D: np.ndarray, I: np.ndarray) -> np.ndarray:
        """The cells that engage: n_p >= 1 and I_c > engage_min_mass. D, I: (N^2,) float64 -> (k,) int64."""
        n_p = np.rint(D * self.config.n_defenders)
        return np.flatnonzero((n_p >= 1) & (I > self.config.engage_min_mass))

    def lookup(self, n_p: np.ndarray, n_e: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The expected outcome of games per unit of intruder mass, with one client call.

        n_p, n_e: (k,) int team sizes, n_p >= 1 -> (removed: (k,) float64 the share of the
        intruders captured within tau, score: (k,) float64 the capture score per unit of
        mass, estimated: (k,) bool the interpolated answers). A pair met more than once is
        asked once (the client's get_many, one call, on the distinct pairs), unless the client's
        backend is not repeatable (the games fidelity: every engagement is its own game). The score's rule
        is the config's `capture_score`: "expected", the mean over all games of each game's
        mean of max(0, 1 - t/tau) per intruder (capture_score_tau), or "conditional", max(0,
        1 - t/capture_time_norm) with t the mean capture time of the games that caught
        someone (t_max when none did).
        """
        n_p, n_e = np.asarray(n_p), np.asarray(n_e)
        inverse = None
        if (n_p.dtype.kind in "iu" and n_e.dtype.kind in "iu" and len(n_p) > _DISTINCT_FROM
                and self.client.repeatable):
            lo_p, lo_e = int(n_p.min()), int(n_e.min())
            width = int(n_e.max()) - lo_e + 1
            keys, inverse = np.unique((n_p.astype(np.int64) - lo_p) * width + (n_e.astype(np.int64) - lo_e),
                                      return_inverse=True)
            n_p, n_e = keys // width + lo_p, keys % width + lo_e
        values = self.client.get_many(list(zip(n_p.tolist(), n_e.tolist())), estimate=self.estimates)
        cfg = self.config
        removed = np.array([v.frac_captured_tau for v in values], dtype=np.float64)
        if cfg.capture_score == "expected":
            score = np.array([v.capture_score_tau for v in values], dtype=np.float64)
        else:
            t = np.array([v.mean_capture.mean for v in values], dtype=np.float64)
            score = np.maximum(0.0, 1.0 - np.where(np.isfinite(t), t, cfg.t_max) / cfg.capture_time_norm)
        estimated = np.array([v.estimate is not None for v in values], dtype=bool)
        if inverse is not None:
            removed, score, estimated = removed[inverse], score[inverse], estimated[inverse]
        return removed, score, estimated

    def rates(self, n_p: np.ndarray, n_e: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        """The expected outcome of games per unit of intruder mass (lookup, its interpolations counted).

        n_p, n_e: (k,) int team sizes, n_p >= 1 -> (removed: (k,) float64, score: (k,)
        float64, estimates: int the interpolated answers); see lookup.
        """
        removed, score, estimated = self.lookup(n_p, n_e)
        return removed, score, int(estimated.sum())

    def engage_many(self, D: np.ndarray, I: np.ndarray) -> Engagements:
        """The engagements of B episodes' densities, answered with one lookup (none without any).

        D, I: (B, N^2) float64 the defenders and the intruders after their advance -> Engagements;
        an episode's cells are those engaged() gives it alone, in the same order.
        """
        B, cells = D.shape
        n_p = np.rint(D * self.config.n_defenders)
        flat = np.flatnonzero((n_p >= 1) & (I > self.config.engage_min_mass))
        episode, cell = np.divmod(flat, cells)
        n_p, n_e = team_sizes(self.config, D.reshape(-1)[flat], I.reshape(-1)[flat])
        if len(flat):
            removed, score, estimated = self.lookup(n_p, n_e)
        else:
            removed, score, estimated = np.zeros(0), np.zeros(0), np.zeros(0, dtype=bool)
        return Engagements(episode, cell, np.bincount(episode, minlength=B), n_p, n_e, removed, score, estimated)

    def engage(self, D: np.ndarray, I: np.ndarray) -> Engagement:
        """The engagements of densities D, I: (N^2,) float64 (the intruders after their advance)."""
        e = self.engage_many(np.asarray(D)[None], np.asarray(I)[None])
        return Engagement(e.cells, e.n_p, e.n_e, e.removed, e.score, int(e.estimated.sum()))
