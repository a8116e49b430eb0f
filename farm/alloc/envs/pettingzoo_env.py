"""The allocation MDP as a zero-sum game of two learners, `defenders` and `intruders`, in
PettingZoo's two APIs (docs/engine.md shows their use).

The defenders move their density D as the single env's action moves it; the intruders route
theirs, each cell's mass sent up-left, left or down-left (farm.alloc.game.dynamics.routes). The
defenders are paid the single env's reward R, the intruders -R. raw_env(...) is the AEC env
(the defenders act, then the intruders, who under `information: follower` see the defenders
after their move), env(...) the same in PettingZoo's OrderEnforcingWrapper, parallel_env(...)
both sides at once from the same state. A step is farm.alloc.game.dynamics' pieces, so an episode
whose intruders route by the drift law is the single env's episode to the bit, and
reset(seed=s) draws the single env's start. Needs pettingzoo (the extra `marl`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import ClassVar

import numpy as np
from gymnasium.error import ResetNeeded
from gymnasium.spaces import Box
from gymnasium.utils import seeding

try:
    from pettingzoo import AECEnv, ParallelEnv
    from pettingzoo.utils.wrappers import OrderEnforcingWrapper
except ModuleNotFoundError as e:  # only pettingzoo itself missing: a broken install keeps its own error
    if e.name != "pettingzoo":
        raise
    raise ModuleNotFoundError("farm.alloc.envs.pettingzoo_env needs pettingzoo: pip install 'swarm-farm[marl]'",
                              name="pettingzoo") from None

from farm.alloc.envs.defenders import check_env_arguments, env_client, tally_step
from farm.alloc.game.config import AllocConfig
from farm.alloc.game.dynamics import (
    Layout,
    check_actions,
    episode_end,
    move_defenders,
    move_probabilities,
    observe,
    resolve,
    route_probabilities,
    routing_of,
    start_densities,
)
from farm.alloc.game.model import EngagementModel, row_sums
from farm.core.errors import ActionError, ConfigError

__all__ = ["AGENTS", "SwarmAllocationAECEnv", "SwarmAllocationParallelEnv", "env", "parallel_env", "raw_env"]

AGENTS = ("defenders", "intruders")  # the agents, in the AEC env's order within a step


class _TwoSides:
    """What both envs share: the arguments, the spaces, the state, the step's two halves, rendering.

    Attributes: config: AllocConfig; client: CaptureTimeClient; model: EngagementModel; n: int,
    the grid side N; layout: farm.alloc.game.dynamics.Layout; information: "follower" or
    "simultaneous", what the intruders see; possible_agents: list of str, AGENTS; agents: list of
    str, the agents still playing (empty before reset() and after the episode's end);
    observation_spaces, action_spaces: dicts of gymnasium Box by agent; state_space: Box; D, I:
    (N^2,) float64 the densities at the step's start; moved: (N^2,) float64 the defenders after
    their move while the intruders are to act (AEC env), else None; steps: int and breached,
    eliminated: float, the episode's counters; engagements, estimated: int, the engaged cells
    answered over the env's lifetime and of them the interpolated ones; np_random: the generator
    of the starts (None before the first reset()).
    """

    def __init__(self, config: AllocConfig | None, client, store, render_mode: str | None, estimates,
                 kwargs: dict, information: str | None):
        name = type(self).__name__
        self.config = check_env_arguments(name, config, estimates, kwargs)
        if self.config.intruders != "drift":
            raise ConfigError(f"intruders: in {name} the intruders are an agent and act themselves; leave "
                              f"intruders at drift (got {self.config.intruders!r})", field="intruders")
        if render_mode not in (None, "rgb_array"):
            raise ConfigError(f"render_mode: must be None or 'rgb_array', got {render_mode!r}", field="render_mode")
        self.information = self.config.information if information is None else information
        self.estimates = estimates
        self.render_mode = render_mode
        n = self.config.grid_size
        self.n = n
        self.layout = Layout(n)
        self.possible_agents = list(AGENTS)
        self.agents: list[str] = []
        cells = 2 * n * n
        self.observation_spaces = {agent: Box(0.0, 1.0, shape=(cells,), dtype=np.float32) for agent in AGENTS}
        self.action_spaces = {"defenders": Box(-1.0, 1.0, shape=(len(self.layout.src),), dtype=np.float32),
                              "intruders": Box(-1.0, 1.0, shape=(len(self.layout.route_src),), dtype=np.float32)}
        self.state_space = Box(0.0, 1.0, shape=(cells,), dtype=np.float32)
        self._owns_client = client is None  # close() closes a client the env made, never one it was given
        self.client = env_client(self.config, store) if client is None else client
        self.model = EngagementModel(self.config, self.client, estimates)
        self.np_random: np.random.Generator | None = None
        self.D = np.zeros(n * n)
        self.I = np.zeros(n * n)
        self.moved: np.ndarray | None = None
        self.steps = 0
        self.breached = 0.0
        self.eliminated = 0.0
        self.engagements = 0
        self.estimated = 0

    def observation_space(self, agent: str) -> Box:
        """The agent's observation space: Box(0, 1, (2 N^2,), float32), [D, I] or [D', I]."""
        return self.observation_spaces[agent]

    def action_space(self, agent: str) -> Box:
        """The agent's action space: the defenders' Box(-1, 1, (A,), float32), A = n_actions(N), one
        number per feasible move; the intruders' Box(-1, 1, (R,), float32), R = N (3N - 2), one
        number per route (farm.alloc.game.dynamics.routes)."""
        return self.action_spaces[agent]

    def state(self) -> np.ndarray:
        """The global state: (2 N^2,) float32 [D, I] clipped to [0, 1], D the defenders as they stand
        (after their move while the intruders are to act)."""
        return observe(self._defenders_now()[None], self.I[None])[0]

    def render(self):
        """The densities as they stand as an image: (32 N, 32 N, 3) uint8 under render_mode
        "rgb_array", else None. Defenders blue, intruders red (farm.alloc.game.plots.density_frame)."""
        if self.render_mode != "rgb_array":
            return None
        from farm.alloc.game.plots import density_frame

        return density_frame(self._defenders_now().reshape(self.n, self.n), self.I.reshape(self.n, self.n),
                             self.steps)

    def close(self):
        """Close the client (and its store) when the env made it; a client it was given stays open
        for its owner. Closing twice does nothing more."""
        if self._owns_client:
            self._owns_client = False
            self.client.close()

    # ----- the game's pieces ------------------------------------------------------------
    def _defenders_now(self) -> np.ndarray:
        return self.D if self.moved is None else self.moved

    def _start(self, seed) -> dict:
        """Start an episode as SwarmAllocationEnv.reset(seed=seed) does; returns the info."""
        if seed is not None or self.np_random is None:
            self.np_random, _ = seeding.np_random(seed)
        D, I = start_densities(self.layout, self.np_random.dirichlet(np.ones(self.n))[None])
        self.D, self.I = D[0], I[0]
        self.moved = None
        self.steps = 0
        self.breached = 0.0
        self.eliminated = 0.0
        self.agents = list(AGENTS)
        return self._info(0.0, 0.0, 0, 0, float(row_sums(I)[0]))

    def _check(self, agent: str, action, name: str) -> np.ndarray:
        """The agent's action as (K,) float64 (check_actions), or ActionError naming it as `name`."""
        return check_actions(action, self.action_spaces[agent].shape, name)

    def _move(self, action: np.ndarray) -> np.ndarray:
        """The defenders after their move: action: (A,) float64 -> D': (N^2,) float64."""
        p = move_probabilities(self.layout, self.config, action[None])
        return move_defenders(self.layout, self.D[None], p)[0]

    def _resolve(self, moved: np.ndarray, action: np.ndarray) -> tuple[float, bool, bool, dict]:
        """The rest of the step from the defenders after their move moved: (N^2,) float64 and the
        intruders' action: (R,) float64; the state and counters move on. Returns (R, terminated,
        truncated, info), R the defenders' reward."""
        routing = routing_of(self.layout, route_probabilities(self.layout, self.config, action[None]))
        r = resolve(self.layout, self.config, self.model, moved[None], self.I[None], routing)
        self.moved = None
        breach, eliminated, engaged, estimates = tally_step(self, r)
        terminated, truncated = episode_end(self.config, np.array([self.steps]), r.remaining)
        info = self._info(breach, eliminated, engaged, estimates, float(r.remaining[0]), float(r.coverage[0]),
                          float(r.per_engaged[0]))
        return float(r.reward[0]), bool(terminated[0]), bool(truncated[0]), info

    def _info(self, breach, eliminated, engaged, estimates, mass, coverage=0.0, per_cell=0.0) -> dict:
        """The step's measures, as SwarmAllocationEnv's info."""
        return {"breached_step": breach, "breached": self.breached, "eliminated_step": eliminated,
                "eliminated": self.eliminated, "engaged_cells": engaged, "estimates": estimates,
                "intruder_mass": mass, "coverage": coverage, "defenders_per_engaged": per_cell}


