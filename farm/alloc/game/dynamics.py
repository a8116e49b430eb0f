"""One step of the allocation MDP for B episodes at once: the one definition of a step.

The single env steps through step() with B = 1 and the batched one with B episodes, so episode
k of a batch gets, to the last bit, the numbers it would get alone: every operation here is
elementwise, or a sum over one episode's entries alone (np.add.reduceat over each cell's moves,
np.bincount in entry order, farm.alloc.game.model's row_sums and segment_sums), and the engagements
of all B episodes are answered by one lookup (EngagementModel.engage_many).

Its parts: moves, n_actions, Layout (the action layout of an N x N grid; routes, the intruders');
check_actions (the refusal rule, ActionError); move_probabilities, move_defenders (the
`action_map`, D' = T D) and defenders_move (both); route_probabilities, routing_of (the
intruders' action as a routing) and intruder_routing (both); start_densities, observe,
episode_end (termination, truncation); step (StepResult: defenders_move, then resolve, the part
after the defenders' move), the pieces the intruders' env composes too.
Densities are (B, N^2) float64, one episode a row, cells in cell order c = row * N + col.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from farm.alloc.game.config import AllocConfig
from farm.alloc.game.model import EngagementModel, advance_intruders_many, route_intruders_many, row_sums, segment_sums
from farm.core.errors import ActionError

__all__ = ["moves", "routes", "n_actions", "Layout", "check_actions", "move_probabilities", "route_probabilities",
           "routing_of", "intruder_routing", "check_pure_routes", "pure_routing", "move_defenders", "defenders_move",
           "start_densities", "observe",
           "episode_end", "StepResult", "step", "resolve"]


def moves(n: int):
    """The feasible moves of an n x n grid, in the action vector's order.

    A cell may stay or move to any of its 8 neighbours inside the grid; cells come in
    cell order (c = row * n + col), each cell's moves in row-major (d_row, d_col) order.
    Returns (src, dst, start): src: (A,) int64 and dst: (A,) int64 the source and
    destination cell of each move, A = n_actions(n); start: (n*n,) int64 the offset of
    each cell's slice in the action vector.
    """
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


def routes(n: int):
    """The intruders' routes of an n x n grid, in the intruder action vector's order.

    Each cell's mass may go up-left, left or down-left (d_row -1, 0, +1; the top and bottom
    rows have two); cells in cell order. Returns (src, d_row, start): src: (R,) int64 each
    route's cell, d_row: (R,) int64 its row change, R = n (3n - 2); start: (n*n,) int64 the
    offset of each cell's slice.
    """
    src, d_row, start = [], [], []
    for r in range(n):
        for c in range(n):
            start.append(len(src))
            for dr in (-1, 0, 1):
                if 0 <= r + dr < n:
                    src.append(r * n + c)
                    d_row.append(dr)
    return np.array(src), np.array(d_row), np.array(start)


def n_actions(n: int) -> int:
    """The number of feasible moves A of an n x n grid (n >= 2): the action's length.

    Corners have 4 moves, other edge cells 6, inner cells 9: A = 4*4 + 6*4(n-2) + 9(n-2)^2
    (49 for n = 3).
    """
    return 4 * 4 + 6 * 4 * (n - 2) + 9 * (n - 2) ** 2


class Layout:
    """The action layout of an N x N grid, and its offsets for batches of B episodes.

    n: the grid side N. Attributes: n; cells: int, N^2; src, dst: (A,) int64 and start:
    (N^2,) int64 as moves(n) returns them; n_moves: (N^2,) int64 the moves of each cell;
    base: int, the base cell (row N//2, col 0); right: (N,) int64 the right-most column's
    cells, top to bottom; route_src, route_row: (R,) int64 and route_start: (N^2,) int64 the
    intruders' routes as routes(n) returns them; n_routes: (N^2,) int64 the routes of each cell.
    """

    def __init__(self, n: int):
        self.n = n
        self.cells = n * n
        self.src, self.dst, self.start = moves(n)
        self.n_moves = np.diff(np.append(self.start, len(self.src)))
        self.base = (n // 2) * n
        self.right = np.arange(n) * n + (n - 1)
        self.route_src, self.route_row, self.route_start = routes(n)
        self.n_routes = np.diff(np.append(self.route_start, len(self.route_src)))
        self._offsets: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._route_offsets: dict[int, np.ndarray] = {}

    def offsets(self, B: int) -> tuple[np.ndarray, np.ndarray]:
        """(starts: (B N^2,) int64 each cell's slice in the flattened (B A,) actions, dst: (B A,)
        int64 each move's destination in the flattened (B N^2,) densities), made once per B."""
        if B not in self._offsets:
            A = len(self.src)
            starts = ((np.arange(B) * A)[:, None] + self.start).reshape(-1)
            dst = ((np.arange(B) * self.cells)[:, None] + self.dst).reshape(-1)
            self._offsets[B] = (starts, dst)
        return self._offsets[B]

    def route_offsets(self, B: int) -> np.ndarray:
        """starts: (B N^2,) int64 each cell's slice in the flattened (B R,) intruder actions, made once per B."""
        if B not in self._route_offsets:
            R = len(self.route_src)
            self._route_offsets[B] = ((np.arange(B) * R)[:, None] + self.route_start).reshape(-1)
        return self._route_offsets[B]


def check_actions(action, shape: tuple[int, ...], name: str = "action") -> np.ndarray:
    """The action(s) as float64 of `shape`, values as given (the step clips them), or ActionError.

    Refused: anything that is not an array of real numbers (integers or floats) of shape
    `shape` ((A,) for one episode, (B, A) for a batch), and NaN or infinite values; name:
    the argument's name in the message.
    """
    expected = f"{name}: expected shape {tuple(shape)} of finite numbers in the action space"
    try:
        a = np.asarray(action)
    except (TypeError, ValueError, OverflowError):
        raise ActionError(f"{expected}, got a {type(action).__name__} that is not an array of numbers") from None
    if a.dtype.kind not in "iuf":
        raise ActionError(f"{expected}, got dtype {a.dtype}")
    if a.shape != tuple(shape):
        raise ActionError(f"{expected}, got shape {a.shape}")
    with np.errstate(over="ignore"):  # a float128 beyond float64 becomes inf, refused below
        a = a.astype(np.float64)
    finite = np.isfinite(a)
    if not finite.all():
        bad = np.flatnonzero(~finite)
        at = np.unravel_index(bad[0], a.shape)
        where = at[0] if len(at) == 1 else tuple(int(i) for i in at)
        raise ActionError(f"{expected}, got {a[at]} at index {where} ({len(bad)} value(s) not finite)")
    return a


def _slice_probabilities(config: AllocConfig, a: np.ndarray, starts: np.ndarray, src: np.ndarray, cells: int,
                         n_moves: np.ndarray) -> np.ndarray:
    """The action_map on each cell's slice: a: (B, K) float64 clipped to [-1, 1]; starts: (B
    cells,) each slice's offset in a.reshape(-1); src: (K,) each entry's cell; n_moves: (cells,)
    each slice's length -> (B, K) float64, each slice summing to 1."""
    B = len(a)
    if config.action_map == "softmax":
        z = config.softmax_beta * a
        z = z - np.maximum.reduceat(z.reshape(-1), starts).reshape(B, cells)[:, src]
        w = np.exp(z)
    else:
        w = a + 1.0
    total = np.add.reduceat(w.reshape(-1), starts).reshape(B, cells)
    uniform = total <= 0
    total = np.where(uniform, 1.0, total)
    p = w / total[:, src]
    if uniform.any():
        p = np.where(uniform[:, src], 1.0 / n_moves[src], p)
    return p


def move_probabilities(layout: Layout, config: AllocConfig, action: np.ndarray) -> np.ndarray:
    """Map actions to the probabilities of the feasible moves (the config's `action_map`).

    action: (B, A) float, clipped to [-1, 1] -> p: (B, A) float64 in the same order, each
    cell's slice summing to 1: `softmax`, p = softmax(beta a) per cell (beta =
    `softmax_beta`); `shifted`, p = (a + 1) / sum(a + 1), uniform when every entry is -1.
    """
    a = np.minimum(np.maximum(np.asarray(action, dtype=np.float64), -1.0), 1.0)
    starts, _ = layout.offsets(len(a))
    return _slice_probabilities(config, a, starts, layout.src, layout.cells, layout.n_moves)


def route_probabilities(layout: Layout, config: AllocConfig, action: np.ndarray) -> np.ndarray:
    """Map intruder actions to the probabilities of their routes, as move_probabilities maps the
    defenders' (the same `action_map`): action: (B, R) float, clipped to [-1, 1] -> (B, R) float64."""
    a = np.minimum(np.maximum(np.asarray(action, dtype=np.float64), -1.0), 1.0)
    return _slice_probabilities(config, a, layout.route_offsets(len(a)), layout.route_src, layout.cells,
                                layout.n_routes)


def routing_of(layout: Layout, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The routing of route probabilities p: (B, R) float64 -> (up, down): (B, N^2) float64 each
    cell's share sent up-left and down-left (farm.alloc.game.model.route_intruders_many)."""
    B, cells = len(p), layout.cells
    up, down = np.zeros((B, cells)), np.zeros((B, cells))
    rising, falling = layout.route_row == -1, layout.route_row == 1
    up[:, layout.route_src[rising]] = p[:, rising]
    down[:, layout.route_src[falling]] = p[:, falling]
    return up, down


def intruder_routing(layout: Layout, config: AllocConfig, action: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The intruders' routing of their actions: action: (B, R) float, clipped to [-1, 1] ->
    (up, down): (B, N^2) float64 (route_probabilities, then routing_of)."""
    return routing_of(layout, route_probabilities(layout, config, action))


def check_pure_routes(layout: Layout, choice, shape: tuple[int, ...], name: str) -> np.ndarray:
    """Pure routes as (B, N^2) int64 (one route index a cell, 0 .. its routes - 1), or ActionError
    naming name for anything else (another shape, not whole numbers, out of a cell's range)."""
    expected = f"{name}: expected shape {tuple(shape)} of route indices (0 .. a cell's routes - 1)"
    try:
        a = np.asarray(choice)
    except (TypeError, ValueError, OverflowError):
        raise ActionError(f"{expected}, got a {type(choice).__name__}") from None
    if a.shape != tuple(shape):
        raise ActionError(f"{expected}, got shape {a.shape}")
    whole = a.dtype.kind in "iu" or (a.dtype.kind == "f" and bool(np.all(np.isfinite(a)))
                                     and bool(np.all(a == np.round(a))))
    if not whole:
        raise ActionError(f"{expected}, got dtype {a.dtype}")
    a = a.astype(np.int64).reshape(-1, layout.cells)
    if np.any(a < 0) or np.any(a >= layout.n_routes[None, :]):
        raise ActionError(f"{expected}, got an index out of a cell's routes")
    return a


def pure_routing(layout: Layout, choice: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The routing of pure routes: choice: (B, N^2) int64 each cell's route index (its routes in
    the routes() order) -> (up, down): (B, N^2) float64 of 0s and 1s."""
    d_row = layout.route_row[layout.route_start[None, :] + np.asarray(choice)]
    return (d_row == -1).astype(np.float64), (d_row == 1).astype(np.float64)


def move_defenders(layout: Layout, D: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The defenders after their move, D' = T D: D: (B, N^2) float64, p: (B, A) float64 the
    move probabilities -> (B, N^2) float64 (each destination's inflow summed in move order)."""
    B = len(D)
    _, dst = layout.offsets(B)
    flow = p * D[:, layout.src]
    return np.bincount(dst, weights=flow.reshape(-1), minlength=B * layout.cells).reshape(B, layout.cells)


def defenders_move(layout: Layout, config: AllocConfig, D: np.ndarray, action: np.ndarray) -> np.ndarray:
    """The defenders after the move of their actions: D: (B, N^2) float64, action: (B, A) float,
    clipped to [-1, 1] -> (B, N^2) float64 (move_probabilities, then move_defenders)."""
    return move_defenders(layout, D, move_probabilities(layout, config, action))


def start_densities(layout: Layout, shares: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The densities at an episode's start: all defenders at the base, the intruders over the
    right-most column. shares: (B, N) float64 the intruders' row shares (a flat Dirichlet
    draw each) -> (D, I): (B, N^2) float64 each."""
    B = len(shares)
    D = np.zeros((B, layout.cells))
    D[:, layout.base] = 1.0
    I = np.zeros((B, layout.cells))
    I[:, layout.right] = shares
    return D, I


def observe(D: np.ndarray, I: np.ndarray) -> np.ndarray:
    """The observations: D, I: (B, N^2) float64 -> (B, 2 N^2) float32 [D, I] clipped to [0, 1]."""
    return np.minimum(np.maximum(np.concatenate([D, I], axis=1), 0.0), 1.0).astype(np.float32)


def episode_end(config: AllocConfig, steps: np.ndarray, remaining: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(terminated, truncated): (B,) bool each, of episodes after steps: (B,) int steps taken
    with remaining: (B,) float64 intruder mass; terminated when the mass is below `epsilon`,
    else truncated at `max_steps` steps."""
    terminated = remaining < config.epsilon
    return terminated, ~terminated & (steps >= config.max_steps)


@dataclass(frozen=True)
class StepResult:
    """One step of B episodes: the new densities and each episode's measures.

    D, I: (B, N^2) float64 the densities after the step; breach: (B,) float64 the intruder
    mass breached; eliminated: (B,) float64 the mass eliminated; score: (B,) float64 the
    capture score S; engaged: (B,) int64 the engaged cells; estimates: (B,) int64 of them
    the interpolated answers; coverage: (B,) float64 the share of the intruder mass (after
    its advance) in engaged cells; per_engaged: (B,) float64 the mean n_p over the engaged
    cells (0.0 with none); remaining: (B,) float64 the intruder mass left, sum(I); reward:
    (B,) float64.
    """

    D: np.ndarray
    I: np.ndarray
    breach: np.ndarray
    eliminated: np.ndarray
    score: np.ndarray
    engaged: np.ndarray
    estimates: np.ndarray
    coverage: np.ndarray
    per_engaged: np.ndarray
    remaining: np.ndarray
    reward: np.ndarray


def step(layout: Layout, config: AllocConfig, model: EngagementModel, D: np.ndarray, I: np.ndarray,
         action: np.ndarray, intruders=None) -> StepResult:
    """One step of the MDP (SwarmAllocationEnv's Description) for B episodes.

    D, I: (B, N^2) float64 the densities before the step (not changed); action: (B, A)
    float64, checked (check_actions); model: the config's EngagementModel, asked once (its
    engage_many) for every engaged cell of the B episodes; intruders: None, the drift law of
    the config, or a function (D', I) -> (up, down) giving the intruders' routing (resolve)
    from the defenders after their move D': (B, N^2) float64. Returns the StepResult; the
    caller keeps the episodes' counters.
    """
    D = defenders_move(layout, config, D, action)
    return resolve(layout, config, model, D, I, None if intruders is None else intruders(D, I))


def resolve(layout: Layout, config: AllocConfig, model: EngagementModel, D: np.ndarray, I: np.ndarray,
            routing: tuple[np.ndarray, np.ndarray] | None = None) -> StepResult:
    """The rest of a step once the defenders have moved: the intruders' move, the engagements, the reward.

    D: (B, N^2) float64 the defenders after their move; I: (B, N^2) float64 the intruders
    before theirs (not changed); routing: None, the drift law of the config
    (farm.alloc.game.model.advance_intruders_many), or (up, down): (B, N^2) float64 each cell's
    share of intruder mass sent up-left and down-left (farm.alloc.game.model.route_intruders_many).
    """
    if routing is None:
        I, breach = advance_intruders_many(I, layout.n, config.vertical_drift)
    else:
        I, breach = route_intruders_many(I, layout.n, *routing)
    e = model.engage_many(D, I)
    B = len(D)
    total = row_sums(I)
    engaged = e.counts
    if len(e.cells):
        flat = e.episode * layout.cells + e.cells
        values = np.empty((3, len(flat)))  # the masses before, the scores, the masses eliminated
        before = values[0]
        np.take(I.reshape(-1), flat, out=before)
        after = before * (1.0 - e.removed)
        np.multiply(before, e.score, out=values[1])
        np.subtract(before, after, out=values[2])
        I.reshape(-1)[flat] = after
        mass, score, eliminated = segment_sums(values, engaged)
        coverage = np.divide(mass, total, out=np.zeros(B), where=total > 0)
        per_engaged = np.divide(np.bincount(e.episode, weights=e.n_p, minlength=B), engaged, out=np.zeros(B),
                                where=engaged > 0)
        estimates = np.bincount(e.episode[e.estimated], minlength=B)
    else:
        score = eliminated = coverage = per_engaged = np.zeros(B)
        estimates = np.zeros(B, dtype=np.int64)
    remaining = row_sums(I)
    reward = -config.c_distribution * remaining + config.c_capture * score - config.breach_penalty * breach
    return StepResult(D, I, breach, eliminated, score, engaged, estimates, coverage, per_engaged, remaining, reward)
