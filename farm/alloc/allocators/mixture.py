"""`mixture`: a mixed strategy over allocators, drawing one member per episode or per step, or
playing the members' mean move."""

from __future__ import annotations

import numpy as np

from farm.core.mixture import mixture_members, saved_generator, saved_member

__all__ = ["Mixture"]

class Mixture:
    """A mixed strategy over allocators of the registry: each episode (draw `episode`) or each step
    (draw `step`) plays one member, drawn with the weights from a seeded generator; or (draw
    `mean`) every step moves each cell's defenders by the members' move probabilities averaged
    with the weights (a deterministic policy: what a network distilled from the mixture learns).

    config, client: as every allocator's; members: names or {policy: NAME, options: {...}};
    weights: None (uniform) or one number >= 0 a member; draw: episode or step; seed: the
    generator of a caller that runs no episodes (predict() then draws a member per call). An
    episode's draw is made by whoever runs the episode, from the episode's own generator
    (for_episode: farm.alloc.evaluation.rollout.play, the intruders' env), so a mixture's episodes are
    the same whatever the batching. Attributes: players (the members' allocators), weights.
    """

    def __init__(self, config, client=None, members=None, weights=None, draw: str = "episode", seed: int = 0):
        from farm.alloc.game.registry import ALLOCATORS

        parsed, self.weights = mixture_members("mixture", members, weights, draw, "policy")
        self.names = [name for name, _ in parsed]
        self.players = [ALLOCATORS.make(name, config, client, **options) for name, options in parsed]
        self.draw = draw
        self.config = config
        self._rng = np.random.default_rng(seed)
        from farm.alloc.game.dynamics import Layout

        self._layout = Layout(config.grid_size)

    def for_episode(self, rng: np.random.Generator):
        """The mixture as one episode plays it: a member drawn from rng (draw episode), draws per
        step from a generator of rng's (draw step), or itself (draw mean: it draws nothing)."""
        if self.draw == "mean":
            return self
        if self.draw == "episode":
            return _Member(self, int(rng.choice(len(self.players), p=self.weights)))
        return _Draws(self, np.random.default_rng(rng.integers(2 ** 63)))

    def resume_episode(self, state: dict):
        """The episode's play from its get_state(); ValueError for a member that is not one."""
        member = saved_member(state, len(self.players))
        return _Draws(self, saved_generator(state)) if member is None else _Member(self, member)

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        """The members' mean move (draw mean), else a member drawn from the mixture's own generator
        acts (see the class doc)."""
        if self.draw == "mean":
            return self._mean_action(obs), state
        k = int(self._rng.choice(len(self.players), p=self.weights))
        return self.players[k].predict(obs, state, episode_start, deterministic)


    def _mean_action(self, obs) -> np.ndarray:
        """The action whose moves are the members' move probabilities averaged with the weights:
        obs: (2 N^2,) float32 -> (A,) float32 (action_from_probabilities of the mean)."""
        from farm.alloc.allocators.planners.core import action_from_probabilities
        from farm.alloc.game.dynamics import move_probabilities

        layout = self._layout
        actions = np.stack([np.asarray(p.predict(obs, deterministic=True)[0], dtype=np.float64)
                            for p in self.players])
        mean = self.weights @ move_probabilities(layout, self.config, actions)
        return action_from_probabilities(self.config, mean, layout.start, layout.src)


class _Member:
    """One episode's member of a mixture drawn per episode."""

    def __init__(self, mixture: Mixture, member: int):
        self.mixture, self.member = mixture, member

    def choose(self) -> int:
        """The member this step plays."""
        return self.member

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        return self.mixture.players[self.choose()].predict(obs, state, episode_start, deterministic)

    def get_state(self) -> dict:
        return {"member": self.member}


class _Draws:
    """One episode of a mixture drawn per step, from the episode's generator."""

    def __init__(self, mixture: Mixture, rng: np.random.Generator):
        self.mixture, self.rng = mixture, rng

    def choose(self) -> int:
        """The member this step plays, drawn now from the episode's generator."""
        m = self.mixture
        return int(self.rng.choice(len(m.players), p=m.weights))

    def predict(self, obs, state=None, episode_start=None, deterministic=True):
        return self.mixture.players[self.choose()].predict(obs, state, episode_start, deterministic)

    def get_state(self) -> dict:
        return {"rng": self.rng.bit_generator.state}
