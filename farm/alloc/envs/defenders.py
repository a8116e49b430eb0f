"""The N x N grid allocation MDP (paper section 3, docs/model.md section 5) as a gymnasium env.

SwarmAllocationEnv is the env (registered as `farm/SwarmAllocation-v0`); its docstring
describes the MDP: action and observation spaces, one step, the reward, the start and
the end of an episode, and its arguments. moves and n_actions give the action layout
of an N x N grid. A step is farm.alloc.game.dynamics.step, for one episode here and for B at
once in farm.alloc.envs.vector (so both give an episode the same numbers); its intruder
advance and engagements (and the lattice of team sizes, `team_sizes: lattice`) are
farm.alloc.game.model's functions, which the planners use to look ahead. check_env_arguments
and env_client are the constructor's rules, which the batched env shares.
See farm.alloc.game.config for the settings and the two engagement models.
"""

from __future__ import annotations

import logging

import gymnasium as gym
import numpy as np
from gymnasium.error import ResetNeeded
from pydantic import ValidationError

from farm.alloc.game.config import AllocConfig
from farm.alloc.game.dynamics import (
    Layout,
    StepResult,
    check_actions,
    episode_end,
    move_probabilities,
    moves,
    n_actions,
    observe,
    start_densities,
    step,
)
from farm.alloc.game.model import EngagementModel, row_sums
from farm.alloc.intruders.play import (
    configured_intruders,
    draw_state,
    for_episode,
    intruder_move,
)
from farm.core.config import error_field, first_line
from farm.core.errors import ConfigError

__all__ = ["GridEnv", "SwarmAllocationEnv", "moves", "n_actions", "check_env_arguments", "env_client", "tally_step",
           "check_state", "resume_draws", "STATE_FIELDS"]

log = logging.getLogger(__name__)

STATE_FIELDS = ("D", "I", "steps", "breached", "eliminated", "started", "rng", "engagements", "estimated")


def check_env_arguments(name: str, config: AllocConfig | None, estimates, kwargs: dict) -> AllocConfig:
    """The env's config from its constructor's arguments, or a one-line ConfigError.

    name: the env class's name, for the message; config: an AllocConfig or None; kwargs:
    AllocConfig keyword arguments, the settings when config is None (both given: refused);
    estimates: False, True or "lattice" (anything else refused, naming `estimates`). Bad
    keyword settings are a ConfigError naming the field, as gym.make's users get it.
    """
    if config is not None and kwargs:
        raise ConfigError(f"{name}: give a config or AllocConfig keyword arguments, not both "
                          f"(got a config and {', '.join(sorted(kwargs))})")
    if estimates not in (False, True, "lattice") or estimates.__class__ not in (bool, str):
        raise ConfigError(f"estimates: must be false, true or 'lattice', got {estimates!r}", field="estimates")
    if config is not None:
        return config
    try:
        return AllocConfig(**kwargs)
    except ValidationError as e:  # gym.make(id, **settings) lands here: one line, not pydantic's dump
        raise ConfigError(first_line(e), field=error_field(e)) from None


