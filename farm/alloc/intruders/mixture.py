"""`mixture`: a mixed strategy over intruder policies, drawing one member per episode or per step."""

from __future__ import annotations

import numpy as np

from farm.alloc.game.registry import INTRUDERS
from farm.alloc.intruders.base import IntruderPolicy
from farm.alloc.intruders.play import draw_state, for_episode
from farm.core.mixture import mixture_members, saved_generator, saved_member

__all__ = ["IntruderMixture"]


class IntruderMixture(IntruderPolicy):
    """A mixed strategy over intruder policies of the registry: each episode (draw `episode`) or
    each step (draw `step`) plays one member, drawn with the weights.

    members: names or {intruders: NAME, options: {...}}; weights: None (uniform) or one number
    >= 0 a member; draw: episode, step, or mean (the members' routings averaged); seed: the
    generator of a caller that runs no episodes (routing() then draws per row and call); client:
    the capture-time client, given to the members that take one. An
    episode's draw is made by whoever runs the episode, from the episode's generator
    (for_episode: the envs, farm.alloc.evaluation.rollout.play).
    """

    def __init__(self, config, client=None, members=None, weights=None, draw: str = "episode", seed: int = 0):
        super().__init__(config)
        parsed, self.weights = mixture_members("intruder_options", members, weights, draw, "intruders")
        self.names = [name for name, _ in parsed]
        self.players = [INTRUDERS.make(name, config, client, **options) for name, options in parsed]
        self.draw = draw
        self._rng = np.random.default_rng(seed)

    @classmethod
    def make(cls, config, client=None, members=None, weights=None, draw: str = "episode", seed: int = 0):
        """The registry's maker (client: given to the members that take one)."""
        return cls(config, client, members, weights, draw, seed)

    def _pick(self, rng, size=None):
        return rng.choice(len(self.players), p=self.weights, size=size)

    def for_episode(self, rng: np.random.Generator):
        """The mixture as one episode plays it (see Mixture.for_episode)."""
        if self.draw == "mean":
            return self
        if self.draw == "episode":
            member = int(self._pick(rng))
            return _Member(self, member, for_episode(self.players[member], rng))
        return _Draws(self, np.random.default_rng(rng.integers(2 ** 63)))

    def resume_episode(self, state: dict):
        """The episode's play from its get_state(); ValueError for a member that is not one."""
        member = saved_member(state, len(self.players))
        if member is None:
            return _Draws(self, saved_generator(state))
        played = self.players[member]
        if state.get("played") is not None:
            played = played.resume_episode(state["played"])
        return _Member(self, member, played)

    def routing(self, D, I):
        """The members' routings averaged with the weights (draw mean), else each row's routing by a
        member drawn from the mixture's own generator."""
        if self.draw == "mean":
            routings = [p.routing(np.atleast_2d(D), np.atleast_2d(I)) for p in self.players]
            return (sum(w * up for w, (up, _) in zip(self.weights, routings)),
                    sum(w * down for w, (_, down) in zip(self.weights, routings)))
        return self._rows(np.atleast_2d(D), np.atleast_2d(I), self._pick(self._rng, size=len(np.atleast_2d(I))))

    def _rows(self, D, I, members):
        up, down = np.zeros(I.shape), np.zeros(I.shape)
        for k in np.unique(members).tolist():
            rows = np.flatnonzero(members == k)
            up[rows], down[rows] = self.players[k].routing(D[rows], I[rows])
        return up, down


class _Member:
    """One episode's member of a mixture drawn per episode: its index and its play of the episode
    (for_episode's: the member itself, or its own episode's play for a member that keeps one)."""

    def __init__(self, mixture: IntruderMixture, member: int, played):
        self.mixture, self.member, self.played = mixture, member, played

    def routing(self, D, I):
        return self.played.routing(D, I)

    def get_state(self) -> dict:
        saved = draw_state(self.played)
        return {"member": self.member} if saved is None else {"member": self.member, "played": saved}


class _Draws:
    """One episode of a mixture drawn per step, from the episode's generator."""

    def __init__(self, mixture: IntruderMixture, rng: np.random.Generator):
        self.mixture, self.rng = mixture, rng

    def routing(self, D, I):
        D, I = np.atleast_2d(D), np.atleast_2d(I)
        return self.mixture._rows(D, I, self.mixture._pick(self.rng, size=len(I)))

    def get_state(self) -> dict:
        return {"rng": self.rng.bit_generator.state}
