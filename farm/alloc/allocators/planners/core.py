"""The planners' shared core: what every planner of farm.alloc.allocators.planners builds on.

action_from_probabilities (the action that realises wanted move probabilities),
advance_matrix (the intruders' advance as a linear map), plan_horizon, Levels and levels()
(the games a target cell's defender count can play), the option checks, _Planner (the base
class: the grid, predict(), Intercept's rule that every planner's unused mass follows, and
the level programs of receding_horizon and minimax: flow_network, solve_levels, first_step)
and _Rates (the capture-time statistics, one client call per batch and kept).

Every density is a vector over the N x N cells in cell order, c = row * N + col; a
defender count is a density times n_defenders.
"""

from __future__ import annotations

import inspect
import math

import numpy as np

from farm.alloc.game.config import AllocConfig
from farm.alloc.game.dynamics import moves
from farm.alloc.game.model import LATTICE, EngagementModel, advance_intruders, snap_many
from farm.core.checks import is_positive, is_whole
from farm.core.errors import ConfigError, InputError

__all__ = ["Levels", "levels", "action_from_probabilities", "advance_matrix", "plan_horizon"]

_TINY = 1e-9  # a defender count below this is no mass


# ----------------------------------------------------------------------------- shared helpers
def action_from_probabilities(config: AllocConfig, p: np.ndarray, start: np.ndarray, src: np.ndarray) -> np.ndarray:
    """The action that the config's action_map turns back into the move probabilities p.

    p: (A,) float64 the wanted probability of each feasible move, in the action's order
    (farm.alloc.envs.defenders.moves: src (A,) int64 each move's cell, start (N^2,) int64 each cell's
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
    """The intruders' advance as a linear map, made from farm.alloc.game.model.advance_intruders.

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


def plan_horizon(config: AllocConfig, I: np.ndarray, horizon: int | None) -> int:
    """The steps a planner of `horizon` steps (None: no limit) plans for intruders I: (N^2,) float64.

    0 without intruders. Else until the intruders now on the grid have breached (the
    right-most column holding intruders, plus one), never past max_steps (the steps taken
    are read from that column: the intruders start in the right-most one), and at most
    `horizon`; at least 1.
    """
    n = config.grid_size
    cols = np.flatnonzero(np.asarray(I).reshape(n, n).max(axis=0) > config.engage_min_mass)
    if len(cols) == 0:
        return 0
    c_max = int(cols[-1])
    left = config.max_steps - (n - 1 - c_max)
    return max(1, min(horizon or c_max + 1, c_max + 1, left))


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
    if not is_positive(value):
        raise ConfigError(f"{owner}: {name} must be a positive number, got {value!r}")
    return float(value)


MAX_PLANS = 100  # a planner's iterations or rounds a step at most: each is a program solved a step


