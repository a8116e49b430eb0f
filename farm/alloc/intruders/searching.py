"""`search`: intruders that plan against a model of the defenders, by exhaustive search over their routings.

The model is a mixture of deterministic allocators drawn once an episode; the intruders, who see
each move before they route (the follower), keep the members whose moves so far match what they
saw and route to minimise the defenders' expected measure to the episode's end. Against a member
of the model it is the intruders' exact best response to the mixture (with one member, it plays
farm.alloc.intruders.exact_search.exact_response's routings); against an allocator outside the model it
re-plans from what it sees, the members that no longer match put back at their prior weights.
"""

from __future__ import annotations

import numpy as np

from farm.alloc.game.dynamics import check_actions, episode_end, move_defenders, move_probabilities, observe, resolve
from farm.alloc.game.model import EngagementModel
from farm.alloc.intruders.base import IntruderPolicy
from farm.alloc.intruders.exact_search import (
    DEFAULT_MAX_NODES,
    OBJECTIVES,
    Routings,
    check_search,
    draws_moves,
    episode_start,
)
from farm.core.errors import ConfigError
from farm.core.mixture import mixture_members

__all__ = ["SearchingIntruders", "check_searchable"]

_MATCH = 1e-9  # a member's predicted move matches the seen one within this, cell by cell
_MEMO = 200_000  # the states the memos may hold before an episode's start clears them (a cache only)


def check_searchable(config, objective: str = "eliminated") -> None:
    """ConfigError (one line naming intruder_options) when the search's tree from an episode's start
    on config's map could exceed its budget (exact_search.check_search: the 5 x 5 and larger maps):
    asked when the policy is made, so an env or a training with `search` intruders there is
    refused before its first step."""
    try:
        check_search(config, episode_start(config, 0)[1], objective=objective)
    except ConfigError:
        n = config.grid_size
        raise ConfigError(f"intruder_options: search: its tree on this {n}x{n} map could hold more than "
                          f"{DEFAULT_MAX_NODES:,} states (search intruders play on maps whose tree fits: the 3 x 3 "
                          f"ones)", field="intruder_options") from None