class SwarmAllocationAECEnv(_TwoSides, AECEnv):
    """The grid allocation MDP as a two-player AEC game: the defenders act, then the intruders.

    Each step, in PettingZoo's agent order:

    1. `defenders` observe [D, I] and act: Box(-1, 1, (A,), float32), the single env's action
       (SwarmAllocationEnv), mapped by the config's `action_map` to move probabilities; the
       defenders move, D' = T D;
    2. `intruders` observe [D', I] under `information: follower` (the default), or [D, I] under
       `simultaneous` (the defenders' move unseen), and act: Box(-1, 1, (R,), float32), R = N (3N
       - 2), one number per route of each cell (up-left, left, down-left; two on the top and
       bottom rows, farm.alloc.game.dynamics.routes), mapped to each cell's route shares by the same
       `action_map`; their mass is routed and advances one column left (what leaves column 0 has
       breached);
    3. every cell holding both sides engages and the reward R is the single env's; the defenders
       get R, the intruders -R (rewards, at the step's end: each agent's last() holds its reward
       since it last acted).

    Observations: (2 N^2,) float32 [D, I] clipped to [0, 1], D at index c and I at N^2 + c for
    cell c = row * N + col. Actions are clipped to [-1, 1]; step() refuses an action of another
    shape, not of real numbers, or with NaN or an infinity with farm.core.errors.ActionError (one
    line naming the agent's action) before anything changes. An episode starts as the single
    env's (all defenders at the base, the intruders over the right-most column, their row shares
    drawn from the generator reset(seed=...) seeds, the draw the single env's reset(seed=...)
    makes) and ends as its: both agents terminate when the intruder mass falls below `epsilon`,
    else are truncated after `max_steps` steps; each is then stepped once with None (PettingZoo's
    dead step) and removed. infos: both agents get the single env's info of the last step (of
    reset() after it). step() before reset(), or once every agent is removed, raises
    gymnasium.error.ResetNeeded.

    Arguments: as SwarmAllocationEnv's: config (AllocConfig or None), client, store,
    render_mode (None or "rgb_array", else ConfigError), estimates, **kwargs (AllocConfig
    fields when config is None). The config's `intruders` must be `drift` (ConfigError naming
    it): the intruders' action routes them, so no intruder policy and no `vertical_drift` is
    played. Attributes: _TwoSides' (information: the config's).
    """

    metadata: ClassVar[dict] = {"name": "swarm_allocation_v0", "render_modes": ["rgb_array"], "render_fps": 2,
                "is_parallelizable": False}

    def __init__(self, config: AllocConfig | None = None, *, client=None, store=None, render_mode: str | None = None,
                 estimates: bool | str = False, **kwargs):
        """Make the env; the class docstring describes the arguments."""
        super().__init__(config, client, store, render_mode, estimates, kwargs, None)
        self.rewards: dict[str, float] = {}
        self._cumulative_rewards: dict[str, float] = {}
        self.terminations: dict[str, bool] = {}
        self.truncations: dict[str, bool] = {}
        self.infos: dict[str, dict] = {}
        self.agent_selection = AGENTS[0]

    def reset(self, seed: int | None = None, options: dict | None = None) -> None:
        """Start an episode (the class docstring); the defenders act first. options: unused."""
        info = self._start(seed)
        self.rewards = dict.fromkeys(self.agents, 0.0)
        self._cumulative_rewards = dict.fromkeys(self.agents, 0.0)
        self.terminations = dict.fromkeys(self.agents, False)
        self.truncations = dict.fromkeys(self.agents, False)
        self.infos = {agent: dict(info) for agent in self.agents}
        self.agent_selection = AGENTS[0]

    def observe(self, agent: str) -> np.ndarray:
        """The agent's observation: (2 N^2,) float32, [D, I] for the defenders; for the intruders
        [D', I] once the defenders have moved this step under `follower`, else [D, I]."""
        if agent == "intruders" and self.information == "follower":
            return self.state()
        return observe(self.D[None], self.I[None])[0]

    def step(self, action) -> None:
        """The selected agent's action (the class docstring); None for an agent that has ended."""
        if not self.agents:
            raise ResetNeeded("Cannot call step() before reset() or after the episode's end: call reset()")
        agent = self.agent_selection
        if self.terminations[agent] or self.truncations[agent]:
            self._was_dead_step(action)
            return
        a = self._check(agent, action, f"{agent}' action")
        self._cumulative_rewards[agent] = 0.0
        if agent == "defenders":
            self.moved = self._move(a)
            self.rewards = dict.fromkeys(self.agents, 0.0)
            self.agent_selection = "intruders"
        else:
            reward, terminated, truncated, info = self._resolve(self.moved, a)
            self.rewards = {"defenders": reward, "intruders": -reward}
            self.terminations = dict.fromkeys(self.agents, terminated)
            self.truncations = dict.fromkeys(self.agents, truncated)
            self.infos = {agent: dict(info) for agent in self.agents}
            self.agent_selection = "defenders"
        self._accumulate_rewards()