def check_state(state, fields: tuple[str, ...], shape: tuple[int, ...], generators: str) -> None:
    """ConfigError (one line naming set_state) unless state is a state the env's get_state()
    could have returned, so that set_state takes all of it or none: the one rule of the single
    env (shape (N^2,)) and the batched one (shape (B, N^2)).

    state: a dict holding every name of fields; D, I: densities of `shape`, finite numbers >=
    0; steps: whole numbers >= 0 and breached, eliminated: finite numbers, of shape[:-1] (one
    each per episode); started: bools of that shape; engagements, estimated: whole numbers >= 0;
    state[generators]: a generator's bit_generator.state (the single env's `rng`), or a list of
    one per episode, None for an episode never reset (the batched env's `rngs`), each one a
    PCG64 takes."""
    from gymnasium.utils import seeding

    from farm.core.checks import is_whole

    if not isinstance(state, dict):
        raise ConfigError(f"set_state: expected the dict get_state() returns, got {type(state).__name__}",
                          field="set_state")
    missing = [name for name in fields if name not in state]
    if missing:
        raise ConfigError(f"set_state: the state has no {missing[0]!r}", field="set_state")
    if np.shape(state["D"]) != shape or np.shape(state["I"]) != shape:
        raise ConfigError(f"set_state: the state's densities are of shape {np.shape(state['D'])}, this env's are "
                          f"of shape {shape}", field="set_state")
    for side in ("D", "I"):
        values = np.asarray(state[side])
        if values.dtype.kind not in "iuf" or not np.all(np.isfinite(values)) or np.any(values < 0):
            raise ConfigError(f"set_state: the state's densities {side} must be finite numbers >= 0",
                              field="set_state")
    episodes = shape[:-1]
    for name, kinds, what in (("steps", "iu", "whole numbers >= 0"), ("breached", "iuf", "finite numbers"),
                              ("eliminated", "iuf", "finite numbers"), ("started", "b", "true or false")):
        values = np.asarray(state[name])
        if values.shape != episodes or values.dtype.kind not in kinds or (
                kinds != "b" and not np.all(np.isfinite(values))) or (name == "steps" and np.any(values < 0)):
            raise ConfigError(f"set_state: the state's {name} must be {what}, one per episode", field="set_state")
    for name in ("engagements", "estimated"):
        if not is_whole(state[name], numpy=True) or state[name] < 0:
            raise ConfigError(f"set_state: the state's {name} must be a whole number >= 0, got {state[name]!r}",
                              field="set_state")
    saved = state[generators] if episodes else [state[generators]]
    if not isinstance(saved, (list, tuple)) or len(saved) != (episodes[0] if episodes else 1):
        raise ConfigError(f"set_state: the state's {generators} must hold one generator state per episode",
                          field="set_state")
    for g in saved:
        if g is None and episodes:
            continue
        try:
            seeding.np_random(0)[0].bit_generator.state = g
        except (TypeError, ValueError, KeyError, OverflowError) as e:
            raise ConfigError(f"set_state: the state's {generators} is not a generator's state ({type(e).__name__})",
                              field="set_state") from None


def resume_draws(env, state: dict) -> None:
    """env._resume_draw(state) (the frozen side's draws of the episodes, a mixture's), its
    damage (a member that is not one, a generator state that is not one) a ConfigError naming
    set_state; the hooks assign last, so a damaged draw leaves env as it was."""
    try:
        env._resume_draw(state)
    except (TypeError, ValueError, KeyError, IndexError, AttributeError) as e:
        raise ConfigError(f"set_state: the state's draw of the frozen side is damaged ({type(e).__name__})",
                          field="set_state") from None


def env_client(config: AllocConfig, store):
    """The in-process capture-time client (no Ray) an env makes when given none, over store
    (str, Path or None: farm.service.store.default_store_path(), logged at INFO)."""
    from farm.service import CaptureTimeClient
    from farm.service.store import default_store_path

    if store is None:
        store = default_store_path()
        log.info("capture-time store: %s", store)
    return CaptureTimeClient(config.game_settings(), local_store=store)


def tally_step(env, r: StepResult) -> tuple[float, float, int, int]:
    """Move a one-episode env to a step's outcome r (a StepResult, B = 1): its D, I and counters
    (breached, eliminated, engagements, estimated, steps). Returns the step's breach, eliminated
    mass, engaged cells and estimates."""
    env.D, env.I = r.D[0], r.I[0]
    breach, eliminated = float(r.breach[0]), float(r.eliminated[0])
    engaged, estimates = int(r.engaged[0]), int(r.estimates[0])
    env.breached += breach
    env.eliminated += eliminated
    env.engagements += engaged
    env.estimated += estimates
    env.steps += 1
    return breach, eliminated, engaged, estimates


