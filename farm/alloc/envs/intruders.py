"""The intruders' side of the grid MDP as a gymnasium env, against a frozen allocator (docs/model.md section 8).

SwarmIntruderEnv is one episode (the id `farm/SwarmIntruders-v0`, and `farm/<name>-intruders-v0`
with each scenario's settings); SwarmIntruderVectorEnv, the ids' `vector_entry_point`, batches
it as farm.alloc.envs.vector batches farm.alloc.envs.defenders:

    env = gymnasium.make("farm/outnumbered_3x3-intruders-v0", opponent="stay_at_base")

The episodes are the defenders' env's (the same start from the same seeded generator, the same
step, info and end) with the sides swapped: the agent routes the intruders and a frozen
allocator (Opponent) moves the defenders. A step is the pieces farm.alloc.game.dynamics.step is made
of: defenders_move of the allocator's action, intruder_routing of the agent's, resolve. Episode
k of a batch reset with seed s is, to the last bit, the single env reset with seed s + k.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium.error import ResetNeeded
from gymnasium.vector.utils import batch_space

from farm.alloc.allocators import allocator_entry
from farm.alloc.envs.defenders import GridEnv
from farm.alloc.envs.move_helpers import check_procs
from farm.alloc.envs.vector import GridVectorEnv
from farm.alloc.game.config import AllocConfig
from farm.alloc.game.dynamics import (
    Layout,
    StepResult,
    check_actions,
    check_pure_routes,
    defenders_move,
    intruder_routing,
    observe,
    pure_routing,
    resolve,
)
from farm.alloc.intruders.play import draw_state, for_episode
from farm.core.errors import ConfigError

__all__ = ["ACTIONS", "DEFAULT_OPPONENT", "REWARDS", "Opponent", "SwarmIntruderEnv", "SwarmIntruderVectorEnv"]

ACTIONS = ("shares", "pure")  # the intruders' action: each cell's shares of its routes, or one route a cell
REWARDS = ("eliminated", "zero_sum")  # the intruders' reward: minus the mass eliminated, or minus the defenders'
DEFAULT_OPPONENT = "intercept"  # the frozen allocator when none is named


class Opponent:
    """The frozen allocator of the intruders' env: the allocator `name` of the registry
    (farm.alloc.allocators: a baseline, a planner, or a learned one such as `ppo` with options
    {run: FOLDER}) with its options, made as make_allocator makes it, on config's map and the env's
    client. ConfigError (one line) naming `opponent` for a name the registry does not hold, and
    `opponent_options` for an option the allocator does not take or that it refuses.

    procs: the processes that answer a batch's moves, the caller's and procs - 1 helpers
    (farm.alloc.envs.move_helpers.MoveHelpers: on Ray, the same moves whatever procs); close() stops them.

    Attributes: name: str; policy: the allocator (its predict()); layout: the map's Layout.
    """

    def __init__(self, config: AllocConfig, client, name: str, options: dict | None = None, procs: int = 1):
        procs = check_procs(procs)
        entry = allocator_entry(name, "opponent")
        options = dict(options or {})
        unknown = sorted(set(options) - set(entry.options()))
        if unknown:
            raise ConfigError(f"opponent_options: {name} has no option {unknown[0]!r} (options: "
                              f"{', '.join(entry.options()) or 'none'})", field="opponent_options")
        try:
            self.policy = entry.make(config, client, **options)
        except ConfigError as e:
            raise ConfigError(f"opponent_options: {name}: {e}", field="opponent_options") from None
        self.name = name
        self.config = config
        self.layout = Layout(config.grid_size)
        self.helpers = None
        if procs > 1:
            from farm.alloc.envs.move_helpers import MoveHelpers

            self.helpers = MoveHelpers(config, client, name, options, procs)

    def moves(self, D: np.ndarray, I: np.ndarray, players: list | None = None) -> np.ndarray:
        """The defenders after the allocator's move from each episode's state: D, I: (B, N^2)
        float64 -> (B, N^2) float64; players: each episode's allocator (for_episode's draw of a
        mixture), default the allocator itself. The allocator is asked as farm.alloc.evaluation.rollout.play
        asks it, predict(obs, deterministic=True) on each episode's float32 observation [D, I]
        alone, and its actions are checked (ActionError naming `opponent action`) before anything moves."""
        obs = observe(D, I)
        players = players if players is not None else [self.policy] * len(obs)
        if self.helpers is not None and len(obs) > 1:
            actions = self.helpers.moves(self.policy, players, obs)
        else:
            actions = [player.predict(o, deterministic=True)[0] for player, o in zip(players, obs)]
        a = check_actions(actions, (len(obs), len(self.layout.src)), "opponent action")
        return defenders_move(self.layout, self.config, D, a)

    def close(self) -> None:
        """Stop the helpers, if any."""
        if self.helpers is not None:
            self.helpers.close()


def _check_actions_kind(actions) -> str:
    """actions as one of ACTIONS, or a one-line ConfigError naming `actions`."""
    if not isinstance(actions, str) or actions not in ACTIONS:
        raise ConfigError(f"actions: must be one of {', '.join(ACTIONS)}, got {actions!r}", field="actions")
    return actions


def _action_space(layout, actions: str):
    """The intruders' single action space: Box(-1, 1, (R,)) of route shares, or MultiDiscrete of
    each cell's routes (pure)."""
    if actions == "pure":
        return gym.spaces.MultiDiscrete(layout.n_routes)
    return gym.spaces.Box(-1.0, 1.0, shape=(len(layout.route_src),), dtype=np.float32)


