"""`learned`: a trained intruder policy of a run folder (`farm train` with `side: intruders`)."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np

from farm.alloc.game.dynamics import observe, pure_routing, route_probabilities, routing_of
from farm.alloc.intruders.base import IntruderPolicy
from farm.core.checks import flag
from farm.core.errors import ConfigError

__all__ = ["LearnedIntruders"]


class LearnedIntruders(IntruderPolicy):
    """The trained model of the run folder `run` (its config's algo; model.zip on the CPU), acting on
    the observation [D, I] it sees: its action is mapped to routes as the env maps an intruder
    action (route_probabilities). deterministic: its policy's mean action (True) or a draw.
    ConfigError (one line naming intruder_options) for a folder without a trained intruder
    model, or one trained on a map of another size."""

    def __init__(self, config, run: str | None = None, deterministic: bool = True):
        super().__init__(config)
        import yaml

        from farm.alloc.networks.trained import load_model

        self.deterministic = flag("intruder_options.deterministic", deterministic)
        if run is None:
            raise ConfigError("intruder_options: learned intruders need the run folder (run: PATH)",
                              field="intruder_options")
        path = Path(run) / "config.yaml"  # a run folder's config (farm.alloc.training.runs, which imports the rollout)
        values = yaml.safe_load(path.read_text()) if path.is_file() else None
        if not isinstance(values, dict) or values.get("side") != "intruders":
            raise ConfigError(f"intruder_options: {run} holds no intruders' training run (farm train with "
                              f"side: intruders)", field="intruder_options")
        self.model = load_model(run, values.get("algo", "ppo"))
        self.pure = isinstance(self.model.action_space, gym.spaces.MultiDiscrete)  # one route a cell
        shape, routes = self.model.observation_space.shape, len(self.layout.route_src)
        fits = np.array_equal(self.model.action_space.nvec, self.layout.n_routes) if self.pure \
            else self.model.action_space.shape == (routes,)
        if shape != (2 * self.n * self.n,) or not fits:
            trained = int(round((shape[0] / 2) ** 0.5))
            raise ConfigError(f"intruder_options: {run} was trained on a {trained}x{trained} map, not this "
                              f"{self.n}x{self.n} one", field="intruder_options")

    @classmethod
    def make(cls, config, run: str | None = None, deterministic: bool = True):
        """The registry's maker."""
        return cls(config, run, deterministic)

    def routing(self, D, I):
        """The model's action on each episode's observation, as routes."""
        obs = observe(np.atleast_2d(D), np.atleast_2d(I))
        action, _ = self.model.policy.predict(obs, deterministic=self.deterministic)
        if self.pure:
            return pure_routing(self.layout, np.asarray(action, dtype=np.int64).reshape(len(obs), -1))
        return routing_of(self.layout, route_probabilities(self.layout, self.config, action))