class GridEnv(gym.Env):
    """One episode of the grid MDP as a gymnasium env, whichever side acts in it: the part the
    defenders' env (SwarmAllocationEnv, whose docstring describes each piece) and the intruders'
    env (farm.alloc.envs.intruders.SwarmIntruderEnv) share: the arguments, the observation space,
    the start, a step's accounting and info (_record of the step's StepResult), get_state and
    set_state, render and close. A subclass sets action_space and step(); its hooks are
    _prepare (before the agent sees a state), _obs (what it sees) and _reward (what it gets).

    Attributes: config: AllocConfig; client: CaptureTimeClient; model: EngagementModel; n:
    int, the grid side N; layout: farm.alloc.game.dynamics.Layout; base: int, the base cell's index;
    D, I: (N^2,) float64 the densities; steps: int and breached, eliminated: float, the
    episode's counters; engagements, estimated: int, the engaged cells answered by the service
    over the env's lifetime and of them the interpolated ones.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 2}

    def __init__(self, name: str, config: AllocConfig | None, client, store, render_mode: str | None,
                 estimates: bool | str, kwargs: dict):
        """Make the env's shared part. name: the env class's name, for check_env_arguments' message;
        the other arguments are SwarmAllocationEnv's (its class docstring's Arguments)."""
        self.config = check_env_arguments(name, config, estimates, kwargs)
        self.estimates = estimates
        self.engagements = 0  # engaged cells answered by the service, over the env's lifetime
        self.estimated = 0  # of which by an interpolation (estimates=True)
        n = self.config.grid_size
        self.n = n
        self.layout = Layout(n)
        self.observation_space = gym.spaces.Box(0.0, 1.0, shape=(2 * n * n,), dtype=np.float32)
        self.render_mode = render_mode
        self._owns_client = client is None  # close() closes a client the env made, never one it was given
        self.client = env_client(self.config, store) if client is None else client
        self.model = EngagementModel(self.config, self.client, estimates)
        self.base = self.layout.base
        self.D = np.zeros(n * n)
        self.I = np.zeros(n * n)
        self.steps = 0
        self.breached = 0.0
        self.eliminated = 0.0
        self._reset_done = False  # step() needs a reset() first

    def reset(self, *, seed=None, options=None):
        """Start an episode (see SwarmAllocationEnv's Starting State); returns (observation, info).

        seed: seeds the env's generator (the intruders' start); options: unused.
        observation: (2 N^2,) float32 (_obs); info: the step measures, all 0.
        """
        super().reset(seed=seed)
        D, I = start_densities(self.layout, self.np_random.dirichlet(np.ones(self.n))[None])
        self._draw()
        self.D, self.I = D[0], I[0]
        self.steps = 0
        self.breached = 0.0
        self.eliminated = 0.0
        self._reset_done = True
        self._prepare()
        return self._obs(), self._info(0.0, 0.0, 0, 0, float(row_sums(I)[0]))

    def _record(self, r: StepResult):
        """Take a step's outcome, r: a StepResult of one episode (B = 1): the densities, the
        counters, the episode's end; then _prepare unless it ended. Returns step()'s (obs,
        reward: float (_reward), terminated, truncated: bool, info)."""
        breach, eliminated, engaged, estimates = tally_step(self, r)
        terminated, truncated = episode_end(self.config, np.array([self.steps]), r.remaining)
        terminated, truncated = bool(terminated[0]), bool(truncated[0])
        if not (terminated or truncated):
            self._prepare()
        info = self._info(breach, eliminated, engaged, estimates, float(r.remaining[0]), float(r.coverage[0]),
                          float(r.per_engaged[0]))
        return self._obs(), float(self._reward(r)[0]), terminated, truncated, info

    def _prepare(self) -> None:
        """What happens before the agent sees a state (after a start, and after a step that did
        not end the episode): nothing here."""

    def _draw(self) -> None:
        """The draw of the frozen side when it draws its play per episode (a mixture), from the
        env's generator right after the start: nothing here."""

    def _draw_state(self) -> dict:
        """The episode's draw, for get_state ({} without one)."""
        return {}

    def _resume_draw(self, state: dict) -> None:
        """Take the episode's draw from a state get_state() returned: nothing here."""

    def _reward(self, r: StepResult) -> np.ndarray:
        """The agent's reward of the step r: (B,) float64, the defenders' (r.reward) here."""
        return r.reward

    def get_state(self) -> dict:
        """The env's state, for set_state() to continue it later (a resumed training): a
        picklable dict of copies. D, I: (N^2,) float64 the densities; steps: int; breached,
        eliminated: float; started: bool, a reset() done; rng: dict, the generator's
        bit_generator.state; engagements, estimated: int, the lifetime counters. The client is no
        part of it: its answers do not depend on what it answered before (under `estimates:
        true` they depend on timing anyway)."""
        return {"D": self.D.copy(), "I": self.I.copy(), "steps": self.steps, "breached": self.breached,
                "eliminated": self.eliminated, "started": self._reset_done,
                "rng": self.np_random.bit_generator.state, "engagements": self.engagements,
                "estimated": self.estimated, **self._draw_state()}

    def set_state(self, state: dict) -> None:
        """Take a state get_state() returned (of an env of the same grid): the episode goes on
        from there, the generator draws what the saved one would have, the counters go on.
        ConfigError (one line) for a state check_state refuses: of another grid size, with a
        field missing, with densities that are not finite numbers >= 0, counters that are not
        numbers, or a damaged generator state; the env is unchanged then."""
        check_state(state, STATE_FIELDS, (self.n * self.n,), "rng")
        resume_draws(self, state)  # first: a damaged draw leaves the env as it was
        self.D = np.array(state["D"], dtype=np.float64)
        self.I = np.array(state["I"], dtype=np.float64)
        self.steps = int(state["steps"])
        self.breached = float(state["breached"])
        self.eliminated = float(state["eliminated"])
        self._reset_done = bool(state["started"])
        self.np_random.bit_generator.state = state["rng"]
        self.engagements = int(state["engagements"])
        self.estimated = int(state["estimated"])

    def _obs(self) -> np.ndarray:
        """The observation: (2 N^2,) float32 [D, I] clipped to [0, 1]."""
        return observe(self.D[None], self.I[None])[0]

    def _info(self, breach, eliminated, engaged, estimates, mass, coverage=0.0, per_cell=0.0) -> dict:
        """The info dict of reset() and step() (see SwarmAllocationEnv's Info).

        mass: the intruder mass sum(I); coverage: the share of the intruder mass (after its
        advance) in cells with defenders (n_p >= 1), which are the engaged cells;
        defenders_per_engaged: mean n_p over them.
        """
        return {"breached_step": breach, "breached": self.breached, "eliminated_step": eliminated,
                "eliminated": self.eliminated, "engaged_cells": engaged,
                "estimates": estimates, "intruder_mass": mass, "coverage": coverage,
                "defenders_per_engaged": per_cell}

    def render(self):
        """The densities as an image: (32 N, 32 N, 3) uint8 under render_mode "rgb_array", else None.

        Defenders blue, intruders red (farm.alloc.game.plots.density_frame).
        """
        if self.render_mode != "rgb_array":
            return None
        from farm.alloc.game.plots import density_frame

        return density_frame(self.D.reshape(self.n, self.n), self.I.reshape(self.n, self.n), self.steps)

    def close(self):
        """Release the env's resources: the client's store if the env made the client.

        A client made by the env (none given) is closed, with its in-process service's
        SQLite store; a client given to the env belongs to its owner and stays open.
        Closing twice is allowed and does nothing more.
        """
        if self._owns_client:
            self._owns_client = False
            self.client.close()
        super().close()