def _routing(layout, config: AllocConfig, actions: str, action, shape: tuple, name: str):
    """The routing of a batch of intruder actions, each checked (ActionError naming name)."""
    if actions == "pure":
        return pure_routing(layout, check_pure_routes(layout, action, shape, name))
    return intruder_routing(layout, config, check_actions(action, shape, name).reshape(-1, len(layout.route_src)))


def _check_reward(reward) -> str:
    """reward as one of REWARDS, or a one-line ConfigError naming `reward`."""
    if not isinstance(reward, str) or reward not in REWARDS:
        raise ConfigError(f"reward: must be one of {', '.join(REWARDS)}, got {reward!r}", field="reward")
    return reward


def _check_intruders(config: AllocConfig) -> None:
    """ConfigError (one line naming `intruders`) when config names an intruder policy: in the
    intruders' env the agent routes them."""
    if config.intruders != "drift":
        raise ConfigError(f"intruders: the intruders' env routes the intruders by its agent's actions; leave "
                          f"intruders at drift, got {config.intruders!r}", field="intruders")


def _intruder_rewards(reward: str, r: StepResult) -> np.ndarray:
    """The intruders' rewards of a step: (B,) float64, minus the mass eliminated (`eliminated`)
    or minus the defenders' reward (`zero_sum`)."""
    return -r.eliminated if reward == "eliminated" else -r.reward


def _check_moved(state: dict, shape: tuple, optional: bool) -> None:
    """ConfigError (one line naming set_state) unless state["moved"] holds the defenders after
    the allocator's move: finite numbers >= 0 of shape (None too when optional)."""
    if not isinstance(state, dict):
        return  # GridEnv's and GridVectorEnv's set_state refuse it (check_state)
    if "moved" not in state:
        raise ConfigError("set_state: the state has no 'moved'", field="set_state")
    moved = state["moved"]
    if moved is None and optional:
        return
    values = np.asarray(moved) if moved is not None else np.zeros(0)
    if values.shape != shape or values.dtype.kind not in "iuf" or not np.all(np.isfinite(values)) \
            or np.any(values < 0):
        raise ConfigError(f"set_state: the state's moved defenders must be finite numbers >= 0 of shape {shape}",
                          field="set_state")


