"""The N x N grid allocation MDP (paper section 3, docs/model.md section 5) as a gymnasium env.

State: defenders' density D (sums to 1) and intruders' density I (sums to the
surviving fraction) over cells c = row * N + col. Observation [D, I], float32.
Action: one number in [-1, 1] per feasible move (stay or one of the 8
neighbours inside the grid), cell by cell in cell order, moves in row-major
(d_row, d_col) order; each cell's slice maps to a probability row:
  softmax:  p = softmax(beta * a)              (default, beta = 5)
  shifted:  p = (a + 1) / sum(a + 1)           (uniform when all are -1)
giving a column-stochastic T (column j: where cell j's defenders go; infeasible
moves exactly 0), and D' = T D.
A step (step_seconds of game time, under engagement v2 the time an intruder needs
to cross a cell): defenders move; intruders drift vertically (optional) and
advance one column left, the mass leaving the left edge breaching; then every
cell holding both sides is engaged: n_p = round(D_c N_def) >= 1,
n_e = max(1, round(I_c N_int)), and the capture-time service's expected fraction
of intruders captured within the window tau removes that share of the cell's
intruders (under v2 the games are pure pursuit against intruders heading for the
exit, which they escape through; escaped intruders go on with the column's
advance, never counted as eliminated). Reward:
  R = -c_distribution * sum(I) + c_capture * sum_c I_c max(0, 1 - t_c / capture_time_norm)
      - breach_penalty * (mass breached this step),
t_c the mean capture time of the cell's game (t_max when nobody is caught);
capture_time_norm is tau under v2. See farm.alloc.config for the two models.
"""

from __future__ import annotations

import logging

import gymnasium as gym
import numpy as np

from farm.alloc.config import AllocConfig

log = logging.getLogger(__name__)

LATTICE = (1, 2, 3, 4, 6, 8, 12, 16, 24, 32, 48, 64, 96, 128, 192, 256)


def moves(n: int):
    """Feasible moves of an n x n grid: src (A,), dst (A,) int64 cell indices and
    start (n*n,) int64 offset of each cell's slice in the action vector."""
    src, dst, start = [], [], []
    for r in range(n):
        for c in range(n):
            start.append(len(src))
            for dr in (-1, 0, 1):
                for dc in (-1, 0, 1):
                    rr, cc = r + dr, c + dc
                    if 0 <= rr < n and 0 <= cc < n:
                        src.append(r * n + c)
                        dst.append(rr * n + cc)
    return np.array(src), np.array(dst), np.array(start)


def n_actions(n: int) -> int:
    return 4 * 4 + 6 * 4 * (n - 2) + 9 * (n - 2) ** 2


_LATTICE = np.array(LATTICE)
_LATTICE_MIDS = np.sqrt(_LATTICE[:-1] * _LATTICE[1:])  # geometric midpoints: never an integer


def snap_many(x: np.ndarray) -> np.ndarray:
    """(k,) int team sizes -> (k,) int64: the nearest lattice size of each in log
    scale (team_sizes: lattice); at a midpoint the smaller would win, but no
    integer is one."""
    return _LATTICE[np.searchsorted(_LATTICE_MIDS, x)]


def snap(x: int) -> int:
    """snap_many for one team size."""
    return int(snap_many(np.asarray([x]))[0])


