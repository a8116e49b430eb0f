"""How an env, a rollout or a search asks a config's intruder policy for a step's routing."""

from __future__ import annotations

from farm.alloc.game.registry import INTRUDERS

__all__ = ["configured_intruders", "intruder_move", "for_episode", "draw_state", "EpisodeIntruders"]


def configured_intruders(config, client=None):
    """The intruder policy of an AllocConfig (`intruders`, `intruder_options`; client: the
    capture-time client of the caller, for a policy that plans on it), or None for the drift law,
    which dynamics.step applies itself (the default path, unchanged)."""
    if config.intruders == "drift":
        return None
    return INTRUDERS.make(config.intruders, config, client, **config.intruder_options)


def intruder_move(policy, information: str, D, I):
    """The `intruders` argument of farm.alloc.game.dynamics.step for a step from D, I ((B, N^2) float64):
    None for the drift law (policy None); under `follower` the policy's routing of the defenders
    after their move; under `simultaneous` its routing of D, I, chosen before the defenders move."""
    if policy is None:
        return None
    if information == "follower":
        return policy.routing
    routing = policy.routing(D, I)
    return lambda moved, intruders: routing


def for_episode(policy, rng):
    """The policy one episode plays: policy.for_episode(rng) for a policy that draws its play per
    episode (a mixture), from the episode's own generator rng, else the policy itself (None stays None)."""
    draw = getattr(policy, "for_episode", None)
    return policy if draw is None else draw(rng)


def draw_state(played):
    """The saved state of an episode's draw (for_episode's result), None for a policy that draws nothing."""
    saved = getattr(played, "get_state", None)
    return None if saved is None else saved()


class EpisodeIntruders:
    """The intruder policies of B episodes, one each (for_episode's), as one policy: routing(D, I)
    asks each distinct policy once for the rows of its episodes. policies: list of B policies."""

    def __init__(self, policies: list):
        self.policies = list(policies)

    def subset(self, rows) -> EpisodeIntruders:
        """The policies of the episodes rows ((m,) int64 indices), in that order."""
        return EpisodeIntruders([self.policies[k] for k in rows])

    def routing(self, D, I):
        """(up, down): (B, N^2) float64 each, row b from policy b."""
        import numpy as np

        first = self.policies[0]
        if all(p is first for p in self.policies):
            return first.routing(D, I)
        up, down = np.zeros(np.shape(I)), np.zeros(np.shape(I))
        groups: dict[int, list[int]] = {}
        for b, policy in enumerate(self.policies):
            groups.setdefault(id(policy), []).append(b)
        for rows in groups.values():
            rows = np.array(rows)
            up[rows], down[rows] = self.policies[rows[0]].routing(D[rows], I[rows])
        return up, down