class SwarmIntruderEnv(GridEnv):
    """The grid MDP played by the intruders against a frozen allocator.

    ## Description

    SwarmAllocationEnv's MDP (farm.alloc.envs.defenders, its docstring) with the sides swapped: each step
    the agent routes each cell's intruder mass up-left, left or down-left, and the frozen
    allocator `opponent` moves the defenders. What the agent sees when it routes is the
    config's `information`:

    - `follower` (the default): the allocator moves first (its action on [D, I]), and the
      agent sees [D', I], D' the defenders after that move;
    - `simultaneous`: the agent sees [D, I] and the allocator moves from the same state within
      the step.

    A step: the defenders move, D' = T D (defenders_move of the allocator's action); the
    intruders move by the agent's routing (intruder_routing); every cell holding both engages;
    the reward (farm.alloc.game.dynamics.resolve, the defenders' env's own step after its move).

    ## Action Space

    A `Box(-1, 1, (R,), float32)`, R = N (3N - 2) (21 for N = 3): one number per route (up-left,
    left, down-left; the top and bottom rows have two), cell by cell in cell order
    (farm.alloc.game.dynamics.routes), mapped to each cell's shares as the defenders' actions are
    (`action_map`, route_probabilities). step() refuses (farm.core.errors.ActionError, naming
    `intruder action`) an action of another shape, of no real numbers or not finite, leaving
    the env as it was.

    ## Observation Space

    A `Box(0, 1, (2 N^2,), float32)`: [D', I] under `follower`, [D, I] under `simultaneous`,
    clipped to [0, 1]. The last observation of an episode is the state it ended in, [D, I]
    (the allocator does not move after the end).

    ## Rewards

    `reward: eliminated` (the default): minus the intruder mass eliminated in the step (the
    intruders want to survive); `zero_sum`: minus the defenders' reward (the game is zero-sum).

    ## Starting State, Episode End, Info

    The defenders' env's: the same start drawn from the same seeded generator (reset(seed=s)
    starts the episode SwarmAllocationEnv's reset(seed=s) starts), the same end and the same
    info keys.

    ## Arguments

    Those of SwarmAllocationEnv (config or AllocConfig keyword arguments, client, store,
    render_mode, estimates), and:

    - `opponent`: str, the frozen allocator's name in farm.alloc.allocators' registry (default
      `intercept`); `opponent_options`: dict or None, its options (a learned allocator's
      `run`), ConfigError naming `opponent` or `opponent_options` when refused (Opponent);
    - `reward`: `eliminated` or `zero_sum`, else ConfigError naming `reward`;
    - `actions`: `shares` (the default: Box(-1, 1, (R,)), each cell's shares of its routes mapped
      by the config's action_map) or `pure` (MultiDiscrete: one route a cell, each cell's routes
      in the routes() order, the family the exact search answers in), else ConfigError naming
      `actions`.

    The config's `intruders` must be `drift` (the agent routes them; ConfigError naming
    `intruders` otherwise). get_state() and set_state() save and restore what the defenders'
    env's do and the allocator's move already made (`moved`).

    Attributes: those of farm.alloc.envs.defenders.GridEnv (config, client, model, layout, D, I, the
    counters); opponent: Opponent; reward: str; moved: (N^2,) float64 the defenders after the
    allocator's move from the current state, or None while it has not moved (simultaneous, an
    episode's end).
    """

    def __init__(self, config: AllocConfig | None = None, *, opponent: str = DEFAULT_OPPONENT,
                 opponent_options: dict | None = None, reward: str = "eliminated", actions: str = "shares",
                 client=None, store: str | None = None, render_mode: str | None = None, estimates: bool | str = False,
                 **kwargs):
        """Make the env; the class docstring's Arguments section describes each argument."""
        self.reward = _check_reward(reward)
        self.actions = _check_actions_kind(actions)
        super().__init__("SwarmIntruderEnv", config, client, store, render_mode, estimates, kwargs)
        try:
            _check_intruders(self.config)
            self.opponent = Opponent(self.config, self.client, opponent, opponent_options)
        except BaseException:
            self.close()  # the client it made
            raise
        self.action_space = _action_space(self.layout, self.actions)
        self.follower = self.config.information == "follower"
        self.moved: np.ndarray | None = None
        self._episode_opponent = self.opponent.policy  # the episode's draw of an allocator that draws per episode

    def step(self, action):
        """One step (see Description); returns (obs, reward, terminated, truncated, info).

        action: (R,) finite numbers, clipped to [-1, 1]; obs: (2 N^2,) float32; reward: float;
        terminated, truncated: bool; info: the defenders' env's. Raises
        gymnasium.error.ResetNeeded before the first reset(), and ActionError for an action of
        another shape, not of real numbers, or not finite, leaving the env as it was.
        """
        if not self._reset_done:
            raise ResetNeeded("Cannot call env.step() before calling env.reset()")
        routing = _routing(self.layout, self.config, self.actions, action, self.action_space.shape, "intruder action")
        D, I = self.D[None], self.I[None]
        moved = self.opponent.moves(D, I, [self._episode_opponent]) if self.moved is None else self.moved[None]
        r = resolve(self.layout, self.config, self.model, moved, I, routing)
        self.moved = None
        return self._record(r)

    def _prepare(self) -> None:
        """Under follower, the allocator moves from the state the agent is about to see."""
        if self.follower:
            self.moved = self.opponent.moves(self.D[None], self.I[None], [self._episode_opponent])[0]

    def _draw(self) -> None:
        """The episode's allocator: one that draws per episode draws from the env's generator."""
        self._episode_opponent = for_episode(self.opponent.policy, self.np_random)

    def _draw_state(self) -> dict:
        """{"opponent_draw": the episode's draw} for an allocator that draws per episode, else {}."""
        saved = draw_state(self._episode_opponent)
        return {} if saved is None else {"opponent_draw": saved}

    def _resume_draw(self, state: dict) -> None:
        """The episode's allocator from a saved draw."""
        if "opponent_draw" in state:
            self._episode_opponent = self.opponent.policy.resume_episode(state["opponent_draw"])

    def _obs(self) -> np.ndarray:
        """The observation: (2 N^2,) float32 [D', I] when the allocator has moved, else [D, I]."""
        return observe((self.D if self.moved is None else self.moved)[None], self.I[None])[0]

    def _reward(self, r: StepResult) -> np.ndarray:
        """The intruders' reward (see Rewards): (1,) float64."""
        return _intruder_rewards(self.reward, r)

    def get_state(self) -> dict:
        """The defenders' env's state (SwarmAllocationEnv.get_state) and moved: (N^2,) float64 a
        copy of the allocator's move already made, or None."""
        return {**super().get_state(), "moved": None if self.moved is None else self.moved.copy()}

    def set_state(self, state: dict) -> None:
        """Take a state get_state() returned (SwarmAllocationEnv.set_state's rules, and a `moved`
        of this grid or None); ConfigError (one line naming set_state) otherwise, the env unchanged."""
        _check_moved(state, (self.n * self.n,), optional=True)
        super().set_state(state)
        self.moved = None if state["moved"] is None else np.array(state["moved"], dtype=np.float64)