class SearchingIntruders(IntruderPolicy):
    """Intruders routing by exhaustive search against a mixture of deterministic allocators.

    allocators: the model's members, names or {policy: NAME, options: {...}} of the allocators'
    registry; weights: None (uniform) or one number >= 0 a member; objective: the defenders'
    measure minimised to the episode's end (eliminated or return); client: the capture-time
    client the members plan on and the engagements are answered by (the caller's, passed by
    make_intruders). Each episode (for_episode) keeps which members still match the moves seen;
    routing() outside an episode plans each row from its own state with every member.

    The value of a state before the defenders move, D, I: (N^2,) float64 after t steps, with the
    matching members S, is the weighted mean over the distinct moves of S's members of the value
    after that move (the members making it); after a move D', it is the least over the routings
    (farm.alloc.intruders.exact_search's tie order) of the step's measure plus the value of the state
    it leads to. A state is searched once (memoised on its bytes, t and S; the memos are a cache,
    cleared between episodes once large).
    ConfigError (one line naming intruder_options) for a bad objective, no client, or a member
    that draws its moves.
    """

    def __init__(self, config, allocators=None, weights=None, objective: str = "eliminated", client=None):
        super().__init__(config)
        from farm.alloc.game.registry import ALLOCATORS

        if objective not in OBJECTIVES:
            raise ConfigError(f"intruder_options.objective: one of {', '.join(OBJECTIVES)}, got {objective!r}",
                              field="intruder_options.objective")
        check_searchable(config, objective)
        if client is None:
            raise ConfigError("intruder_options: search intruders plan on a capture-time client; make them with "
                              "one (make_intruders(..., client=...))", field="intruder_options")
        parsed, self.weights = mixture_members("intruder_options", allocators, weights, "episode", "policy")
        self.members = [ALLOCATORS.make(name, config, client, **options) for name, options in parsed]
        for (name, _), member in zip(parsed, self.members):
            if draws_moves(member):
                raise ConfigError(f"intruder_options.allocators: {name} draws its moves; the search models "
                                  f"deterministic allocators (list a mixture's members)",
                                  field="intruder_options.allocators")
        self.tree, self.objective = Routings(config), objective
        self.model = EngagementModel(config, client, False)
        self.start = np.zeros(self.n * self.n)
        self.start[self.layout.base] = 1.0
        self.everyone = tuple(range(len(self.members)))
        self._moves: dict = {}
        self._before: dict = {}
        self._after: dict = {}

    @classmethod
    def make(cls, config, allocators=None, weights=None, objective: str = "eliminated", client=None):
        """The registry's maker."""
        return cls(config, allocators, weights, objective, client)

    def move(self, member: int, D: np.ndarray, I: np.ndarray) -> np.ndarray:
        """(N^2,) float64: the defenders after member's move from D, I ((N^2,) float64), as play() moves them."""
        key = (member, D.tobytes(), I.tobytes())
        if key not in self._moves:
            action, _ = self.members[member].predict(observe(D[None], I[None])[0], deterministic=True)
            actions = check_actions(action, (len(self.layout.src),))[None]
            probabilities = move_probabilities(self.layout, self.config, actions)
            self._moves[key] = move_defenders(self.layout, D[None], probabilities)[0]
        return self._moves[key]

    def before(self, D: np.ndarray, I: np.ndarray, t: int, S: tuple) -> float:
        """The value of (D, I) after t steps, before the defenders move, to the members S."""
        key = (D.tobytes(), I.tobytes(), t, S)
        if key not in self._before:
            if not self.tree.moving(I):  # the mass leaves: no cell engages whatever the defenders do
                self._before[key] = 0.0 if self.objective == "eliminated" else self.after(D, I, t, S)[0]
            else:
                groups: dict = {}
                for i in S:
                    moved = self.move(i, D, I)
                    groups.setdefault(moved.tobytes(), (moved, []))[1].append(i)
                w = self.weights[list(S)].sum()
                self._before[key] = sum(self.weights[g].sum() / w * self.after(moved, I, t, tuple(g))[0]
                                        for moved, g in groups.values())
        return self._before[key]

    def after(self, D: np.ndarray, I: np.ndarray, t: int, S: tuple) -> tuple:
        """(value, up, down, child D, child I): the best routing of intruders I: (N^2,) float64 seeing
        the defenders D after their move at step t, the members S, and the state it leads to."""
        key = (D.tobytes(), I.tobytes(), t, S)
        if key not in self._after:
            cells, up, down = self.tree.routings(I)
            R = len(up)
            r = resolve(self.layout, self.config, self.model, np.repeat(D[None], R, axis=0),
                        np.repeat(I[None], R, axis=0), (up, down))
            eliminated = self.objective == "eliminated"
            values = (r.eliminated if eliminated else r.reward).copy()
            terminated, truncated = episode_end(self.config, np.full(R, t + 1), r.remaining)
            going = ~(terminated | truncated)
            best = None  # the best routing so far, for the bound below
            for k in np.argsort(values, kind="stable").tolist():
                # the mass eliminated later is >= 0: a routing eliminating more now than the best so far
                # (or as much, after it in the tie order) cannot be the best, and is not searched
                if eliminated and best is not None and (values[k], k) > (values[best], best):
                    values[k] = np.inf
                    continue
                if going[k]:
                    values[k] += self.before(r.D[k], r.I[k], t + 1, S)
                if best is None or (values[k], k) < (values[best], best):
                    best = k
            self._after[key] = (float(values[best]), up[best], down[best], r.D[best], r.I[best])
        return self._after[key]

    def steps_taken(self, I: np.ndarray) -> int:
        """The steps an episode has taken when its intruders are I: (N^2,) float64 (they start in the
        right-most column and move one column a step)."""
        columns = np.flatnonzero((I.reshape(self.n, self.n) > 0).any(axis=0))
        return self.n - 1 - int(columns.max()) if len(columns) else self.n

    def routing(self, D, I):
        """Each row's routing planned from its own state with every member: D, I: (B, N^2) float64."""
        D, I = np.atleast_2d(D), np.atleast_2d(I)
        up, down = np.zeros(I.shape), np.zeros(I.shape)
        for b in range(len(I)):
            _, up[b], down[b], _, _ = self.after(D[b], I[b], self.steps_taken(I[b]), self.everyone)
        return up, down

    def for_episode(self, rng):
        """One episode's play, which keeps the members matching the moves it has seen (rng unused: it
        draws nothing). The memos are cleared first once they hold more than _MEMO states."""
        if len(self._moves) + len(self._before) + len(self._after) > _MEMO:
            self._moves, self._before, self._after = {}, {}, {}
        return _Episode(self)

    def resume_episode(self, state: dict):
        """An episode's play from its get_state()."""
        played = _Episode(self)
        played.members = tuple(int(i) for i in state["members"])
        played.t = int(state["t"])
        played.expected = None if state["expected"] is None else tuple(np.asarray(x, dtype=np.float64)
                                                                       for x in state["expected"])
        return played


class _Episode:
    """One episode of search intruders: the members matching the moves seen, the steps taken and the
    state it expects before the defenders' next move (None: the episode's start, or unknown)."""

    def __init__(self, policy: SearchingIntruders):
        self.policy, self.members, self.t, self.expected = policy, policy.everyone, 0, None

    def routing(self, D, I):
        """The episode's routing (one row: D, I: (1, N^2) float64)."""
        p = self.policy
        D, I = np.atleast_2d(D)[0], np.atleast_2d(I)[0]
        if self.t == 0:
            before = p.start
        elif self.expected is not None and np.allclose(self.expected[1], I, rtol=0.0, atol=_MATCH):
            before = self.expected[0]
        else:
            before = None  # not the state it led to: the members cannot be checked against this move
        if before is not None and p.tree.moving(I):
            matching = tuple(i for i in self.members
                             if np.allclose(p.move(i, before, I), D, rtol=0.0, atol=_MATCH))
            self.members = matching or p.everyone
        else:
            self.members = p.everyone if before is None else self.members
        _, up, down, child_D, child_I = p.after(D, I, self.t, self.members)
        self.expected = (child_D, child_I)
        self.t += 1
        return up[None], down[None]

    def get_state(self) -> dict:
        return {"members": list(self.members), "t": self.t,
                "expected": None if self.expected is None else [x.tolist() for x in self.expected]}