class SwarmAllocationEnv(gym.Env):
    metadata = {"render_modes": ["rgb_array"], "render_fps": 2}

    def __init__(self, config: AllocConfig | None = None, *, client=None, store: str | None = None,
                 render_mode: str | None = None, estimates: bool = False, **kwargs):
        """config or keyword arguments (AllocConfig fields); client: a
        CaptureTimeClient, else an in-process one over `store` (default: the user's store,
        farm.service.store.default_store_path(), logged at INFO); estimates: answer a
        first visit of a team-size pair with the service's interpolation of its computed
        neighbours while the exact value is computed in the background (counted in
        info["estimates"]); otherwise wait for the exact value."""
        self.estimates = estimates
        self.engagements = 0  # engaged cells answered by the service, over the env's lifetime
        self.estimated = 0  # of which by an interpolation (estimates=True)
        self.config = config or AllocConfig(**kwargs)
        cfg = self.config
        n = cfg.grid_size
        self.n = n
        self.src, self.dst, self.start = moves(n)
        self.n_moves = np.diff(np.append(self.start, len(self.src)))
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(len(self.src),), dtype=np.float32)
        self.observation_space = gym.spaces.Box(0.0, 1.0, shape=(2 * n * n,), dtype=np.float32)
        self.render_mode = render_mode
        if client is None:
            from farm.service import CaptureTimeClient
            from farm.service.store import default_store_path

            if store is None:
                store = default_store_path()
                log.info("capture-time store: %s", store)
            client = CaptureTimeClient(self.config.service_settings(), local_store=store)
        self.client = client
        self.base = (n // 2) * n
        self.D = np.zeros(n * n)
        self.I = np.zeros(n * n)
        self.steps = 0
        self.breached = 0.0

    # ----- the MDP ------------------------------------------------------------------
    def move_probabilities(self, action: np.ndarray) -> np.ndarray:
        """action (A,) -> p (A,) float64, each cell's slice summing to 1."""
        a = np.minimum(np.maximum(np.asarray(action, dtype=np.float64), -1.0), 1.0)
        if self.config.action_map == "softmax":
            z = self.config.softmax_beta * a
            z = z - np.maximum.reduceat(z, self.start)[self.src]
            w = np.exp(z)
        else:
            w = a + 1.0
        total = np.add.reduceat(w, self.start)
        uniform = total <= 0
        total = np.where(uniform, 1.0, total)
        p = w / total[self.src]
        if uniform.any():
            p = np.where(uniform[self.src], 1.0 / self.n_moves[self.src], p)
        return p

    def transition_matrix(self, action: np.ndarray) -> np.ndarray:
        """(N^2, N^2) float64, column j: where cell j's defenders go."""
        T = np.zeros((self.n * self.n, self.n * self.n))
        T[self.dst, self.src] = self.move_probabilities(action)
        return T

    def _advance_intruders(self) -> float:
        n, d = self.n, self.config.vertical_drift
        grid = self.I.reshape(n, n)
        if d > 0:
            up = d * grid[1:]
            down = d * grid[:-1]
            grid = grid.copy()
            grid[1:] -= up
            grid[:-1] += up
            grid[:-1] -= down
            grid[1:] += down
        breach = float(grid[:, 0].sum())
        moved = np.zeros_like(grid)
        moved[:, :-1] = grid[:, 1:]
        self.I = moved.reshape(-1)
        return breach

    def _engage(self):
        """Every cell holding both sides plays its game; returns (capture score, mass
        eliminated, engaged cells, estimated answers, coverage, defenders per engaged cell)."""
        cfg = self.config
        n_p = np.rint(self.D * cfg.n_defenders).astype(np.int64)
        total = float(self.I.sum())
        cells = np.flatnonzero((n_p >= 1) & (self.I > cfg.engage_min_mass))
        if len(cells) == 0:
            return 0.0, 0.0, 0, 0, 0.0, 0.0
        coverage = float(self.I[cells].sum()) / total if total > 0 else 0.0
        n_e = np.maximum(1, np.rint(self.I[cells] * cfg.n_intruders).astype(np.int64))
        n_p = n_p[cells]
        if cfg.team_sizes == "lattice":
            n_p, n_e = snap_many(n_p), snap_many(n_e)
        pairs = list(zip(n_p.tolist(), n_e.tolist()))
        values = self.client.get_many(pairs, estimate=self.estimates)
        frac = np.array([v.frac_captured_tau for v in values])
        t = np.array([v.mean_capture.mean for v in values], dtype=np.float64)
        t = np.where(np.isfinite(t), t, cfg.t_max)
        before = self.I[cells].copy()
        score = float(np.sum(before * np.maximum(0.0, 1.0 - t / cfg.capture_time_norm)))
        self.I[cells] = before * (1.0 - frac)
        estimates = sum(v.estimate is not None for v in values)
        self.engagements += len(cells)
        self.estimated += estimates
        return (score, float(np.sum(before - self.I[cells])), len(cells), estimates, coverage,
                float(np.mean(n_p)))

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        n = self.n
        self.D = np.zeros(n * n)
        self.D[self.base] = 1.0
        self.I = np.zeros(n * n)
        self.I[np.arange(n) * n + (n - 1)] = self.np_random.dirichlet(np.ones(n))
        self.steps = 0
        self.breached = 0.0
        self.eliminated = 0.0
        return self._obs(), self._info(0.0, 0.0, 0, 0)

    def step(self, action):
        cfg = self.config
        p = self.move_probabilities(action)
        self.D = np.bincount(self.dst, weights=p * self.D[self.src], minlength=self.n * self.n)
        breach = self._advance_intruders()
        self.breached += breach
        score, eliminated, engaged, estimates, coverage, per_cell = self._engage()
        self.eliminated += eliminated
        self.steps += 1
        remaining = float(self.I.sum())
        reward = -cfg.c_distribution * remaining + cfg.c_capture * score - cfg.breach_penalty * breach
        terminated = remaining < cfg.epsilon
        truncated = not terminated and self.steps >= cfg.max_steps
        info = self._info(breach, eliminated, engaged, estimates, coverage, per_cell)
        return self._obs(), float(reward), bool(terminated), bool(truncated), info

    def _obs(self) -> np.ndarray:
        return np.minimum(np.maximum(np.concatenate([self.D, self.I]), 0.0), 1.0).astype(np.float32)

    def _info(self, breach, eliminated, engaged, estimates, coverage=0.0, per_cell=0.0) -> dict:
        """coverage: the share of the intruder mass (after its advance) in cells with defenders
        (n_p >= 1), which are the engaged cells; defenders_per_engaged: mean n_p over them."""
        return {"breached_step": breach, "breached": self.breached, "eliminated_step": eliminated,
                "eliminated": getattr(self, "eliminated", 0.0), "engaged_cells": engaged,
                "estimates": estimates, "intruder_mass": float(self.I.sum()), "coverage": coverage,
                "defenders_per_engaged": per_cell}

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        from farm.alloc.plots import density_frame

        return density_frame(self.D.reshape(self.n, self.n), self.I.reshape(self.n, self.n), self.steps)