class SwarmIntruderVectorEnv(GridVectorEnv):
    """B = num_envs episodes of SwarmIntruderEnv stepped together (gymnasium VectorEnv).

    Each episode is SwarmIntruderEnv's (its docstring); this class batches it as
    farm.alloc.envs.vector.SwarmAllocationVectorEnv batches the defenders' env, with the same
    seeds, SAME_STEP autoreset, infos, get_state and set_state (its docstring). Spaces:
    single_observation_space Box(0, 1, (2 N^2,), float32) and single_action_space Box(-1, 1,
    (R,), float32), and their batches. The allocator is asked for each episode alone, as the
    single env asks it, so that episode k of a batch reset with seed s is, to the last bit, the
    single env reset with seed s + k and given the same actions.

    step(actions): actions (B, R) finite numbers (ActionError naming `intruder actions`
    otherwise, before anything changes). The ended episodes' last observations
    (infos["final_obs"]) are the states they ended in, [D, I].

    Arguments: those of SwarmIntruderEnv and num_envs: int >= 1; render_mode None only;
    opponent_procs: the processes that answer the allocator's moves (Opponent's procs, at most
    num_envs: 1, the default, this process alone; more needs Ray and a client on the
    capture-time service actor).

    Attributes: those of GridVectorEnv; opponent: Opponent; reward: str; moved: (B, N^2)
    float64 the defenders after the allocator's move from each episode's state (under
    follower; zeros under simultaneous).
    """

    STATE_FIELDS = (*GridVectorEnv.STATE_FIELDS, "moved")

    def __init__(self, config: AllocConfig | None = None, num_envs: int = 1, *, opponent: str = DEFAULT_OPPONENT,
                 opponent_options: dict | None = None, reward: str = "eliminated", actions: str = "shares",
                 client=None, store: str | None = None, render_mode: str | None = None, estimates: bool | str = False,
                 opponent_procs: int = 1, **kwargs):
        """Make the env; the class docstring's Arguments describe each argument."""
        self.reward = _check_reward(reward)
        self.actions = _check_actions_kind(actions)
        super().__init__("SwarmIntruderVectorEnv", config, num_envs, client, store, render_mode, estimates, kwargs)
        try:
            _check_intruders(self.config)
            self.opponent = Opponent(self.config, self.client, opponent, opponent_options,
                                     min(check_procs(opponent_procs), self.num_envs))
        except BaseException:
            self.close_extras()  # the client it made
            raise
        self.single_action_space = _action_space(self.layout, self.actions)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.follower = self.config.information == "follower"
        self.moved = np.zeros_like(self.D)
        self._episode_opponents = [self.opponent.policy] * self.num_envs  # each episode's draw of the allocator

    def step(self, actions):
        """One step of every episode, with SAME_STEP autoreset (see the class docstring).

        actions: (B, R) finite numbers, clipped to [-1, 1]. Returns (obs: (B, 2 N^2) float32,
        rewards: (B,) float64, terminated, truncated: (B,) bool, infos). ResetNeeded before
        every episode has been reset; ActionError for actions of another shape, not numbers or
        not finite, leaving the env as it was.
        """
        if not self.started.all():
            raise ResetNeeded("Cannot call env.step() before calling env.reset()")
        routing = _routing(self.layout, self.config, self.actions, actions, self.action_space.shape,
                           "intruder actions")
        moved = self.moved if self.follower else self.opponent.moves(self.D, self.I, self._episode_opponents)
        return self._record(resolve(self.layout, self.config, self.model, moved, self.I, routing))

    def _prepare(self, episodes: np.ndarray) -> None:
        """Under follower, the allocator moves from the states of the episodes (indices, (m,) int64)."""
        if self.follower and len(episodes):
            self.moved[episodes] = self.opponent.moves(self.D[episodes], self.I[episodes],
                                                       [self._episode_opponents[k] for k in episodes.tolist()])

    def _draw(self, k: int, rng) -> None:
        """Episode k's allocator: one that draws per episode draws from its generator."""
        self._episode_opponents[k] = for_episode(self.opponent.policy, rng)

    def _draw_state(self) -> dict:
        """{"opponent_draws": each episode's draw (None: none)} for an allocator that draws per episode, else {}."""
        saved = [draw_state(p) for p in self._episode_opponents]
        return {} if all(d is None for d in saved) else {"opponent_draws": saved}

    def _resume_draw(self, state: dict) -> None:
        """The episodes' allocators from their saved draws."""
        if "opponent_draws" in state:
            self._episode_opponents = [self.opponent.policy if d is None else self.opponent.policy.resume_episode(d)
                                       for d in state["opponent_draws"]]

    def _observations(self) -> np.ndarray:
        """(B, 2 N^2) float32: [D', I] under follower, [D, I] under simultaneous."""
        return observe(self.moved if self.follower else self.D, self.I)

    def _reward(self, r: StepResult) -> np.ndarray:
        """The intruders' rewards (SwarmIntruderEnv's Rewards): (B,) float64."""
        return _intruder_rewards(self.reward, r)

    def close_extras(self, **kwargs) -> None:
        """Stop the allocator's helpers, then GridVectorEnv's close_extras."""
        opponent = getattr(self, "opponent", None)
        if opponent is not None:
            opponent.close()
        super().close_extras(**kwargs)

    def get_state(self) -> dict:
        """GridVectorEnv's state and moved: (B, N^2) float64, a copy."""
        return {**super().get_state(), "moved": self.moved.copy()}

    def set_state(self, state: dict) -> None:
        """Take a state get_state() returned (GridVectorEnv.set_state's rules, and a `moved` of
        this batch and grid); ConfigError (one line naming set_state) otherwise, the env unchanged."""
        _check_moved(state, self.D.shape, optional=False)
        super().set_state(state)
        self.moved = np.array(state["moved"], dtype=np.float64)
