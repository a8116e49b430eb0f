"""The allocation MDP's model, as functions: what the env does and what planners predict.

The env (farm.alloc.env) steps through these functions, and the planners
(farm.alloc.policies.planners) call the same ones to look ahead, so a planner's model of a
step is the env's step and never a copy that could drift from it:

- advance_intruders: the intruders' vertical drift and one-column advance (known in
  advance: it does not depend on the defenders);
- team_sizes: a cell's game, (n_p, n_e) from its densities (rounding, the lattice);
- EngagementModel: a cell's expected outcome from the capture-time client's
  statistics, the share of its intruders removed and its capture score per unit of
  intruder mass under the config's `capture_score` rule (docs/model.md section 5).

Every density is a vector over the N x N cells in cell order, c = row * N + col.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from farm.alloc.config import AllocConfig
from farm.service.keys import LATTICE

__all__ = ["LATTICE", "snap", "snap_many", "advance_intruders", "team_sizes", "Engagement", "EngagementModel"]

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


def advance_intruders(I: np.ndarray, n: int, drift: float) -> tuple[np.ndarray, float]:
    """The intruders' move of one step: vertical drift, then one column left.

    I: (N^2,) float64 intruder densities; n: the grid side N; drift: the share d of each
    row's mass sent to each neighbouring row (`vertical_drift`). Returns (I': (N^2,)
    float64 the densities after the advance, breach: float the mass that left the left
    edge). I is not changed.
    """
    grid = I.reshape(n, n)
    if drift > 0:
        up = drift * grid[1:]
        down = drift * grid[:-1]
        grid = grid.copy()
        grid[1:] -= up
        grid[:-1] += up
        grid[:-1] -= down
        grid[1:] += down
    breach = float(grid[:, 0].sum())
    moved = np.zeros_like(grid)
    moved[:, :-1] = grid[:, 1:]
    return moved.reshape(-1), breach


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


class EngagementModel:
    """A config's engagements answered by a capture-time client: the env's and the planners' model.

    config: AllocConfig; client: a CaptureTimeClient of config.service_settings();
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

    def rates(self, n_p: np.ndarray, n_e: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
        """The expected outcome of games per unit of intruder mass.

        n_p, n_e: (k,) int team sizes, n_p >= 1 -> (removed: (k,) float64 the share of the
        intruders captured within tau, score: (k,) float64 the capture score per unit of
        mass, estimates: int the interpolated answers). The score's rule is the config's
        `capture_score`: "expected", the mean over all games of each game's mean of
        max(0, 1 - t/tau) per intruder (capture_score_tau), or "conditional", max(0, 1 -
        t/capture_time_norm) with t the mean capture time of the games that caught someone
        (t_max when none did).
        """
        cfg = self.config
        pairs = list(zip(np.asarray(n_p).tolist(), np.asarray(n_e).tolist()))
        values = self.client.get_many(pairs, estimate=self.estimates)
        removed = np.array([v.frac_captured_tau for v in values], dtype=np.float64)
        if cfg.capture_score == "expected":
            score = np.array([v.capture_score_tau for v in values], dtype=np.float64)
        else:
            t = np.array([v.mean_capture.mean for v in values], dtype=np.float64)
            score = np.maximum(0.0, 1.0 - np.where(np.isfinite(t), t, cfg.t_max) / cfg.capture_time_norm)
        return removed, score, sum(v.estimate is not None for v in values)

    def engage(self, D: np.ndarray, I: np.ndarray) -> Engagement:
        """The engagements of densities D, I: (N^2,) float64 (the intruders after their advance)."""
        cells = self.engaged(D, I)
        n_p, n_e = team_sizes(self.config, D[cells], I[cells])
        if len(cells) == 0:
            empty = np.zeros(0)
            return Engagement(cells, n_p, n_e, empty, empty, 0)
        removed, score, estimates = self.rates(n_p, n_e)
        return Engagement(cells, n_p, n_e, removed, score, estimates)