def _count(owner: str, name: str, value, minimum: int = 1, maximum: int | None = None) -> int:
    """value if it is an integer >= minimum (and <= maximum, when given; not a bool), else
    ConfigError naming owner.name."""
    if not is_whole(value) or value < minimum:
        raise ConfigError(f"{owner}: {name} must be an integer >= {minimum}, got {value!r}")
    if maximum is not None and value > maximum:
        raise ConfigError(f"{owner}: {name} must be an integer from {minimum} to {maximum} (each is a program "
                          f"solved every step), got {value!r}")
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
        """The action for an observation, as a trained SB3 model's predict method returns it.

        obs: (2 N^2,) float32 [D, I] -> (action: (A,) float32 in [-1, 1], state). state is
        passed through; episode_start and deterministic are accepted and unused (the
        planners are deterministic: the same obs gets the same action, whatever came
        before). Raises farm.core.errors.InputError for an obs of another shape or not finite.
        """
        obs = np.asarray(obs, dtype=np.float64)
        k = self.n * self.n
        if obs.shape != (2 * k,) or not np.all(np.isfinite(obs)):
            raise InputError(f"obs: expected shape ({2 * k},) of finite numbers [D, I], got shape {obs.shape}",
                             field="obs")
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


    # ----- the level programs (receding_horizon, minimax) ----------------------------
    def flow_network(self, x: np.ndarray, target: np.ndarray):
        """A program over a time-expanded network of the defenders' mass, a level chosen at each target.

        x: (N^2,) float64 the defender counts now; target: (H+1, N^2) bool the (step, cell)s
        where intruders may be engaged (row 0 unused). Nodes (k, cell) for k = 0..H hold the
        mass after k steps; edges are the feasible moves of each step; the defenders start
        where x has them. A target's inflow chooses one level (levels(): one-hot variables,
        each level's count range enforced on the inflow). Only what can matter is in the
        program: nodes reachable from the defenders that can still reach a target; mass may
        leave the program only through a move to a cell outside it (never a target).

        None when no defender can reach a target. Else a dict: targets (T, 2) int64 (step,
        cell); T; m (the levels); edges (E, 3) int64 (step, from, to); E; matrix, lb, ub (the
        constraints: conservation, then per target the one-hot row and the inflow's range);
        upper (E + T (m + 1),) float64 the variables' upper bounds; inflow (T, E) sparse;
        first (E,) bool the first step's edges and first_moves their action indices.
        """
        from scipy import sparse

        n2, L = self.n * self.n, self.levels
        H = len(target) - 1
        target = np.asarray(target, dtype=bool).copy()
        target[0] = False

        def dilate(mask):
            return np.bincount(self.src, weights=mask[self.dst].astype(float), minlength=n2) > 0

        reach = np.zeros((H + 1, n2), dtype=bool)
        reach[0] = x > _TINY
        for k in range(1, H + 1):
            reach[k] = dilate(reach[k - 1])
        useful = np.zeros_like(reach)
        useful[H] = target[H]
        for k in range(H - 1, -1, -1):
            useful[k] = target[k] | dilate(useful[k + 1])
        node = reach & useful
        tk, tc = np.nonzero(node & target)
        if len(tk) == 0:
            return None
        T, m = len(tk), len(L.sizes)
        edges = np.concatenate([np.stack([np.full(int(sel.sum()), k), self.src[sel], self.dst[sel]], axis=1)
                                for k in range(1, H + 1)
                                for sel in [node[k - 1][self.src] & node[k][self.dst]]]).astype(np.int64)
        E = len(edges)
        node_id = np.full((H + 1, n2), -1)
        node_id[node] = np.arange(int(node.sum()))
        out_node = node_id[edges[:, 0] - 1, edges[:, 1]]
        in_node = node_id[edges[:, 0], edges[:, 2]]
        n_nodes = int(node.sum())
        # conservation, one row per node with outgoing edges: out - in <= 0 (x at step 0); = when closed
        outs = np.bincount(out_node, minlength=n_nodes)
        rows_of = np.full(n_nodes, -1)
        has_out = np.flatnonzero(outs > 0)
        rows_of[has_out] = np.arange(len(has_out))
        e_idx = np.arange(E)
        in_row = rows_of[in_node]
        rows = [rows_of[out_node], in_row[in_row >= 0]]
        cols = [e_idx, e_idx[in_row >= 0]]
        vals = [np.ones(E), -np.ones(int((in_row >= 0).sum()))]
        node_k, node_c = np.nonzero(node)
        n_moves = self.ends - self.start
        closed = outs[has_out] == n_moves[node_c[has_out]]
        rhs = np.where(node_k[has_out] == 0, x[node_c[has_out]], 0.0)
        lb = [np.where(closed, rhs, -np.inf)]
        ub = [rhs]
        r0 = len(has_out)
        # targets: one-hot; inflow - sum lo z >= 0; inflow - sum hi z <= 0
        cap = np.array([x[self.cheb[c] <= k].sum() for k, c in zip(tk, tc, strict=True)])  # the most a target can get
        lo = np.concatenate([[0.0], L.lo])
        t_of = np.full((H + 1, n2), -1)
        t_of[tk, tc] = np.arange(T)
        e_t = t_of[edges[:, 0], edges[:, 2]]
        into = np.flatnonzero(e_t >= 0)
        z = E + np.arange(T * (m + 1)).reshape(T, m + 1)
        hi = np.concatenate([np.full((T, 1), L.zero_hi), np.minimum(L.hi[None, :], cap[:, None] + 1.0)], axis=1)
        t_rows = np.repeat(np.arange(T), m + 1)
        rows += [r0 + t_rows, r0 + T + e_t[into], r0 + T + t_rows, r0 + 2 * T + e_t[into], r0 + 2 * T + t_rows]
        cols += [z.reshape(-1), into, z.reshape(-1), into, z.reshape(-1)]
        vals += [np.ones(T * (m + 1)), np.ones(len(into)), -np.tile(lo, T), np.ones(len(into)), -hi.reshape(-1)]
        lb += [np.ones(T), np.zeros(T), np.full(T, -np.inf)]
        ub += [np.ones(T), np.full(T, np.inf), np.zeros(T)]
        matrix = sparse.csr_array((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                  shape=(r0 + 3 * T, E + T * (m + 1)))
        upper = np.full(E + T * (m + 1), np.inf)
        fillable = np.concatenate([np.ones((T, 1)), lo[None, 1:] <= cap[:, None] + 1e-9], axis=1)
        upper[E:] = fillable.reshape(-1)
        first = edges[:, 0] == 1
        inflow = sparse.csr_array((np.ones(len(into)), (e_t[into], into)), shape=(T, E))
        return {"targets": np.stack([tk, tc], axis=1), "T": T, "m": m, "edges": edges, "E": E, "matrix": matrix,
                "lb": np.concatenate(lb), "ub": np.concatenate(ub), "upper": upper, "inflow": inflow,
                "first": first, "first_moves": self.move_index(edges[first, 1], edges[first, 2])}

    def solve_levels(self, net, V: np.ndarray, exact: bool, rounds: int, time_limit: float, extra=None):
        """Maximise the targets' level values over a flow_network, by branch and bound or relax-and-fix.

        V: (T, m + 1) float64 each target's levels' values (column 0: no game). extra: None,
        or more continuous variables and rows, a dict: c (q,) float64 their values (added to
        the objective), rows (r, E + T (m + 1) + q) sparse, lb, ub (r,) float64, lower,
        upper (q,) float64 their bounds. exact: HiGHS's branch and bound
        (scipy.optimize.milp, time_limit seconds, then its best plan); else the LP
        relaxation (a target's value the concave envelope of its levels' values) rounded by
        relax-and-fix: every target whose levels come out mixed is fixed at the highest
        level its planned inflow fills, the others may only go up, and the LP is solved
        again; after `rounds` rounds every target is fixed (a fix that leaves no feasible
        plan is undone and the target capped there instead). Counts the programs solved in
        self.last["programs"] when self.last has it.

        Returns (choice: (T,) int64 the chosen levels, flows: (E,) float64, y: (q,) float64
        the extra variables) or (None, None, None) when no plan was found.
        """
        from scipy import sparse
        from scipy.optimize import Bounds, LinearConstraint, milp

        E, m, T = net["E"], net["m"], net["T"]
        q = 0 if extra is None else len(extra["c"])
        objective = np.concatenate([V.reshape(-1), [] if extra is None else extra["c"]])
        c = np.concatenate([np.zeros(E), -objective / max(float(np.abs(objective).max()), 1e-300)])
        matrix, lb, ub = net["matrix"], net["lb"], net["ub"]
        if extra is not None:
            matrix = sparse.vstack([sparse.hstack([matrix, sparse.csr_array((matrix.shape[0], q))]),
                                    sparse.csr_array(extra["rows"])], format="csr")
            lb, ub = np.concatenate([lb, extra["lb"]]), np.concatenate([ub, extra["ub"]])
        constraints = LinearConstraint(matrix, lb, ub)
        integrality = np.concatenate([np.zeros(E), np.full(T * (m + 1), 1 if exact else 0), np.zeros(q)])
        lower = np.concatenate([np.zeros(E + T * (m + 1)), [] if extra is None else extra["lower"]])
        upper = np.concatenate([net["upper"], [] if extra is None else extra["upper"]])
        lo = np.concatenate([[0.0], self.levels.lo])
        fixed = np.zeros(T, dtype=bool)
        undo, done = None, 0
        options = {"time_limit": time_limit, "mip_rel_gap": 0.0} if exact else {"presolve": False}
        z0 = E  # the level variables' offset
        while True:
            res = milp(c, constraints=constraints, integrality=integrality, bounds=Bounds(lower, upper),
                       options=options)
            if "programs" in getattr(self, "last", {}):
                self.last["programs"] += 1
            if res.x is None:
                if undo is None:
                    return None, None, None
                lower, upper, fixed, just_fixed = undo  # cap the targets just fixed instead
                for i, a in just_fixed:
                    upper[z0 + i * (m + 1) + a + 1: z0 + (i + 1) * (m + 1)] = 0.0
                undo = None
                continue
            zs = res.x[z0:z0 + T * (m + 1)].reshape(T, m + 1)
            mixed = (zs.max(axis=1) < 1 - 1e-6) & ~fixed
            if exact or not mixed.any():
                return np.argmax(zs, axis=1), res.x[:E], res.x[E + T * (m + 1):]
            done += 1
            inflow = net["inflow"] @ res.x[:E]
            undo = (lower.copy(), upper.copy(), fixed.copy(), [])
            if done >= rounds:
                mixed = ~fixed  # the last round fixes every target
            else:
                for i in np.flatnonzero(~mixed & ~fixed):  # whole levels may only go up
                    upper[z0 + i * (m + 1): z0 + i * (m + 1) + int(np.argmax(zs[i]))] = 0.0
            for i in np.flatnonzero(mixed):
                allowed = np.flatnonzero(upper[z0 + i * (m + 1): z0 + (i + 1) * (m + 1)] > 0)
                filled = allowed[lo[allowed] <= inflow[i] + 1e-9]
                a = int(filled.max()) if len(filled) else int(allowed.min())
                upper[z0 + i * (m + 1): z0 + (i + 1) * (m + 1)] = 0.0
                upper[z0 + i * (m + 1) + a] = lower[z0 + i * (m + 1) + a] = 1.0
                fixed[i] = True
                undo[3].append((i, a))

    def first_step(self, x: np.ndarray, net, flows: np.ndarray, I: np.ndarray) -> np.ndarray:
        """The move probabilities of a plan's first step: (A,) float64 (place()).

        x: (N^2,) float64 the defender counts; net: the plan's flow_network; flows: (E,)
        float64 its edges' flows; I: (N^2,) float64 the intruders. The first step's planned
        flows are kept; the mass the plan does not use moves as Intercept would, landing on a
        first step's target only where that leaves the target's game the planned one.
        """
        first = np.zeros(len(self.src))
        np.add.at(first, net["first_moves"], flows[net["first"]])
        count = np.bincount(self.dst, weights=first, minlength=len(x))
        on_target = set(net["targets"][net["targets"][:, 0] == 1, 1].tolist())

        def keep(s, d, amount):  # on a first-step target only when its game stays the planned one
            if d in on_target and self.levels.of([count[d] + amount])[0] != self.levels.of([count[d]])[0]:
                return False
            count[d] += amount
            return True

        return self.place(x, first, I, keep)


class _Rates:
    """The capture-time statistics a planner needs, one client call per batch
    (EngagementModel.rates; the client's memo answers a pair it has seen without a call)."""

    def __init__(self, config: AllocConfig, client, estimates: bool):
        self.model = EngagementModel(config, client, estimates)
        self._keys = np.zeros(0, dtype=np.int64)  # the n_e of table(), ascending, and their rows
        self._removed = self._score = None
        self._sizes = None

    def get(self, n_p, n_e) -> tuple[np.ndarray, np.ndarray]:
        """(removed, score): (k,) float64 each, of the games n_p, n_e: (k,) int (n_p >= 1)."""
        removed, score, _ = self.model.rates(np.asarray(n_p).reshape(-1), np.asarray(n_e).reshape(-1))
        return removed, score

    def grid(self, sizes: np.ndarray, n_e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(removed, score): (len(n_e), len(sizes)) float64 each, every size against every n_e."""
        P, E = np.meshgrid(sizes, n_e)
        removed, score = self.get(P.reshape(-1), E.reshape(-1))
        return removed.reshape(P.shape), score.reshape(P.shape)

    def table(self, sizes: np.ndarray, n_e) -> tuple[np.ndarray, np.ndarray]:
        """(removed, score): n_e.shape + (len(sizes),) float64 each, every size against each
        n_e (int array of any shape). The rows are kept: only the n_e not asked before are
        asked (one grid()); sizes must be the same at every call."""
        n_e = np.asarray(n_e, dtype=np.int64)
        sizes = np.asarray(sizes, dtype=np.int64)
        if self._sizes is None:
            self._sizes = sizes.copy()
            self._removed = self._score = np.zeros((0, len(sizes)))
        elif not np.array_equal(sizes, self._sizes):
            raise ValueError("_Rates.table: sizes differ from the first call's")
        new = np.setdiff1d(n_e, self._keys)
        if len(new):
            removed, score = self.grid(sizes, new)
            keys = np.concatenate([self._keys, new])
            order = np.argsort(keys)
            self._keys = keys[order]
            self._removed = np.concatenate([self._removed, removed])[order]
            self._score = np.concatenate([self._score, score])[order]
        at = np.searchsorted(self._keys, n_e)
        return self._removed[at], self._score[at]