class SwarmAllocationEnv(GridEnv):
    """The grid allocation MDP: place a defender swarm over an N x N grid against intruders.

    ## Description

    The paper's section 3 (docs/model.md section 5). An N x N grid (`grid_size`) of
    cells c = row * N + col, each cell one pursuit-evasion arena. The defenders' density
    D (sums to 1) and the intruders' density I (sums to the surviving fraction) live on
    the cells. The intruders enter at the right-most column and advance one column left
    per step; the allocator moves the defenders' mass between neighbouring cells. Every
    cell holding both sides is engaged: its game, n_p = round(D_c n_defenders) >= 1
    defenders against n_e = max(1, round(I_c n_intruders)) intruders, is answered by the
    capture-time service (a CaptureTimeClient), and the service's expected fraction of
    intruders captured within the window tau removes that share of the cell's intruders.

    Under engagement v2 (the default) a step lasts `step_seconds` of game time, the time
    an intruder needs to cross a cell, and the window is that step (tau = step_seconds).
    A step, in this order:

    1. the defenders move: D' = T D (T from the action, below);
    2. the intruders drift vertically (`vertical_drift` d: each row sends a share d of
       its mass to each neighbouring row), then advance one column left; the mass that
       leaves the left edge has breached;
    3. every cell with n_p >= 1 and I_c > `engage_min_mass` is engaged (`team_sizes:
       lattice` snaps n_p and n_e with farm.alloc.game.model.snap_many). Under v2 the games are by default pure
       pursuit against intruders heading for the exit, through which they escape; escaped
       intruders stay in the cell's mass and go on with the next advance, never
       counted as eliminated. Defenders are never lost.

    See farm.alloc.game.config for the settings and the two engagement models (v1, v2).

    ## Action Space

    A `Box(-1, 1, (A,), float32)`, A = n_actions(N) (49 for N = 3): one number per
    feasible move (stay or one of the 8 neighbours inside the grid), cell by cell in cell
    order, moves in row-major (d_row, d_col) order (moves(N) gives src, dst and start).
    Values are clipped to [-1, 1]. step() refuses (farm.core.errors.ActionError, a
    workers.InputError and ValueError) an action of another shape, of no real numbers
    (booleans, complex numbers, text or objects) or with NaN or an infinity, before it
    changes anything. Each cell's slice maps to a probability row
    (`action_map`):

    - `softmax` (default): p = softmax(beta a), beta = `softmax_beta` (5);
    - `shifted`: p = (a + 1) / sum(a + 1), uniform when every entry is -1.

    This gives a column-stochastic T: (N^2, N^2) float64, column j where cell j's
    defenders go, infeasible moves exactly 0 (transition_matrix).

    ## Observation Space

    A `Box(0, 1, (2 N^2,), float32)`: [D, I] clipped to [0, 1], D at index c and I at
    N^2 + c for cell c = row * N + col.

    | Index          | Observation                        | Min | Max |
    |----------------|------------------------------------|-----|-----|
    | 0 .. N^2-1     | defenders' density D_c             | 0   | 1   |
    | N^2 .. 2N^2-1  | intruders' density I_c             | 0   | 1   |

    ## Rewards

        R = -c_distribution * sum(I) + c_capture * S - breach_penalty * B

    sum(I) is the intruder mass left after the step's engagements; B the mass breached
    this step; the capture score S = sum over engaged cells of I_c s_c, I_c the cell's
    mass before its engagement and s_c its game's score per unit of mass. Under
    `capture_score: expected` (v2's default) s_c is an expectation over all the cell's
    games: the mean over games of each game's mean over its intruders of max(0, 1 -
    t/tau), an intruder not caught within tau scoring 0 (CaptureStats.capture_score_tau).
    Under `conditional` (engagement v1's) s_c = max(0, 1 - t_c /
    capture_time_norm), t_c the mean capture time of the games that caught someone (t_max
    when none did); capture_time_norm is 10 s under v1. Defaults: c_distribution 1,
    c_capture 0, breach_penalty 1.

    ## Starting State

    All defenders at the base, the left-centre cell (row N//2, col 0). The intruders
    over the right-most column (col N-1), their row shares drawn from a flat Dirichlet
    (total 1) with the env's generator, seeded by reset(seed=...). The episode's
    counters (steps, breached, eliminated) start at 0.

    ## Episode End

    1. Termination: the intruder mass sum(I) falls below `epsilon` (1e-3).
    2. Truncation: `max_steps` (12) steps taken without termination.

    step() before the first reset() raises gymnasium.error.ResetNeeded.

    ## Info

    reset() and step() return a dict of floats and ints: breached_step and
    eliminated_step (intruder mass breached and eliminated this step), breached and
    eliminated (over the episode), engaged_cells and estimates (engaged cells this step,
    and of them the ones answered by an interpolation, see `estimates` below),
    intruder_mass (sum(I)), coverage (the share of the intruder mass, after its advance,
    in engaged cells) and defenders_per_engaged (the mean n_p over engaged cells, 0.0
    with none). reset() reports 0 for every per-step entry.

    ## Arguments

    ```python
    >>> import gymnasium, farm.alloc
    >>> env = gymnasium.make("farm/SwarmAllocation-v0", grid_size=3, n_defenders=100, n_intruders=50)
    >>> obs, info = env.reset(seed=0)
    >>> obs.shape, obs.dtype, env.action_space.shape
    ((18,), dtype('float32'), (49,))

    ```

    - `config`: AllocConfig or None (default): the MDP's and the engagement games'
      settings; None makes them from `**kwargs`.
    - `client`: a CaptureTimeClient or None (default), which answers the engagements.
      None: the env makes an in-process client (no Ray) over `store` and owns it.
    - `store`: str, Path or None (default): the SQLite store of the env's own client;
      None: farm.service.store.default_store_path(), logged at INFO. Unused with a client.
    - `render_mode`: None (default) or "rgb_array": render() returns a (32 N, 32 N, 3)
      uint8 image of the densities.
    - `estimates`: False (default), True or "lattice". True: answer a first visit of a
      team-size pair with the service's interpolation of its computed neighbours while the
      exact value is computed in the background (counted in info["estimates"]; which
      visits are interpolated depends on timing); "lattice": answer every pair off the
      lattice by the interpolation of its lattice anchors, computed exactly, for the
      client's life (timing-independent, so reproducible); False: wait for the exact value.
    - `**kwargs`: AllocConfig fields (e.g. grid_size: int, n_defenders: int,
      c_capture: float), the settings when config is None; given with a config they
      are a farm.core.errors.ConfigError.

    close() closes the client (and its store) when the env made it, and leaves a client
    it was given open for its owner. get_state() and set_state() save and restore the
    episode in progress, the generator and the counters (a resumed training goes on with
    the same episode and draws).

    Attributes: config: AllocConfig; client: CaptureTimeClient; n: int, the grid side N;
    layout: farm.alloc.game.dynamics.Layout of the grid;
    src, dst: (A,) int64 and start: (N^2,) int64 as moves(N) returns them; n_moves:
    (N^2,) int64 the number of moves of each cell; base: int, the base cell's index;
    D, I: (N^2,) float64 the densities; steps: int and breached, eliminated: float, the
    episode's counters; engagements, estimated: int, the engaged cells answered by the
    service over the env's lifetime and of them the interpolated ones.
    """

    def __init__(self, config: AllocConfig | None = None, *, client=None, store: str | None = None,
                 render_mode: str | None = None, estimates: bool | str = False, **kwargs):
        """Make the env; the class docstring's Arguments section describes each argument."""
        super().__init__("SwarmAllocationEnv", config, client, store, render_mode, estimates, kwargs)
        self.src, self.dst, self.start = self.layout.src, self.layout.dst, self.layout.start
        self.n_moves = self.layout.n_moves
        self.action_space = gym.spaces.Box(-1.0, 1.0, shape=(len(self.src),), dtype=np.float32)
        self.intruders = configured_intruders(self.config, self.client)  # None: the drift law
        self._episode_intruders = self.intruders  # the episode's draw of intruders that draw per episode

    # ----- the MDP ------------------------------------------------------------------
    def check_action(self, action) -> np.ndarray:
        """The action as (A,) float64, values as given (step() clips them), or ActionError.

        Refused: anything that is not an array of real numbers (integers or floats) of the
        action space's shape (A,), and NaN or infinite values (farm.alloc.game.dynamics.check_actions).
        """
        return check_actions(action, self.action_space.shape)

    def move_probabilities(self, action: np.ndarray) -> np.ndarray:
        """Map an action to the probabilities of the feasible moves (the `action_map`).

        action: (A,) float, clipped to [-1, 1] -> p: (A,) float64 in the same order, each
        cell's slice summing to 1 (farm.alloc.game.dynamics.move_probabilities for one episode).
        """
        return move_probabilities(self.layout, self.config, np.asarray(action, dtype=np.float64)[None])[0]

    def transition_matrix(self, action: np.ndarray) -> np.ndarray:
        """The column-stochastic transition matrix of an action (for tests and plots).

        action: (A,) float -> T: (N^2, N^2) float64, column j where cell j's defenders go
        (infeasible moves exactly 0); step() applies the same map as D' = T D without
        making T.
        """
        T = np.zeros((self.n * self.n, self.n * self.n))
        T[self.dst, self.src] = self.move_probabilities(action)
        return T

    def step(self, action):
        """One step of the MDP (see Description); returns (obs, reward, terminated, truncated, info).

        action: (A,) finite numbers, clipped to [-1, 1]; obs: (2 N^2,) float32 [D, I];
        reward: float; terminated, truncated: bool (see Episode End); info: see Info.
        Raises gymnasium.error.ResetNeeded before the first reset(), and
        farm.core.errors.ActionError for an action of another shape, not of real numbers, or
        not finite (check_action), leaving the env as it was.
        """
        if not self._reset_done:
            raise ResetNeeded("Cannot call env.step() before calling env.reset()")
        D, I = self.D[None], self.I[None]
        intruders = intruder_move(self._episode_intruders, self.config.information, D, I)
        return self._record(step(self.layout, self.config, self.model, D, I, self.check_action(action)[None],
                                 intruders))

    def _draw(self) -> None:
        """The episode's intruders: a policy that draws per episode draws from the env's generator."""
        self._episode_intruders = for_episode(self.intruders, self.np_random)

    def _draw_state(self) -> dict:
        """{"intruder_draw": the episode's draw} for intruders that draw per episode, else {}."""
        saved = draw_state(self._episode_intruders)
        return {} if saved is None else {"intruder_draw": saved}

    def _resume_draw(self, state: dict) -> None:
        """The episode's intruders from a saved draw."""
        if "intruder_draw" in state:
            self._episode_intruders = self.intruders.resume_episode(state["intruder_draw"])
