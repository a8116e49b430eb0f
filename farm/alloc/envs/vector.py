"""B episodes of the grid allocation MDP stepped at once in numpy: a gymnasium VectorEnv.

SwarmAllocationVectorEnv is the batched form of farm.alloc.envs.defenders.SwarmAllocationEnv (whose
docstring is the MDP), registered as the `vector_entry_point` of `farm/SwarmAllocation-v0` and
of every scenario's `farm/<name>-v0`:

    import gymnasium, farm.alloc
    envs = gymnasium.make_vec("farm/outnumbered_3x3-v0", num_envs=16, vectorization_mode="vector_entry_point")

A step moves all B episodes with farm.alloc.game.dynamics.step, the single env's own step, and asks
the capture-time client once (one get_many) for every engaged cell of the B episodes, each
distinct team-size pair once. Episode k of a batch reset with seed s is, to the last bit, the
single env reset with seed s + k and given the same actions: the same observations, rewards,
ends and info values (tests/test_vector_env.py). farm.alloc.envs.sb3_vec adapts it to
stable-baselines3's VecEnv.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium.error import ResetNeeded
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from farm.alloc.envs.defenders import check_env_arguments, check_state, env_client, resume_draws
from farm.alloc.game.config import AllocConfig
from farm.alloc.game.dynamics import (
    Layout,
    StepResult,
    check_actions,
    episode_end,
    observe,
    start_densities,
    step,
)
from farm.alloc.game.model import EngagementModel, row_sums
from farm.alloc.intruders.play import (
    EpisodeIntruders,
    configured_intruders,
    draw_state,
    for_episode,
    intruder_move,
)
from farm.core.checks import is_whole, whole
from farm.core.errors import ConfigError

__all__ = ["GridVectorEnv", "SwarmAllocationVectorEnv", "INFO_KEYS", "batch_bytes", "check_batch"]

# The single env's info entries, in its order, with the dtype gymnasium batches each one as.
INFO_KEYS = (("breached_step", np.float64), ("breached", np.float64), ("eliminated_step", np.float64),
             ("eliminated", np.float64), ("engaged_cells", np.int64), ("estimates", np.int64),
             ("intruder_mass", np.float64), ("coverage", np.float64), ("defenders_per_engaged", np.float64))
_FLOATS = [key for key, dtype in INFO_KEYS if dtype is np.float64]  # the rows of step()'s (7, B) block
_INTS = [key for key, dtype in INFO_KEYS if dtype is np.int64]  # and of its (2, B) block
_MASS = _FLOATS.index("intruder_mass")
_STATE_FIELDS = ("num_envs", "D", "I", "steps", "breached", "eliminated", "started", "rngs", "engagements",
                 "estimated")


EPISODE_CELL_FLOATS = 32  # float64 values a cell of one episode holds at most: its state, bounds, a step's
EPISODE_MOVE_FLOATS = 8  # ... and per feasible move (its actions and move probabilities)
EPISODE_BYTES = 4096  # ... and beyond them: its generator, its infos' entries (generous)


def _num_envs(value) -> int:
    """num_envs as an int >= 1, or a one-line ConfigError naming it."""
    return whole("num_envs", value, 1, numpy=True)


def batch_bytes(num_envs: int, layout: Layout) -> int:
    """What num_envs episodes of layout's grid hold in memory at most, in bytes: the batched
    env's arrays and one step's (EPISODE_CELL_FLOATS, EPISODE_MOVE_FLOATS, EPISODE_BYTES)."""
    moves = max(len(layout.src), len(layout.route_src))
    return num_envs * (8 * (EPISODE_CELL_FLOATS * layout.cells + EPISODE_MOVE_FLOATS * moves) + EPISODE_BYTES)


def check_batch(num_envs: int, layout: Layout) -> None:
    """ConfigError (one line naming num_envs) when num_envs episodes (batch_bytes) need more than
    half of this machine's memory (farm.games.sizes.memory_limit): refused before any array."""
    from farm.games.sizes import memory_limit

    needed, limit = batch_bytes(num_envs, layout), memory_limit()
    if needed > limit:
        raise ConfigError(f"num_envs: {num_envs:,} episodes of a {layout.n} x {layout.n} grid need about "
                          f"{needed / 2**30:,.1f} GiB in memory, more than half of this machine's "
                          f"({limit / 2**30:,.1f} GiB); step at most {max(1, limit // batch_bytes(1, layout)):,} "
                          f"at once", field="num_envs")


