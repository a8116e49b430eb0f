"""The planners' shared core: what every planner of farm.alloc.policies.planners builds on.

action_from_probabilities (the action that realises wanted move probabilities),
advance_matrix (the intruders' advance as a linear map), Levels and levels() (the games
a target cell's defender count can play), the option checks, _Planner (the base class:
the grid, predict(), Intercept's rule that every planner's unused mass follows) and
_Rates (the capture-time statistics, one client call per batch and kept).

Every density is a vector over the N x N cells in cell order, c = row * N + col; a
defender count is a density times n_defenders.
"""

from __future__ import annotations

import inspect
import math

import numpy as np

from farm.alloc.config import AllocConfig
from farm.alloc.env import moves
from farm.alloc.model import LATTICE, EngagementModel, advance_intruders, snap_many
from farm.core.errors import ConfigError, InputError

__all__ = ["Levels", "levels", "action_from_probabilities", "advance_matrix"]

_TINY = 1e-9  # a defender count below this is no mass


# ----------------------------------------------------------------------------- shared helpers
def action_from_probabilities(config: AllocConfig, p: np.ndarray, start: np.ndarray, src: np.ndarray) -> np.ndarray:
    """The action that the config's action_map turns back into the move probabilities p.

    p: (A,) float64 the wanted probability of each feasible move, in the action's order
    (farm.alloc.env.moves: src (A,) int64 each move's cell, start (N^2,) int64 each cell's
    first move), each cell's slice summing to 1 -> (A,) float32 in [-1, 1].

    `softmax`: a_i = 1 + (log p_i - log p_max) / beta, clipped at -1. The map gives back
    softmax(beta a), proportional to exp(beta) p_i / p_max, i.e. p itself, except where
    p_i < p_max exp(-2 beta): those moves get that floor (-1 is as low as the action
    goes), a share of at most (moves - 1) exp(-2 beta) of the cell's mass (3.6e-4 for 9
    moves at beta = 5). `shifted`: a = 2 p / p_max - 1, which (a + 1) / sum(a + 1) maps
    back to p exactly.
    """
    p = np.maximum(np.asarray(p, dtype=np.float64), 0.0)
    p_max = np.maximum.reduceat(p, start)[src]
    ratio = p / np.where(p_max > 0, p_max, 1.0)
    if config.action_map == "softmax":
        with np.errstate(divide="ignore"):
            a = 1.0 + np.log(ratio) / config.softmax_beta
    else:
        a = 2.0 * ratio - 1.0
    return np.clip(a, -1.0, 1.0).astype(np.float32)


def advance_matrix(n: int, drift: float) -> tuple[np.ndarray, np.ndarray]:
    """The intruders' advance as a linear map, made from farm.alloc.model.advance_intruders.

    n: the grid side N; drift: `vertical_drift`. Returns (A: (N^2, N^2) float64 with
    advance_intruders(I)[0] = A @ I, b: (N^2,) float64 with the breached mass b @ I).
    """
    k = n * n
    A, b = np.zeros((k, k)), np.zeros(k)
    for j in range(k):
        e = np.zeros(k)
        e[j] = 1.0
        A[:, j], b[j] = advance_intruders(e, n, drift)
    return A, b


class Levels:
    """The defender counts a planner chooses among at a target cell, each one game.

    sizes: (m,) int64 the games' n_p, level i + 1 playing sizes[i] (level 0 plays no
    game); lo, hi: (m,) float64 the range of real defender counts (density times
    n_defenders) that play sizes[i], kept a margin inside the rounding thresholds (hi is
    inf for the top level); zero_hi: the largest count that plays no game. Made by levels().
    """

    def __init__(self, sizes: np.ndarray, lo: np.ndarray, hi: np.ndarray, zero_hi: float):
        self.sizes, self.lo, self.hi, self.zero_hi = sizes, lo, hi, zero_hi

    def needed(self, i: int, chunk: float, have: float = 0.0) -> float:
        """The defenders to add to `have` to reach level i + 1's range, in whole chunks (at least one)."""
        return max(chunk, math.ceil((self.lo[i] - have) / chunk - 1e-9) * chunk)

    def of(self, count) -> np.ndarray:
        """The levels of real defender counts: (k,) float64 -> (k,) int64 (0: no game, i + 1: sizes[i])."""
        return np.searchsorted(self.lo, np.asarray(count, dtype=np.float64), side="right")


