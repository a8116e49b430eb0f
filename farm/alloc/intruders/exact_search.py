"""The intruders' exact best response to a deterministic allocator, by exhaustive search over their routings.

exact_response searches one episode (its docstring has the algorithm, the tie rule and the
guard on its size); ExactResponse holds what it finds; cell_options lays out a cell's routings on
a share grid (1: the pure routings, each cell's whole mass along one route); tree_bound and
check_search are the refusal it makes before searching; Routings lays out a state's routings;
ScriptedIntruders replays a found routing sequence through farm.alloc.evaluation.rollout.play. The
information structure is the follower's of docs/model.md section 8.
"""

from __future__ import annotations

from dataclasses import dataclass
from fractions import Fraction

import numpy as np

from farm.alloc.game.config import AllocConfig
from farm.alloc.game.dynamics import (
    Layout,
    check_actions,
    episode_end,
    move_defenders,
    move_probabilities,
    observe,
    resolve,
    start_densities,
)
from farm.alloc.game.model import EngagementModel
from farm.alloc.intruders.base import IntruderPolicy
from farm.core.errors import ConfigError

__all__ = [
    "DEFAULT_MAX_NODES",
    "OBJECTIVES",
    "ExactResponse",
    "Routings",
    "ScriptedIntruders",
    "cell_options",
    "check_search",
    "draws_moves",
    "episode_start",
    "exact_response",
    "routing_text",
    "tree_bound",
]

OBJECTIVES = ("eliminated", "return")
DEFAULT_MAX_NODES = 100_000


def cell_options(feasible: tuple[bool, bool, bool], shares: int = 1) -> np.ndarray:
    """A cell's routings on the share grid 1/shares: feasible: whether it has the routes (up-left,
    left, down-left) -> (K, 3) float64, each row the shares sent up-left, left and down-left
    (multiples of 1/shares summing to 1, 0 on a route it lacks), in the search's tie order:
    straight share largest first, then up-left share largest first."""
    k = int(shares)
    rows = [(u, s, k - u - s) for u in range(k + 1) for s in range(k + 1 - u)]
    rows = [r for r in rows if all(ok or x == 0 for ok, x in zip(feasible, r))]
    rows.sort(key=lambda r: (-r[1], -r[0]))
    return np.array(rows, dtype=np.float64) / k