class GridVectorEnv(VectorEnv):
    """B episodes of the grid MDP stepped together, whichever side acts in them: the part the
    defenders' batched env (SwarmAllocationVectorEnv, whose docstring describes each piece) and
    the intruders' (farm.alloc.envs.intruders.SwarmIntruderVectorEnv) share: the arguments, the
    observation spaces, the starts and their seeds, a step's accounting, infos and SAME_STEP
    autoreset (_record of the step's StepResult), get_state and set_state, close. A subclass
    sets the action spaces and step(); its hooks are _prepare (before the agent sees the
    episodes' states), _observations (what it sees) and _reward (what it gets).

    Attributes: config: AllocConfig; client; model: EngagementModel; layout:
    farm.alloc.game.dynamics.Layout; num_envs: int, B; D, I: (B, N^2) float64 the densities;
    steps: (B,) int64; breached, eliminated: (B,) float64 the episodes' counters; started:
    (B,) bool, the episodes reset at least once; engagements, estimated: int, the engaged
    cells answered over the env's lifetime and of them the interpolated ones.
    """

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}
    STATE_FIELDS = _STATE_FIELDS  # get_state's keys

    def __init__(self, name: str, config: AllocConfig | None, num_envs, client, store, render_mode: str | None,
                 estimates: bool | str, kwargs: dict):
        """Make the env's shared part. name: the env class's name, for check_env_arguments'
        message; the other arguments are SwarmAllocationVectorEnv's (its class docstring's Arguments)."""
        B = _num_envs(num_envs)
        self.config = check_env_arguments(name, config, estimates, kwargs)
        if render_mode is not None:
            raise ConfigError(f"render_mode: the batched env renders nothing (None only), got {render_mode!r}",
                              field="render_mode")
        self.render_mode = None
        self.estimates = estimates
        self.num_envs = B
        n = self.config.grid_size
        self.layout = Layout(n)
        check_batch(B, self.layout)
        self.single_observation_space = gym.spaces.Box(0.0, 1.0, shape=(2 * n * n,), dtype=np.float32)
        self.observation_space = batch_space(self.single_observation_space, B)
        self._owns_client = client is None  # close() closes a client the env made, never one it was given
        self.client = env_client(self.config, store) if client is None else client
        self.model = EngagementModel(self.config, self.client, estimates)
        cells = self.layout.cells
        self.D = np.zeros((B, cells))
        self.I = np.zeros((B, cells))
        self.steps = np.zeros(B, dtype=np.int64)
        self.breached = np.zeros(B)
        self.eliminated = np.zeros(B)
        self.started = np.zeros(B, dtype=bool)
        self._rngs: list[np.random.Generator | None] = [None] * B
        self.engagements = 0
        self.estimated = 0
        self._all = np.ones(B, dtype=bool)
        self._indices = np.arange(B)
        self._alpha = np.ones(n)  # the flat Dirichlet of the intruders' start

    # ----- the MDP ------------------------------------------------------------------
    def _seeds(self, seed) -> list:
        """The episodes' seeds of reset(seed=...): a list of B ints or Nones."""
        B = self.num_envs
        if seed is None:
            return [None] * B
        def whole_seed(s) -> bool:
            return is_whole(s) and s >= 0

        if whole_seed(seed):
            return [int(seed) + k for k in range(B)]
        if isinstance(seed, (list, tuple, np.ndarray)) and len(seed) == B \
                and all(s is None or whole_seed(s) for s in seed):
            return [None if s is None else int(s) for s in seed]
        raise ConfigError(f"seed: must be an int >= 0, None or a list of {B} of them, got {seed!r}", field="seed")

    def _reset_mask(self, options) -> np.ndarray:
        """The episodes reset() resets: options["reset_mask"], (B,) bool with one True at least, else all."""
        if not options or "reset_mask" not in options:
            return self._all
        mask = options["reset_mask"]
        if not isinstance(mask, np.ndarray) or mask.dtype != np.bool_ or mask.shape != (self.num_envs,) \
                or not mask.any():
            raise ConfigError(f"reset_mask: must be a ({self.num_envs},) numpy bool array with one True at least, "
                              f"got {mask!r}", field="reset_mask")
        return mask

    def _start(self, episodes: np.ndarray, seeds: list | None = None) -> None:
        """Start the episodes (their indices, (m,) int64) as the single env's reset does, each
        drawing its intruders' start from its own generator (seeds[k]: its new seed or None;
        seeds None: none new)."""
        shares = np.empty((len(episodes), self.layout.n))
        rngs = self._rngs
        for row, k in enumerate(episodes.tolist()):
            if rngs[k] is None or (seeds is not None and seeds[k] is not None):
                rngs[k], _ = seeding.np_random(None if seeds is None else seeds[k])
            shares[row] = rngs[k].dirichlet(self._alpha)
            self._draw(k, rngs[k])
        self.D[episodes], self.I[episodes] = start_densities(self.layout, shares)
        self.steps[episodes] = 0
        self.breached[episodes] = 0.0
        self.eliminated[episodes] = 0.0
        self.started[episodes] = True

    @staticmethod
    def _infos(floats: np.ndarray, ints: np.ndarray, mask: np.ndarray) -> dict:
        """gymnasium's infos from the (7, B) float64 and (2, B) int64 blocks of INFO_KEYS'
        values (rows in _FLOATS' and _INTS' order), each key masked by a copy of mask: (B,) bool."""
        infos = {}
        for row, key in enumerate(_FLOATS):
            infos[key], infos["_" + key] = floats[row], mask.copy()
        for row, key in enumerate(_INTS):
            infos[key], infos["_" + key] = ints[row], mask.copy()
        return infos

    def _reset_info(self, mask: np.ndarray) -> dict:
        """The info of a reset of the episodes in mask ((B,) bool): every per-step entry 0,
        the counters 0, the intruder mass of the new start; masked to them."""
        floats = np.zeros((len(_FLOATS), self.num_envs))
        floats[_MASS] = np.where(mask, row_sums(self.I), 0.0)
        return self._infos(floats, np.zeros((len(_INTS), self.num_envs), dtype=np.int64), mask)

    def reset(self, *, seed=None, options=None):
        """Start the episodes (see SwarmAllocationVectorEnv's docstring); returns (obs: (B, 2 N^2) float32, infos).

        ConfigError (one line) for a seed that is no int >= 0, None or list of B of them, or a bad
        options["reset_mask"]; nothing is changed then.
        """
        seeds = self._seeds(seed)
        mask = self._reset_mask(options)
        episodes = np.flatnonzero(mask)
        self._start(episodes, seeds)
        self._prepare(episodes)
        return self._observations(), self._reset_info(mask)

    def _record(self, r: StepResult):
        """Take a step's outcome, r: a StepResult of the B episodes: the densities, the counters,
        the episodes' ends, the SAME_STEP autoreset of those that ended; then _prepare of every
        episode. Returns step()'s (obs, rewards: (B,) float64 (_reward), terminated, truncated:
        (B,) bool, infos)."""
        self.D, self.I = r.D, r.I
        self.breached = self.breached + r.breach
        self.eliminated = self.eliminated + r.eliminated
        self.engagements += int(r.engaged.sum())
        self.estimated += int(r.estimates.sum())
        self.steps = self.steps + 1
        terminated, truncated = episode_end(self.config, self.steps, r.remaining)
        rewards = self._reward(r)
        values = {"breached_step": r.breach, "breached": self.breached, "eliminated_step": r.eliminated,
                  "eliminated": self.eliminated, "intruder_mass": r.remaining, "coverage": r.coverage,
                  "defenders_per_engaged": r.per_engaged, "engaged_cells": r.engaged, "estimates": r.estimates}
        floats = np.array([values[key] for key in _FLOATS], dtype=np.float64)
        ints = np.array([values[key] for key in _INTS], dtype=np.int64)
        done = terminated | truncated
        if not done.any():
            self._prepare(self._indices)
            return self._observations(), rewards, terminated, truncated, self._infos(floats, ints, self._all)
        ended = np.flatnonzero(done)
        final_obs = np.full(self.num_envs, None, dtype=object)
        for k, last in zip(ended.tolist(), observe(self.D[ended], self.I[ended])):
            final_obs[k] = last.copy()
        final_info = self._infos(np.where(done, floats, 0.0), np.where(done, ints, 0), done)
        self._start(ended)
        self._prepare(self._indices)
        floats[:, ended] = 0.0  # the new episodes' reset info
        floats[_MASS, ended] = row_sums(self.I[ended])
        ints[:, ended] = 0
        infos = self._infos(floats, ints, self._all)
        infos["final_obs"], infos["_final_obs"] = final_obs, done.copy()
        infos["final_info"], infos["_final_info"] = final_info, done.copy()
        return self._observations(), rewards, terminated, truncated, infos

    def _prepare(self, episodes: np.ndarray) -> None:
        """What happens before the agent sees the states of the episodes (their indices, (m,)
        int64: after their start, and after every step): nothing here."""

    def _observations(self) -> np.ndarray:
        """What the agent sees of every episode: (B, 2 N^2) float32 [D, I] (observe)."""
        return observe(self.D, self.I)

    def _reward(self, r: StepResult) -> np.ndarray:
        """The agent's rewards of the step r: (B,) float64, the defenders' (r.reward) here."""
        return r.reward

    # ----- saving and restoring ---------------------------------------------------
    def get_state(self) -> dict:
        """All B episodes' state, for set_state() to continue them later: a picklable dict of
        copies (STATE_FIELDS). num_envs: int; D, I: (B, N^2) float64; steps: (B,) int64; breached,
        eliminated: (B,) float64; started: (B,) bool; rngs: list of B bit_generator.state
        dicts (None for an episode never reset); engagements, estimated: int. The client is
        no part of it (see SwarmAllocationEnv.get_state)."""
        return {"num_envs": self.num_envs, "D": self.D.copy(), "I": self.I.copy(), "steps": self.steps.copy(),
                "breached": self.breached.copy(), "eliminated": self.eliminated.copy(),
                "started": self.started.copy(),
                "rngs": [None if g is None else g.bit_generator.state for g in self._rngs],
                "engagements": self.engagements, "estimated": self.estimated, **self._draw_state()}

    def _draw(self, k: int, rng) -> None:
        """Episode k's draw of the frozen side when it draws its play per episode (a mixture), from
        its generator rng right after its start: nothing here."""

    def _draw_state(self) -> dict:
        """The episodes' draws, for get_state ({} without any)."""
        return {}

    def _resume_draw(self, state: dict) -> None:
        """Take the episodes' draws from a state get_state() returned: nothing here."""

    def set_state(self, state: dict) -> None:
        """Take a state get_state() returned (of an env of the same grid and num_envs): every
        episode goes on from there, each generator draws what the saved one would have.
        ConfigError (one line) for a state of another batch size, or one the single env's rule
        refuses (farm.alloc.envs.defenders.check_state: another grid, a field missing, densities that are
        not finite numbers >= 0, a damaged generator state); the env is unchanged then."""
        if isinstance(state, dict) and "num_envs" in state and state["num_envs"] != self.num_envs:
            raise ConfigError(f"set_state: the state is of {state['num_envs']!r} episodes, this env has "
                              f"{self.num_envs}", field="set_state")
        check_state(state, self.STATE_FIELDS, (self.num_envs, self.layout.cells), "rngs")
        resume_draws(self, state)  # first: a damaged draw leaves the env as it was
        rngs = []
        for saved in state["rngs"]:
            if saved is None:
                rngs.append(None)
                continue
            rng, _ = seeding.np_random(0)
            rng.bit_generator.state = saved
            rngs.append(rng)
        self.D = np.array(state["D"], dtype=np.float64)
        self.I = np.array(state["I"], dtype=np.float64)
        self.steps = np.array(state["steps"], dtype=np.int64)
        self.breached = np.array(state["breached"], dtype=np.float64)
        self.eliminated = np.array(state["eliminated"], dtype=np.float64)
        self.started = np.array(state["started"], dtype=bool)
        self._rngs = rngs
        self.engagements = int(state["engagements"])
        self.estimated = int(state["estimated"])

    def render(self):
        """Nothing: the batched env has no render mode (render_mode None)."""
        return None

    def close_extras(self, **kwargs) -> None:
        """Close the client when the env made it (with its in-process store); a client given to
        the env stays open for its owner. VectorEnv.close() calls this once."""
        if self._owns_client:
            self._owns_client = False
            self.client.close()