def levels(config: AllocConfig) -> Levels:
    """The config's levels (Levels): the games a target cell's defender count can play.

    `team_sizes: lattice`: every lattice size up to snap(n_defenders), its range the
    integer counts that snap to it, widened to the reals that round to those, then
    narrowed by the margin. `exact`: the lattice sizes up to n_defenders, each priced as
    its own game and ranging up to the next level's size, so that a planner wanting no
    more than a level's game sends exactly its size. The margin is 0.1 defender plus,
    under the softmax map, the share 8 exp(-2 beta) of the count that may leak away: each
    range is kept that margin inside the rounding thresholds, so that the action the softmax
    map realises (which leaks a share exp(-2 beta) of a cell's mass to each move it does not
    want) still plays the planned game.
    """
    lattice = config.team_sizes == "lattice"
    top = int(snap_many(np.array([config.n_defenders]))[0]) if lattice else config.n_defenders
    sizes = np.array([s for s in LATTICE if s <= top], dtype=np.int64)
    if lattice:
        mids = np.sqrt(sizes[:-1] * sizes[1:].astype(np.float64))
        first = np.concatenate([[1], np.floor(mids).astype(np.int64) + 1]).astype(np.float64)
    else:
        first = sizes.astype(np.float64)
    last = np.append(first[1:] - 1, np.inf)
    leak = 8.0 * math.exp(-2.0 * config.softmax_beta) if config.action_map == "softmax" else 0.0
    lo = first - 0.4 + leak * first
    hi = np.where(np.isfinite(last), last + 0.4 - leak * np.where(np.isfinite(last), last, 0.0), np.inf)
    return Levels(sizes, lo, hi, 0.4)


def _positive_number(owner: str, name: str, value) -> float:
    """value as a float if it is a positive finite number (not a bool), else ConfigError naming owner.name."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(value) or value <= 0:
        raise ConfigError(f"{owner}: {name} must be a positive number, got {value!r}")
    return float(value)


def _count(owner: str, name: str, value) -> int:
    """value if it is an integer >= 1 (not a bool), else ConfigError naming owner.name."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ConfigError(f"{owner}: {name} must be an integer >= 1, got {value!r}")
    return int(value)


def _flag(owner: str, name: str, value) -> bool:
    """value if it is a bool, else ConfigError naming owner.name."""
    if not isinstance(value, bool):
        raise ConfigError(f"{owner}: {name} must be true or false, got {value!r}")
    return value


