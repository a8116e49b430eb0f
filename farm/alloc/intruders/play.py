"""How an env, a rollout or a search asks a config's intruder policy for a step's routing."""

from __future__ import annotations

from farm.alloc.intruders.registry import make_intruders

__all__ = ["configured_intruders", "intruder_move"]


def configured_intruders(config):
    """The intruder policy of an AllocConfig (`intruders`, `intruder_options`), or None for the
    drift law, which dynamics.step applies itself (the default path, unchanged)."""
    if config.intruders == "drift":
        return None
    return make_intruders(config.intruders, config, **config.intruder_options)


def intruder_move(policy, information: str, D, I):
    """The `intruders` argument of farm.alloc.dynamics.step for a step from D, I ((B, N^2) float64):
    None for the drift law (policy None); under `follower` the policy's routing of the defenders
    after their move; under `simultaneous` its routing of D, I, chosen before the defenders move."""
    if policy is None:
        return None
    if information == "follower":
        return policy.routing
    routing = policy.routing(D, I)
    return lambda moved, intruders: routing