class SwarmAllocationVectorEnv(GridVectorEnv):
    """B = num_envs episodes of the grid allocation MDP, stepped together (gymnasium VectorEnv).

    Each episode is SwarmAllocationEnv's MDP (farm.alloc.envs.defenders, its docstring); this class
    batches it. Spaces: single_observation_space Box(0, 1, (2 N^2,), float32) and
    single_action_space Box(-1, 1, (A,), float32) as the single env's; observation_space
    (B, 2 N^2) float32 and action_space (B, A) float32 their batches.

    reset(seed=None, options=None): seed an int s (episode k seeded s + k, gymnasium's
    convention), a list of B ints or None, or None (each episode keeps its generator; one
    never seeded gets OS entropy, as the single env's np_random); episode k's generator is
    gymnasium.utils.seeding.np_random of its seed, the single env's. options may hold
    "reset_mask": (B,) bool, the episodes to reset (the others go on); no other option is
    read. Returns (obs: (B, 2 N^2) float32, infos).

    step(actions): actions (B, A) finite numbers (ActionError otherwise, before anything
    changes; ResetNeeded before every episode has been reset). Returns (obs: (B, 2 N^2)
    float32, rewards: (B,) float64, terminated: (B,) bool, truncated: (B,) bool, infos).
    Autoreset: SAME_STEP (metadata["autoreset_mode"]), as gymnasium's SyncVectorEnv does it:
    an episode that ends is reset in the same step with its own generator; obs[k] is then the
    new episode's first observation and infos[key][k] its reset's values, and the ended
    episode's last observation and info are in infos["final_obs"]: (B,) object (None for the
    others) and infos["final_info"] (a dict of arrays like infos), masked by
    infos["_final_obs"] and infos["_final_info"]: (B,) bool; the two keys are present only
    in a step where some episode ended.

    infos: gymnasium's dict of arrays, every INFO_KEYS entry of the single env's info as a
    (B,) array (float64 or int64), with its mask `_key`: (B,) bool, all True (every episode
    reports every key; after a reset with a reset_mask only the reset episodes are in it).

    Arguments: those of SwarmAllocationEnv (config or AllocConfig keyword arguments, client,
    store, estimates) and num_envs: int >= 1, episodes that fit in half of this machine's memory
    (check_batch; else a one-line ConfigError naming `num_envs`);
    render_mode: None only (no rendering). A client is shared by the B episodes; close()
    closes it only when the env made it.

    get_state() and set_state() save and restore all B episodes (densities, counters, started
    flags, every generator's bit_generator.state) and the lifetime counters, for the exact
    resume of a training.

    Attributes: config: AllocConfig; client; model: EngagementModel; layout:
    farm.alloc.game.dynamics.Layout; num_envs: int, B; D, I: (B, N^2) float64 the densities;
    steps: (B,) int64; breached, eliminated: (B,) float64 the episodes' counters; started:
    (B,) bool, the episodes reset at least once; engagements, estimated: int, the engaged
    cells answered over the env's lifetime and of them the interpolated ones.
    """

    def __init__(self, config: AllocConfig | None = None, num_envs: int = 1, *, client=None,
                 store: str | None = None, render_mode: str | None = None, estimates: bool | str = False, **kwargs):
        """Make the env; the class docstring's Arguments describe each argument."""
        super().__init__("SwarmAllocationVectorEnv", config, num_envs, client, store, render_mode, estimates, kwargs)
        self.single_action_space = gym.spaces.Box(-1.0, 1.0, shape=(len(self.layout.src),), dtype=np.float32)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.intruders = configured_intruders(self.config, self.client)  # None: the drift law
        self._episode_intruders = [self.intruders] * self.num_envs  # each episode's draw of intruders that draw

    def step(self, actions):
        """One step of every episode, with SAME_STEP autoreset (see the class docstring).

        actions: (B, A) finite numbers, clipped to [-1, 1]. Returns (obs, rewards,
        terminated, truncated, infos). ResetNeeded before every episode has been reset;
        ActionError (farm.alloc.game.dynamics.check_actions) for actions of another shape, not
        numbers or not finite, leaving the env as it was.
        """
        if not self.started.all():
            raise ResetNeeded("Cannot call env.step() before calling env.reset()")
        a = check_actions(actions, self.action_space.shape, "actions")
        side = None if self.intruders is None else EpisodeIntruders(self._episode_intruders)
        intruders = intruder_move(side, self.config.information, self.D, self.I)
        return self._record(step(self.layout, self.config, self.model, self.D, self.I, a, intruders))

    def _draw(self, k: int, rng) -> None:
        """Episode k's intruders: a policy that draws per episode draws from its generator."""
        self._episode_intruders[k] = for_episode(self.intruders, rng)

    def _draw_state(self) -> dict:
        """{"intruder_draws": each episode's draw (None: none)} for intruders that draw per episode, else {}."""
        saved = [draw_state(p) for p in self._episode_intruders]
        return {} if all(d is None for d in saved) else {"intruder_draws": saved}

    def _resume_draw(self, state: dict) -> None:
        """The episodes' intruders from their saved draws."""
        if "intruder_draws" in state:
            self._episode_intruders = [self.intruders if d is None else self.intruders.resume_episode(d)
                                       for d in state["intruder_draws"]]