def episode_start(config: AllocConfig, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(D, I): (N^2,) float64 each, the densities episode `seed` starts from, drawn as
    farm.alloc.evaluation.rollout.play draws them (the intruders' row shares a flat Dirichlet draw of the
    generator gymnasium seeds with seed)."""
    from gymnasium.utils import seeding

    n = config.grid_size
    shares = seeding.np_random(seed)[0].dirichlet(np.ones(n))
    D, I = start_densities(Layout(n), shares[None])
    return D[0], I[0]


def _check_options(objective: str, shares, max_nodes) -> None:
    """ConfigError (one line naming the field) for an unknown objective, or shares or max_nodes
    that is not a whole number >= 1."""
    if objective not in OBJECTIVES:
        raise ConfigError(f"objective: must be one of {', '.join(OBJECTIVES)}, got {objective!r}", field="objective")
    for name, value in (("shares", shares), ("max_nodes", max_nodes)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
            raise ConfigError(f"{name}: must be a whole number >= 1, got {value!r}", field=name)


def tree_bound(config: AllocConfig, I: np.ndarray, shares: int = 1, limit: int | None = None) -> tuple[int, list[int]]:
    """An upper bound on the states the search expands from intruders I: (N^2,) float64 at the
    episode's start, and the bound's routings per state at each step: (bound, [routings of step 1,
    ...]). At each step every cell the intruders can have reached (its mass landing on the rows
    beside its own, one column left) takes part with all its options; a step's states are the
    previous step's times its routings, and states are expanded at steps 0 .. max_steps - 1
    while the mass can still be on the grid. limit: stop counting once the bound exceeds it (the
    bound returned is then the count so far, already over limit)."""
    n = config.grid_size
    mass = (np.asarray(I, dtype=np.float64) > 0).reshape(n, n)
    counts = {True: len(cell_options((False, True, True), shares)),
              False: len(cell_options((True, True, True), shares))}
    edge = np.zeros(n, dtype=bool)
    edge[[0, n - 1]] = True
    total, states, per_step = 0, 1, []
    for _ in range(config.max_steps):
        if not mass.any():
            break
        total += states
        if limit is not None and total > limit:
            break
        free = mass[:, 1:]
        routings = 1
        for row in np.flatnonzero(free.any(axis=1)).tolist():
            routings *= counts[bool(edge[row])] ** int(free[row].sum())
        per_step.append(routings)
        states *= routings
        reach = np.zeros_like(mass)
        reach[:, :-1] = free
        reach[1:, :-1] |= free[:-1]
        reach[:-1, :-1] |= free[1:]
        mass = reach
    return total, per_step


def check_search(config: AllocConfig, I: np.ndarray, *, objective: str = "eliminated", shares: int = 1,
                 max_nodes: int = DEFAULT_MAX_NODES, seed: int | None = None) -> int:
    """The search's refusals, before it starts: ConfigError (one line naming the field) for a
    bad objective, shares or max_nodes, and naming max_nodes when the tree from intruders I:
    (N^2,) float64 could hold more states than max_nodes (seed: the episode's, for the
    message). Returns the bound (tree_bound)."""
    _check_options(objective, shares, max_nodes)
    bound, per_step = tree_bound(config, I, shares, limit=max_nodes)
    if bound > max_nodes:
        episode = "" if seed is None else f" of episode seed {seed}"
        coarser = ", or a coarser share grid" if shares > 1 else ""
        raise ConfigError(f"max_nodes: the search{episode} could expand more than {max_nodes:,} states on this "
                          f"{config.grid_size}x{config.grid_size} map ({per_step[0]:,} routings at its first step, "
                          f"shares {shares}); raise max_nodes, or search a smaller map{coarser}", field="max_nodes")
    return bound


@dataclass(frozen=True)
class ExactResponse:
    """The intruders' best response in one episode and what it gives.

    seed: the episode's seed; summary: {"return", "eliminated", "breached", "length"} as
    farm.alloc.evaluation.rollout.Episode.summary gives them for the episode played with these routings
    (floats, length an int); value: float, the objective's minimum as searched (summed from the
    episode's end); routings: per step, (up, down): (N^2,) float64 each, the shares of each
    cell's mass sent up-left and down-left (farm.alloc.game.model.route_intruders_many); routed: per
    step, (k,) int64 the cells that took part (held mass outside column 0), in cell order;
    nodes: the states expanded (each asked the allocator at most once and resolved all its
    routings in one batch); resolved: the (state, routing) pairs resolved; shares: the share
    grid searched; objective: what was minimised.
    """

    seed: int
    summary: dict
    value: float
    routings: list
    routed: list
    nodes: int
    resolved: int
    shares: int
    objective: str

    def text(self) -> str:
        """The routings as one line (routing_text)."""
        return routing_text(self.routings, self.routed, self.shares)


def routing_text(routings: list, routed: list, shares: int = 1) -> str:
    """A routing sequence as one line: steps separated by "; ", each step its cells that took part
    as `cell:route` (U up-left, L left, D down-left), a split one as its routes' shares joined by
    "+" (`4:U1/2+L1/2`); "-" for a step where no cell took part. routings, routed: as
    ExactResponse's; shares: the share grid (for the fractions)."""
    steps = []
    for (up, down), cells in zip(routings, routed):
        parts = []
        for c in np.asarray(cells).tolist():
            split = [(name, Fraction(round(x * shares), shares)) for name, x in
                     (("U", up[c]), ("L", 1.0 - up[c] - down[c]), ("D", down[c]))]
            split = [(name, f) for name, f in split if f]
            code = split[0][0] if len(split) == 1 else "+".join(f"{name}{f}" for name, f in split)
            parts.append(f"{c}:{code}")
        steps.append(" ".join(parts) or "-")
    return "; ".join(steps)


class Routings:
    """A map's routings on a share grid: config (AllocConfig), layout, n, rows, cols ((N^2,)
    int64 each cell's row and column) and options (each cell's cell_options); routings(I) lays
    out every routing of a state's intruders."""

    def __init__(self, config: AllocConfig, shares: int = 1):
        self.config = config
        self.layout = Layout(config.grid_size)
        n = config.grid_size
        self.n, self.A = n, len(self.layout.src)
        self.rows, self.cols = np.divmod(np.arange(n * n), n)
        options = {edge: cell_options(edge, shares) for edge in ((False, True, True), (True, True, False),
                                                                  (True, True, True))}
        self.options = [options[(r > 0, True, r < n - 1)] for r in self.rows.tolist()]

    def moving(self, I: np.ndarray) -> bool:
        """Whether any cell of intruders I: (N^2,) float64 takes part in a routing (holds mass outside column 0)."""
        return bool(np.any((I > 0) & (self.cols > 0)))

    def routings(self, I: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every routing of a state's intruders I: (N^2,) float64, in the tie order: (cells: (k,)
        int64 the cells taking part, up, down: (R, N^2) float64)."""
        cells = np.flatnonzero((I > 0) & (self.cols > 0))
        options = [self.options[c] for c in cells.tolist()]
        sizes = [len(o) for o in options]
        R = int(np.prod(sizes, dtype=np.int64))
        up, down = np.zeros((R, self.n * self.n)), np.zeros((R, self.n * self.n))
        if len(cells):
            picks = np.unravel_index(np.arange(R), sizes)  # C order: the first cell varies slowest
            for c, o, pick in zip(cells.tolist(), options, picks):
                up[:, c] = o[pick, 0]
                down[:, c] = o[pick, 2]
        return cells, up, down


class _Search(Routings):
    """One episode's search (exact_response): the allocator, the config's model and the memo
    {(D bytes, I bytes, step): (value, up, down, cells, reward, eliminated, breach, child key)}."""

    def __init__(self, config: AllocConfig, policy, client, objective: str, shares: int):
        super().__init__(config, shares)
        self.policy, self.objective = policy, objective
        self.model = EngagementModel(config, client, False)
        self.memo: dict = {}
        self.nodes = self.resolved = 0

    def value(self, D: np.ndarray, I: np.ndarray, steps: int) -> tuple[float, tuple]:
        """(the value of state (D, I) after `steps` steps, its memo key): D, I: (N^2,) float64."""
        key = (D.tobytes(), I.tobytes(), steps)
        if key in self.memo:
            return self.memo[key][0], key
        self.nodes += 1
        cells, up, down = self.routings(I)
        if len(cells):
            action, _ = self.policy.predict(observe(D[None], I[None])[0], deterministic=True)
            actions = check_actions(action, (self.A,))[None]
            moved = move_defenders(self.layout, D[None], move_probabilities(self.layout, self.config, actions))[0]
        else:  # the whole mass leaves the grid at this step: nothing engages, whatever the defenders do
            moved = D
        R = len(up)
        self.resolved += R
        r = resolve(self.layout, self.config, self.model, np.repeat(moved[None], R, axis=0),
                    np.repeat(I[None], R, axis=0), (up, down))
        gain = r.eliminated if self.objective == "eliminated" else r.reward
        terminated, truncated = episode_end(self.config, np.full(R, steps + 1), r.remaining)
        values = gain.copy()
        children: list = [None] * R
        for i in np.flatnonzero(~(terminated | truncated)).tolist():
            later, children[i] = self.value(r.D[i], r.I[i], steps + 1)
            values[i] = gain[i] + later
        best = int(np.argmin(values))
        self.memo[key] = (values[best], up[best], down[best], cells, r.reward[best], r.eliminated[best],
                          r.breach[best], children[best])
        return values[best], key


def draws_moves(policy) -> bool:
    """Whether an allocator draws its moves (a mixture drawn per episode or step; one of mean moves
    does not): the search answers the others."""
    return getattr(policy, "for_episode", None) is not None and getattr(policy, "draw", None) != "mean"


def exact_response(config: AllocConfig, policy, client, seed: int, *, objective: str = "eliminated",
                   shares: int = 1, max_nodes: int = DEFAULT_MAX_NODES) -> ExactResponse:
    """The intruders' best response in episode `seed` of config against policy, a deterministic
    allocator (`predict(obs, deterministic=True) -> (action, state)`), the engagements answered
    by client (a CaptureTimeClient of config.game_settings()); config's own intruders and
    information are not used.

    Each step, the allocator acts on the observation as farm.alloc.evaluation.rollout.play asks it (the
    float32 observation of farm.alloc.game.dynamics.observe), the intruders see the defenders after
    their move D' with their own I and choose a routing, and farm.alloc.game.dynamics.resolve moves
    them, engages and rewards: the follower of docs/model.md section 8, which against a
    deterministic allocator is also the best response under `simultaneous` (the intruders can
    predict its move). The routings: every cell holding intruder mass (> 0) outside column 0
    takes one of its options on the share grid 1/shares (cell_options; shares = 1: its whole
    mass along one route); a cell without mass, or of column 0 (whose mass breaches whatever its
    route), goes straight; a step's routings are every combination of its cells' options.

    objective: the defenders' measure minimised, summed to the episode's end (episode_end):
    "eliminated" (the intruder mass eliminated) or "return" (their reward; the intruders' is its
    negative). The value of a state (D, I, steps taken) is the least, over its routings, of the
    step's objective plus the value of the state it leads to (none when the episode ends there);
    a state is searched once an episode (memoised on the bytes of D and I and the step), all its
    routings resolved in one batch. Ties go to the first routing in this order: the cells taking
    part in cell order, the first varying slowest (itertools.product's order), each cell's
    options as cell_options orders them (straight share largest first, then up-left share
    largest first; for pure routings straight, up-left, down-left, as the heuristics break ties).

    A step whose whole intruder mass is in column 0 leaves none on the grid, so no cell engages
    whatever the defenders do and its measures do not depend on their move: the allocator is not
    asked there (the episode ends with that step). The summary sums the chosen steps forward, as
    play() does, so replaying ExactResponse.routings through play (ScriptedIntruders) gives it to
    the bit; the searched value sums them from the end and may differ in the last bit.

    shares: the share grid (whole number >= 1); max_nodes: the most states the search may expand,
    checked on its bound (tree_bound) before it starts. ConfigError (one line naming the field)
    for a bad objective, shares or max_nodes, a tree that could exceed max_nodes, or an
    allocator that draws its moves (a mixture but of mean moves).
    """
    if draws_moves(policy):
        raise ConfigError("allocator: the exact search answers a deterministic allocator; this one draws its moves "
                          "(search a mixture's members one by one)", field="allocator")
    D, I = episode_start(config, seed)
    check_search(config, I, objective=objective, shares=shares, max_nodes=max_nodes, seed=seed)
    search = _Search(config, policy, client, objective, int(shares))
    value, key = search.value(D, I, 0)
    totals = np.zeros((3,))  # return, eliminated, breached: summed forward from 0, as play() sums them
    routings, routed, length = [], [], 0
    while key is not None:
        _, up, down, cells, reward, eliminated, breach, key = search.memo[key]
        totals += (reward, eliminated, breach)
        routings.append((up.copy(), down.copy()))
        routed.append(cells)
        length += 1
    summary = {"return": float(totals[0]), "eliminated": float(totals[1]), "breached": float(totals[2]),
               "length": length}
    return ExactResponse(int(seed), summary, float(value), routings, routed, search.nodes, search.resolved,
                         int(shares), objective)


class ScriptedIntruders(IntruderPolicy):
    """Intruders that replay a routing sequence in one episode: routings, per step, (up, down):
    (N^2,) float64 each (ExactResponse.routings); its k-th call of routing() answers step k's, as
    (1, N^2) arrays. For checks: a config whose `intruders` names it replays the search through
    farm.alloc.evaluation.rollout.play (one episode a config; register it first, it is not in the registry)."""

    def __init__(self, config, routings=()):
        super().__init__(config)
        self.script = [(np.asarray(u, dtype=np.float64), np.asarray(d, dtype=np.float64)) for u, d in routings]
        self.calls = 0

    @classmethod
    def make(cls, config, routings=()):
        """The registry's maker."""
        return cls(config, routings)

    def routing(self, D, I):
        """The next step's routing of the script; IndexError past its end."""
        up, down = self.script[self.calls]
        self.calls += 1
        return up[None], down[None]