class SwarmAllocationParallelEnv(_TwoSides, ParallelEnv):
    """The grid allocation MDP as a two-player game of simultaneous moves (PettingZoo's ParallelEnv).

    Both agents observe [D, I] ((2 N^2,) float32, as in SwarmAllocationAECEnv) and act at once:
    step({"defenders": (A,), "intruders": (R,)}) moves the defenders, routes the intruders from
    the same state and resolves the step; the defenders get the single env's reward R, the
    intruders -R. The same game as SwarmAllocationAECEnv under `information: simultaneous`,
    whatever the config's `information` says: a step in which both act at once has no order.
    ActionError (one line naming `actions` or the agent's entry, `actions['defenders']`) for
    actions that are not a dict of exactly the two agents' actions or an action refused as
    SwarmAllocationAECEnv refuses it, before anything changes. Starts and ends as
    SwarmAllocationAECEnv; at the episode's end agents is empty, and step() then (or before
    reset()) raises gymnasium.error.ResetNeeded.

    Arguments: as SwarmAllocationAECEnv's. Attributes: _TwoSides' (information: "simultaneous").
    """

    metadata: ClassVar[dict] = {"name": "swarm_allocation_v0", "render_modes": ["rgb_array"], "render_fps": 2}

    def __init__(self, config: AllocConfig | None = None, *, client=None, store=None, render_mode: str | None = None,
                 estimates: bool | str = False, **kwargs):
        """Make the env; the class docstring describes the arguments."""
        super().__init__(config, client, store, render_mode, estimates, kwargs, "simultaneous")

    def reset(self, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        """Start an episode; returns (observations, infos), each a dict by agent. options: unused."""
        info = self._start(seed)
        return self._observations(), {agent: dict(info) for agent in self.agents}

    def step(self, actions: dict) -> tuple[dict, dict, dict, dict, dict]:
        """Both agents' actions at once; returns (observations, rewards, terminations, truncations,
        infos), each a dict by agent."""
        if not self.agents:
            raise ResetNeeded("Cannot call step() before reset() or after the episode's end: call reset()")
        if not isinstance(actions, Mapping) or set(actions) != set(AGENTS):
            got = (f"the keys {', '.join(map(repr, actions)) or 'none'}" if isinstance(actions, Mapping)
                   else f"a {type(actions).__name__}")
            raise ActionError(f"actions: expected a dict of an action for each of 'defenders' and 'intruders', "
                              f"got {got}")
        defenders = self._check("defenders", actions["defenders"], "actions['defenders']")
        intruders = self._check("intruders", actions["intruders"], "actions['intruders']")
        playing = list(self.agents)
        reward, terminated, truncated, info = self._resolve(self._move(defenders), intruders)
        if terminated or truncated:
            self.agents = []
        return (self._observations(playing), {"defenders": reward, "intruders": -reward},
                dict.fromkeys(playing, terminated), dict.fromkeys(playing, truncated),
                {agent: dict(info) for agent in playing})

    def _observations(self, agents: list[str] | None = None) -> dict:
        obs = observe(self.D[None], self.I[None])[0]
        return {agent: obs.copy() for agent in (self.agents if agents is None else agents)}


def raw_env(config: AllocConfig | None = None, **kwargs) -> SwarmAllocationAECEnv:
    """The AEC env without wrappers: SwarmAllocationAECEnv(config, **kwargs)."""
    return SwarmAllocationAECEnv(config, **kwargs)


def env(config: AllocConfig | None = None, **kwargs) -> OrderEnforcingWrapper:
    """The AEC env as PettingZoo's own envs come: raw_env(config, **kwargs) in OrderEnforcingWrapper
    (step(), observe() and render() before reset() are errors, a step after the episode's end a
    warning). Out-of-range action values are clipped, as the single env clips them."""
    return OrderEnforcingWrapper(raw_env(config, **kwargs))


def parallel_env(config: AllocConfig | None = None, **kwargs) -> SwarmAllocationParallelEnv:
    """The ParallelEnv of simultaneous play: SwarmAllocationParallelEnv(config, **kwargs)."""
    return SwarmAllocationParallelEnv(config, **kwargs)