class _Planner:
    """The shared part of the planners: the grid, predict(), Intercept's rule, option checks.

    config: AllocConfig; client: a CaptureTimeClient of config.game_settings(), or None
    for a planner that asks no statistics; unknown: the options no keyword took. Each
    planner names its options as keywords of its __init__; an unknown one is a
    ConfigError naming it. The class's signature leaves the catch-all out, so that
    inspect.signature(cls).bind (the suite's check of planner_options) refuses it too.
    """

    name = "planner"

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        sig = inspect.signature(cls.__init__)
        params = [p for p in list(sig.parameters.values())[1:] if p.kind is not inspect.Parameter.VAR_KEYWORD]
        cls.__signature__ = sig.replace(parameters=params)

    def __init__(self, config: AllocConfig, client, unknown: dict, ties: str = "split"):
        if unknown:
            allowed = [p for p in inspect.signature(type(self)).parameters if p not in ("config", "client")]
            raise ConfigError(f"{self.name}: unknown option {sorted(unknown)[0]!r} "
                              f"(options: {', '.join(allowed) or 'none'})")
        if not isinstance(config, AllocConfig):
            raise ConfigError(f"{self.name}: config must be an AllocConfig, got {type(config).__name__}")
        if ties not in ("split", "largest"):
            raise ConfigError(f"{self.name}: ties must be 'split' or 'largest', got {ties!r}")
        self.config, self.client, self.ties = config, client, ties
        n = config.grid_size
        self.n = n
        self.src, self.dst, self.start = moves(n)
        self.ends = np.append(self.start[1:], len(self.src))  # (N^2,) int64 each cell's slice's end
        rc = np.stack(divmod(np.arange(n * n), n), axis=1)  # (N^2, 2) each cell's (row, col)
        self.cheb = np.abs(rc[:, None, :] - rc[None, :, :]).max(axis=2)  # (N^2, N^2) king-move distances
        step = rc[None, :, :] + np.sign(rc[:, None, :] - rc[None, :, :])  # [g, s]: one step from s towards g
        self.toward = (step[..., 0] * n + step[..., 1]).T  # (N^2, N^2) [s, g]
        self.A, self.breach = advance_matrix(n, config.vertical_drift)
        # rows: unit mass at (r, 1) lands in column 0 spread over the rows as R[:, r]
        R1 = self.A.reshape(n, n, n, n)[:, 0, :, 1]
        R, expected = np.eye(n), np.zeros((n, n))
        for k in range(n):
            expected[k] = np.arange(n) @ R
            R = R1 @ R
        self.expected_row = np.floor(expected + 0.5).astype(np.int64)  # [k, r]: the mass of row r, k steps on

    def plan_on_rates(self, estimates) -> None:
        """For a planner that prices engagements: check `estimates` (a bool option) and the
        client (it needs one), then set estimates, levels (levels()) and rates (_Rates)."""
        self.estimates = _flag(self.name, "estimates", estimates)
        if self.client is None:
            raise ConfigError(f"{self.name}: needs a capture-time client, got client=None")
        self.levels = levels(self.config)
        self.rates = _Rates(self.config, self.client, self.estimates)

    # ----- the interface -----------------------------------------------------------
    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        """The action for an observation, as a trained SB3 model's predict() returns it.

        obs: (2 N^2,) float32 [D, I] -> (action: (A,) float32 in [-1, 1], state). state is
        passed through; episode_start and deterministic are accepted and unused (the
        planners are deterministic: the same obs gets the same action, whatever came
        before). Raises farm.core.errors.InputError for an obs of another shape or not finite.
        """
        obs = np.asarray(obs, dtype=np.float64)
        k = self.n * self.n
        if obs.shape != (2 * k,) or not np.all(np.isfinite(obs)):
            raise InputError(f"obs: expected shape ({2 * k},) of finite numbers [D, I], got shape {obs.shape}", field="obs")
        D, I = np.maximum(obs[:k], 0.0), np.maximum(obs[k:], 0.0)
        return action_from_probabilities(self.config, self.probabilities(D, I), self.start, self.src), state

    def probabilities(self, D: np.ndarray, I: np.ndarray) -> np.ndarray:
        """The wanted move probabilities: D, I: (N^2,) float64 -> (A,) float64, each cell's slice summing to 1."""
        raise NotImplementedError

    # ----- Intercept's rule, which every planner's unused mass follows ------------------
    def meetings(self, I: np.ndarray) -> np.ndarray:
        """Where each cell's defenders go to meet intruder mass earliest (Intercept's rule).

        I: (N^2,) float64 -> share: (N^2, N^2) float64, share[s, g] the part of cell s's
        defenders heading for meeting cell g (each row sums to 1; a cell that can meet
        nobody has share[s, s] = 1). The intruders of cell j (row r, column c) are k steps
        on in column c - k (k = 1..c: the advance is known) and, under drift, in their
        expected row; cell s meets them at step k if that cell is within k king moves of
        s. Each cell takes its smallest such k, and the intruder cells it meets then:
        `ties: split` shares its mass among them in proportion to their intruder mass,
        `largest` sends it all to the largest (then the lowest cell).
        """
        n, n2 = self.n, self.n * self.n
        share = np.zeros((n2, n2))
        J = np.flatnonzero(I > self.config.engage_min_mass)
        if len(J) == 0 or n < 2:
            share[np.arange(n2), np.arange(n2)] = 1.0
            return share
        r, c = divmod(J, n)
        steps = np.arange(1, n)[:, None]  # (K, 1)
        cells = self.expected_row[steps, r[None, :]] * n + np.maximum(c[None, :] - steps, 0)  # (K, m)
        ok = (c[None, :] - steps >= 0)[None] & (self.cheb[:, cells] <= steps[None])  # (N^2, K, m)
        has = ok.any(axis=(1, 2))
        k_first = np.argmax(ok.any(axis=2), axis=1)  # (N^2,) the earliest step index
        met = ok[np.arange(n2), k_first]  # (N^2, m)
        weight = np.where(met, I[J][None, :], 0.0)
        if self.ties == "largest":
            weight = np.eye(len(J))[np.argmax(weight, axis=1)] * met
        weight = weight / np.maximum(weight.sum(axis=1, keepdims=True), 1e-300)
        goal = cells[k_first]  # (N^2, m) the meeting cells at each cell's earliest step
        s_idx = np.repeat(np.arange(n2), len(J))
        np.add.at(share, (s_idx, goal.reshape(-1)), weight.reshape(-1))
        share[~has] = 0.0
        share[np.flatnonzero(~has), np.flatnonzero(~has)] = 1.0
        return share

    def intercept_probabilities(self, I: np.ndarray) -> np.ndarray:
        """Intercept's move probabilities: I: (N^2,) float64 -> (A,) float64; each part of a cell's
        mass takes the one move towards its meeting cell (a step per coordinate; on it: stay)."""
        share = self.meetings(I)
        s, g = np.nonzero(share)
        p = np.zeros(len(self.src))
        np.add.at(p, self.move_index(s, self.toward[s, g]), share[s, g])
        return p

    def move_index(self, s, d) -> np.ndarray:
        """The action index of the moves s -> d: (k,) int64 cells each (d = s or a neighbour) -> (k,) int64."""
        s, d = np.asarray(s), np.asarray(d)
        n = self.n
        r, c = divmod(s, n)
        lo_r, lo_c, hi_c = np.where(r > 0, -1, 0), np.where(c > 0, -1, 0), np.where(c < n - 1, 1, 0)
        # a cell's slice is row-major over the (d_row, d_col) inside the grid
        return self.start[s] + (d // n - r - lo_r) * (hi_c - lo_c + 1) + (d % n - c - lo_c)

    def place(self, x: np.ndarray, flows: np.ndarray, I: np.ndarray, keep) -> np.ndarray:
        """Move probabilities from planned flows, the unplanned mass following Intercept.

        x: (N^2,) float64 each cell's defender count; flows: (A,) float64 the defenders
        planned along each move; I: (N^2,) float64 the intruders; keep(s, d, amount) ->
        bool: whether unplanned mass may land on d (else it goes to the neighbour of s
        nearest d that keep accepts, staying on d if none does). Returns (A,) float64, each
        cell's slice summing to 1 (a cell without mass follows Intercept).
        """
        flows = np.maximum(flows, 0.0)
        rest = np.maximum(x - np.add.reduceat(flows, self.start), 0.0)
        p_int = self.intercept_probabilities(I)
        f = flows.copy()
        for a in np.flatnonzero((p_int > 0) & (rest[self.src] > _TINY)):
            s, d = int(self.src[a]), int(self.dst[a])
            amount = rest[s] * p_int[a]
            if not keep(s, d, amount):
                nbrs = sorted(self.dst[self.start[s]:self.ends[s]].tolist(), key=lambda c: (self.cheb[c, d], c))
                d = next((c for c in nbrs if c != d and keep(s, c, amount)), d)
            f[self.move_index(s, d)] += amount
        f += p_int * (x <= _TINY)[self.src]
        return f / np.add.reduceat(f, self.start)[self.src]


class _Rates:
    """The capture-time statistics a planner needs, one client call per batch
    (EngagementModel.rates; the client's memo answers a pair it has seen without a call)."""

    def __init__(self, config: AllocConfig, client, estimates: bool):
        self.model = EngagementModel(config, client, estimates)

    def get(self, n_p, n_e) -> tuple[np.ndarray, np.ndarray]:
        """(removed, score): (k,) float64 each, of the games n_p, n_e: (k,) int (n_p >= 1)."""
        removed, score, _ = self.model.rates(np.asarray(n_p).reshape(-1), np.asarray(n_e).reshape(-1))
        return removed, score

    def grid(self, sizes: np.ndarray, n_e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(removed, score): (len(n_e), len(sizes)) float64 each, every size against every n_e."""
        P, E = np.meshgrid(sizes, n_e)
        removed, score = self.get(P.reshape(-1), E.reshape(-1))
        return removed.reshape(P.shape), score.reshape(P.shape)
