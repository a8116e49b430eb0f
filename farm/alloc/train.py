"""`farm train CONFIG`: TD3 (stable-baselines3, actor and critics 400-300) on the
allocation env, rewards from the capture-time service.

Config (RL-Zoo-style hyperparameters under `td3`):

    name: paper-3x3-c1-0
    seed: 0
    scenario: null          # a name of farm.alloc.scenarios.SCENARIOS: its env settings are the
                            # base, and `env:` overrides them one by one
    env: {grid_size: 3, n_defenders: 100, n_intruders: 50, c_distribution: 1.0, c_capture: 0.0}
    td3: {n_timesteps: 30000, learning_rate: 0.001, buffer_size: 200000, learning_starts: 1000,
          batch_size: 256, tau: 0.005, gamma: 0.95, train_freq: 1, gradient_steps: 1,
          noise_type: normal, noise_std: 0.2, policy_kwargs: {net_arch: [400, 300]}}
    eval: {freq: 2000, episodes: 10}
    checkpoint_freq: 5000
    log_interval: 100       # episodes between TensorBoard rollout records
    threads: 1              # torch threads for the networks during training; null: torch's own choice
    service: {mode: ray, store: results/capture_times.sqlite, address: null, warm_lattice: true, estimates: false}
                            # estimates: false, true or lattice (ServiceParams)

A run folder holds model.zip, config.yaml, metrics.json, evaluations.npz (the
training curve), checkpoints/ (for --resume), best/ and tb/ (TensorBoard). The
algorithm is stable-baselines3's TD3 as it ships, on SB3's DummyVecEnv; metrics.json
records the wall time of the gradient updates, timed by a callback (UpdateTimer), and
the share of the run spent outside them.

Checkpoints and --resume. Each time the steps pass a multiple of `checkpoint_freq`, after
that step's gradient update (Checkpointer), checkpoints/ gets rl_model_<n>_steps.zip (SB3's
model: weights, optimisers, step count, last observation), rl_model_replay_buffer_<n>_steps.pkl
and, last and atomically, rl_model_state_<n>_steps.pkl (RunState: the random generators, the
training env's episode in progress, the eval env's generator and the evaluations so far, the
timings so far); a checkpoint counts once its state file is there (latest_checkpoint).
`--resume` goes on from the last one, and the run ends as an uninterrupted one does: the same
weights, replay buffer, evaluations.npz, best/ and metrics.json but the timings (on the CPU,
with the same threads; tests/test_train_resume.py). Only the length of training
(td3.n_timesteps) and the threads may differ from the saved config: a run trained shorter and
resumed to a longer length equals one trained to that length at once. metrics.json's
resumed_from names the checkpoint's steps; its figures describe the whole run (the timings
count the earlier parts up to their last checkpoint, not the time lost after it). A --resume
finding no whole checkpoint (none yet, or only ones written before the state file existed)
trains from step 0.

A run that diverges (a loss, a parameter or an action not finite) stops with
farm.errors.TrainingDiverged naming the step (a callback, DivergenceGuard): no
model.zip or metrics.json is written for it.
"""

from __future__ import annotations

import json
import math
import pickle
import re
import time
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml
from pydantic import Field, field_validator, model_validator
from stable_baselines3 import TD3
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, EvalCallback
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.noise import NormalActionNoise
from stable_baselines3.common.vec_env import DummyVecEnv

from workers.errors import is_number

from farm.alloc.config import AllocConfig
from farm.alloc.env import SwarmAllocationEnv
from farm.alloc.scenarios import SCENARIOS
from farm.config import ConfigError, Strict, load_yaml_model
from farm.errors import ActionError, TrainingDiverged


DIVERGED = "DIVERGED"  # written into a run folder whose training diverged: not a result
EVAL_SEED_OFFSET = 1_000_000  # the periodic evaluation's episodes: seeded apart from training's
# What policy_kwargs may set from a config (SB3's TD3Policy arguments that are plain values).
POLICY_KWARGS = ("net_arch", "n_critics", "share_features_extractor", "normalize_images", "optimizer_kwargs")


def _whole(x) -> bool:
    return is_number(x) and isinstance(x, int)


def _number(x) -> bool:
    return is_number(x) and math.isfinite(x)


class TD3Params(Strict):
    """stable-baselines3 TD3's hyperparameters, RL-Zoo style."""

    n_timesteps: int = Field(30_000, ge=1)
    policy: Literal["MlpPolicy"] = "MlpPolicy"
    learning_rate: float = Field(1e-3, gt=0)
    buffer_size: int = Field(200_000, ge=1)
    learning_starts: int = Field(1000, ge=0)
    batch_size: int = Field(256, ge=1)
    tau: float = Field(0.005, gt=0, le=1)
    gamma: float = Field(0.95, ge=0, le=1)
    train_freq: int = Field(1, ge=1)
    gradient_steps: int = Field(1, ge=-1)
    policy_delay: int = Field(2, ge=1)
    noise_type: Literal["normal", "none"] = "normal"
    noise_std: float = Field(0.2, ge=0)
    policy_kwargs: dict[str, Any] = {"net_arch": [400, 300]}

    @field_validator("gradient_steps")
    @classmethod
    def _some_gradient_steps(cls, v):
        if v == 0:
            raise ValueError("must be -1 (as many as the rollout's steps) or >= 1; 0 never updates the model")
        return v

    @field_validator("policy_kwargs")
    @classmethod
    def _policy_kwargs(cls, v):
        unknown = sorted(set(v) - set(POLICY_KWARGS))
        if unknown:
            raise ValueError(f"{unknown[0]}: not a TD3 policy argument a config can set "
                             f"(choose from {', '.join(POLICY_KWARGS)})")
        for name in ("share_features_extractor", "normalize_images"):
            if name in v and not isinstance(v[name], bool):
                raise ValueError(f"{name}: must be true or false, got {v[name]!r}")
        sizes = v.get("net_arch")
        layers = ([] if sizes is None else sizes.values() if isinstance(sizes, dict) and set(sizes) <= {"pi", "qf"}
                  else [sizes])
        for layer in layers:
            if not isinstance(layer, list) or not all(_whole(x) and x >= 1 for x in layer):
                raise ValueError(f"net_arch: must be a list of layer sizes >= 1 (or {{pi: [...], qf: [...]}}), "
                                 f"got {sizes!r}")
        if "n_critics" in v and not (_whole(v["n_critics"]) and v["n_critics"] >= 1):
            raise ValueError(f"n_critics: must be a whole number >= 1, got {v['n_critics']!r}")
        adam = v.get("optimizer_kwargs") or {}
        if not isinstance(adam, dict) or not set(adam) <= {"betas", "eps", "weight_decay", "amsgrad"}:
            raise ValueError(f"optimizer_kwargs: must be a mapping of Adam's betas, eps, weight_decay or amsgrad, "
                             f"got {adam!r}")
        betas = adam.get("betas", (0.9, 0.999))
        if not (isinstance(betas, (list, tuple)) and len(betas) == 2 and all(_number(b) and 0 <= b < 1 for b in betas)):
            raise ValueError(f"optimizer_kwargs.betas: must be two numbers in [0, 1), got {betas!r}")
        for name in ("eps", "weight_decay"):
            if name in adam and not (_number(adam[name]) and adam[name] >= 0):
                raise ValueError(f"optimizer_kwargs.{name}: must be a number >= 0, got {adam[name]!r}")
        if not isinstance(adam.get("amsgrad", False), bool):
            raise ValueError(f"optimizer_kwargs.amsgrad: must be true or false, got {adam['amsgrad']!r}")
        return v


class EvalParams(Strict):
    """The periodic evaluation during training (SB3's EvalCallback)."""

    freq: int = Field(2000, ge=1)
    episodes: int = Field(10, ge=1)


class ServiceParams(Strict):
    """Where training's capture-time statistics come from (farm.service.lookup.open_client)."""

    mode: Literal["ray", "local"] = "ray"
    store: str | None = None  # None: farm.service.store.default_store_path()
    address: str | None = None
    warm_lattice: bool = True
    # During training (its steps and its periodic evaluations), a first visit's outcome comes
    # from an interpolation while the exact value is computed in the background (farm eval
    # afterwards is exact). true: the service's interpolation of what it has computed by then
    # (which visits, and from what, depends on timing); lattice: every pair off the lattice is
    # interpolated from its lattice anchors, computed exactly (reproducible: CaptureTimeClient.
    # lattice_estimates).
    estimates: bool | Literal["lattice"] = False


class TrainConfig(Strict):
    """A `farm train` config (see the module doc)."""

    name: str = Field(min_length=1, max_length=100, pattern=r"^[A-Za-z0-9_.-]+$")
    seed: int = Field(0, ge=0)
    scenario: str | None = None  # SCENARIOS' name: its env settings are the base of `env`
    env: AllocConfig = AllocConfig()
    td3: TD3Params = TD3Params()
    eval: EvalParams = EvalParams()
    checkpoint_freq: int = Field(5000, ge=1)
    log_interval: int = Field(100, ge=1)  # episodes between TensorBoard rollout records
    threads: int | None = Field(1, ge=1, le=1024)  # torch threads while training; None: torch's choice
    service: ServiceParams = ServiceParams()

    @model_validator(mode="before")
    @classmethod
    def _scenario_env(cls, data):
        """A named scenario's env settings are the base; `env:` (a mapping) overrides them.
        An unknown name is left to the field's own check, an env given as an AllocConfig is
        taken whole."""
        if isinstance(data, dict) and isinstance(data.get("scenario"), str) and data["scenario"] in SCENARIOS:
            env = data.get("env")
            if env is None or isinstance(env, dict):
                data = {**data, "env": {**SCENARIOS[data["scenario"]].env, **(env or {})}}
        return data

    @field_validator("scenario")
    @classmethod
    def _known_scenario(cls, v):
        if v is not None and v not in SCENARIOS:
            raise ValueError(f"unknown scenario {v!r} (choose from {', '.join(SCENARIOS)})")
        return v


def load_train_config(path) -> TrainConfig:
    """Read and validate a training YAML; raises ConfigError with one line."""
    return load_yaml_model(path, TrainConfig, "training")


def lattice_pairs(env: AllocConfig) -> list[tuple[int, int]]:
    """The team-size pairs of the lattice up to the env's team sizes (team_sizes: lattice)."""
    from farm.alloc.model import LATTICE, snap

    top_p, top_e = snap(env.n_defenders), snap(env.n_intruders)
    return [(p, e) for p in LATTICE if p <= top_p for e in LATTICE if e <= top_e]


def store_of(config: TrainConfig) -> Path:
    """The capture-time store a run uses: its config's, else the default store."""
    from farm.service.store import default_store_path

    return Path(config.service.store or default_store_path())


def warm(client, config: TrainConfig, progress: bool = True) -> int:
    """Fill the store and the client's memo over the team-size lattice, with a progress bar
    (on Ray the cases are computed in parallel on the farm); returns the cases asked."""
    from farm.progress import GameProgress

    if config.env.team_sizes != "lattice" or not config.service.warm_lattice:
        return 0
    pairs = lattice_pairs(config.env)
    bar = GameProgress(len(pairs), enabled=progress, desc="capture-time lattice", unit="case")
    client.warm(pairs, progress=bar.update)
    bar.close()
    return len(pairs)


class UpdateTimer(BaseCallback):
    """Times the training and its gradient updates through SB3's public callback hooks: an
    off-policy algorithm calls train() between a rollout's end and the next rollout's start
    (or the end of training), so those intervals add up to the update time (`update_seconds`);
    `wall_seconds` runs from the training's start to its end. A resumed run starts them at
    its checkpoint's figures (RunState), so that both describe the whole run."""

    def __init__(self):
        super().__init__()
        self.update_seconds = 0.0
        self.earlier_wall_seconds = 0.0  # a resumed run's parts before its checkpoint
        self._rollout_end: float | None = None
        self._start: float | None = None
        self._end: float | None = None

    @property
    def wall_seconds(self) -> float:
        """The training's wall seconds so far (to its end once ended), earlier parts included."""
        if self._start is None:
            return self.earlier_wall_seconds
        return self.earlier_wall_seconds + (self._end or time.perf_counter()) - self._start

    def _on_training_start(self) -> None:
        self._start, self._end = time.perf_counter(), None

    def _on_rollout_end(self) -> None:
        self._rollout_end = time.perf_counter()

    def _on_rollout_start(self) -> None:
        self._close()

    def _on_training_end(self) -> None:
        self._close()
        self._end = time.perf_counter()

    def _close(self) -> None:
        if self._rollout_end is not None:
            self.update_seconds += time.perf_counter() - self._rollout_end
            self._rollout_end = None

    def _on_step(self) -> bool:
        return True


class DivergenceGuard(BaseCallback):
    """Stops a run that diverges, through SB3's public callback hooks: the actions of every
    step (`self.locals`), and after every training phase (at the next rollout's start and
    at the end of training) the logger's actor and critic losses and every parameter of
    the policy (actor, critics and their targets) must be finite; else TrainingDiverged
    names the step. It reads and changes nothing of the training (no random numbers)."""

    LOSSES = ("train/actor_loss", "train/critic_loss")

    def _on_training_start(self) -> None:
        self._check("in the policy it starts from")

    def _on_step(self) -> bool:
        actions = self.locals.get("actions")
        if actions is not None and not np.all(np.isfinite(actions)):
            raise TrainingDiverged(f"training diverged at step {self.num_timesteps}: the policy's action is not "
                                   f"finite (lower td3.learning_rate?)")
        return True

    def _on_rollout_start(self) -> None:
        self._check("after the update")

    def _on_training_end(self) -> None:
        self._check("after the update")

    def _check(self, what: str) -> None:
        import torch

        for name in self.LOSSES:
            value = self.logger.name_to_value.get(name)
            if value is not None and not math.isfinite(value):
                raise TrainingDiverged(f"training diverged at step {self.num_timesteps}: {name} is {value} "
                                       f"{what} (lower td3.learning_rate?)")
        with torch.no_grad():  # one sum per tensor is fast; a sum that is not finite is looked into
            params = list(self.model.policy.named_parameters())
            sums = torch.stack([p.sum() for _, p in params])
            if bool(torch.isfinite(sums).all()):
                return
            for name, p in params:
                if not bool(torch.isfinite(p).all()):
                    raise TrainingDiverged(f"training diverged at step {self.num_timesteps}: the policy's {name} "
                                           f"is not finite {what} (lower td3.learning_rate?)")


class StepProgress(BaseCallback):
    """A progress bar of environment steps with steps/s and ETA."""

    def __init__(self, total: int, done: int, enabled: bool):
        super().__init__()
        self.total, self.done, self.enabled = total, done, enabled

    def _on_training_start(self) -> None:
        from farm.progress import GameProgress

        self.bar = GameProgress(self.total, self.done, enabled=self.enabled, desc="steps", unit="step")
        self.last = self.num_timesteps

    def _on_step(self) -> bool:
        self.bar.update(self.num_timesteps - self.last)
        self.last = self.num_timesteps
        return True

    def _on_training_end(self) -> None:
        self.bar.close()


class RunState:
    """What a checkpoint holds beside SB3's model (with its optimisers, step count and last
    observation) and replay buffer, so that a run resumed from it goes on exactly as the run
    would have without the stop (training on the CPU is deterministic):

    - the random generators SB3 draws from, by their public getters: numpy's global one (the
      action noise, the replay buffer's samples), torch's (TD3's target smoothing noise),
      python's (SB3 seeds it) and the model's action space's (the warm-up's random actions).
      Loading a model seeds them all again (SB3's set_random_seed), so they are set after;
    - the training env's episode in progress, generator and counters
      (SwarmAllocationEnv.get_state) and the Monitor's rewards of that episode (they only make
      the episode's logged return whole);
    - the eval env's state (evaluations go on drawing from its generator, seeded once at the
      start), and the periodic evaluation's history (EvalCallback's public attributes: the
      steps, returns and lengths of evaluations.npz, the best and the last mean return, and
      its call count, which decides the steps it evaluates at);
    - the wall and update seconds so far (UpdateTimer), so that metrics.json's timings
      describe the whole run: the earlier parts up to the checkpoint and the resumed part.

    train_env, monitor: the training env and the Monitor around it; eval_env: the periodic
    evaluation's env; evaluation: its EvalCallback; timer: the run's UpdateTimer."""

    def __init__(self, train_env: SwarmAllocationEnv, monitor: Monitor, eval_env: SwarmAllocationEnv,
                 evaluation: EvalCallback, timer: UpdateTimer):
        self.train_env, self.monitor, self.eval_env = train_env, monitor, eval_env
        self.evaluation, self.timer = evaluation, timer

    def capture(self, model: TD3) -> dict:
        """The state now, as a picklable dict (restore's input)."""
        import random

        import torch

        e = self.evaluation
        return {
            "steps": int(model.num_timesteps),
            "numpy_rng": np.random.get_state(), "torch_rng": torch.get_rng_state(), "python_rng": random.getstate(),
            "action_space_rng": model.action_space.np_random.bit_generator.state,
            "train_env": self.train_env.get_state(), "episode_rewards": list(self.monitor.rewards),
            "eval_env": self.eval_env.get_state(),
            "evaluations": {"timesteps": list(e.evaluations_timesteps), "results": list(e.evaluations_results),
                            "ep_lengths": list(e.evaluations_length), "best_mean_reward": e.best_mean_reward,
                            "last_mean_reward": e.last_mean_reward},
            "wall_seconds": self.timer.wall_seconds, "update_seconds": self.timer.update_seconds,
        }

    def restore(self, model: TD3, state: dict) -> None:
        """Put a captured state back, into a model just loaded from the same checkpoint (its
        training env reset: the Monitor accepts steps again); rewrites evaluations.npz with
        the evaluations up to the checkpoint (removes it when there were none)."""
        import random

        import torch

        self.train_env.set_state(state["train_env"])
        self.monitor.rewards = list(state["episode_rewards"])
        self.eval_env.set_state(state["eval_env"])
        e, history = self.evaluation, state["evaluations"]
        e.evaluations_timesteps = list(history["timesteps"])
        e.evaluations_results = list(history["results"])
        e.evaluations_length = list(history["ep_lengths"])
        e.best_mean_reward, e.last_mean_reward = history["best_mean_reward"], history["last_mean_reward"]
        e.n_calls = state["steps"]  # one env: a call per step, so it evaluates where an uninterrupted run does
        if e.log_path is not None:  # the stopped part's later evaluations go: the resumed run redoes them
            if e.evaluations_timesteps:  # EvalCallback's own layout
                np.savez(e.log_path, timesteps=e.evaluations_timesteps, results=e.evaluations_results,
                         ep_lengths=e.evaluations_length)
            else:
                Path(e.log_path + ".npz").unlink(missing_ok=True)
        self.timer.earlier_wall_seconds = state["wall_seconds"]
        self.timer.update_seconds = state["update_seconds"]
        np.random.set_state(state["numpy_rng"])
        torch.set_rng_state(state["torch_rng"])
        random.setstate(state["python_rng"])
        model.action_space.np_random.bit_generator.state = state["action_space_rng"]


def checkpoint_files(run_dir: Path, steps: int) -> tuple[Path, Path, Path]:
    """The files of a run folder's checkpoint at `steps`, in checkpoints/: (the model, SB3's
    rl_model_<steps>_steps.zip; the replay buffer, rl_model_replay_buffer_<steps>_steps.pkl;
    the RunState, rl_model_state_<steps>_steps.pkl, written last and whole)."""
    folder = Path(run_dir) / "checkpoints"
    return (folder / f"rl_model_{steps}_steps.zip", folder / f"rl_model_replay_buffer_{steps}_steps.pkl",
            folder / f"rl_model_state_{steps}_steps.pkl")


class AfterUpdates(BaseCallback):
    """An SB3 callback acting each time the steps pass a multiple of `every`, after that step's
    gradient update: an off-policy algorithm updates between a rollout's end and the next
    rollout's start, so it acts at a rollout's start and at the end of training (`due(steps)`,
    the subclass's action). last: the steps it last acted at (a resumed run's checkpoint)."""

    def __init__(self, every: int, last: int = 0):
        super().__init__()
        self.every, self.last = max(1, int(every)), int(last)

    def due(self, steps: int) -> None:
        """Act at `steps` (a subclass's)."""
        raise NotImplementedError

    def _on_step(self) -> bool:
        return True

    def _on_rollout_start(self) -> None:
        self._act_when_due()

    def _on_training_end(self) -> None:
        self._act_when_due()

    def _act_when_due(self) -> None:
        steps = int(self.model.num_timesteps)
        if steps // self.every > self.last // self.every:
            self.due(steps)
            self.last = steps


class Checkpointer(AfterUpdates):
    """Saves a checkpoint (checkpoint_files: the model, the replay buffer, then the RunState)
    each time the steps pass a multiple of `every`, after that step's gradient update
    (AfterUpdates), a state an uninterrupted run goes on from. (SB3's CheckpointCallback saves
    in on_step, before the step's update and before the step's transition enters the replay
    buffer; a run resumed from it went on without them.)

    run_dir: the run folder; every: steps between checkpoints; state: the run's RunState;
    saved: the steps of the checkpoint the run resumed from (0 for a new run)."""

    def __init__(self, run_dir: Path, every: int, state: RunState, saved: int = 0):
        super().__init__(every, saved)
        self.run_dir, self.state = Path(run_dir), state

    def due(self, steps: int) -> None:
        """Save the checkpoint of `steps`."""
        from farm.output import atomic_write_bytes

        model_file, buffer_file, state_file = checkpoint_files(self.run_dir, steps)
        model_file.parent.mkdir(parents=True, exist_ok=True)
        self.model.save(model_file)
        self.model.save_replay_buffer(buffer_file)
        atomic_write_bytes(state_file, pickle.dumps(self.state.capture(self.model)))


def latest_checkpoint(run_dir: Path) -> tuple[Path, int] | None:
    """(model file, steps) of a run folder's last whole checkpoint (its RunState file, which
    is written last, is there), or None."""
    found = []
    for p in (Path(run_dir) / "checkpoints").glob("rl_model_state_*_steps.pkl"):
        m = re.fullmatch(r"rl_model_state_(\d+)_steps\.pkl", p.name)
        if m and all(f.exists() for f in checkpoint_files(run_dir, int(m.group(1)))):
            found.append(int(m.group(1)))
    if not found:
        return None
    steps = max(found)
    return checkpoint_files(run_dir, steps)[0], steps


def train(config: TrainConfig, run_dir, *, resume: bool = False, show_progress: bool = True,
          callbacks: list | None = None) -> dict:
    """Train (or resume) into run_dir, with the capture-time client of config.service
    (farm.service.lookup.open_client: a local Ray or the cluster named, or in process);
    returns the metrics written to metrics.json.

    callbacks: more SB3 callbacks, called after the run's own (so in on_step after the
    step's evaluation, and at a rollout's start or the training's end after the checkpoint of
    the steps so far): farm.experiments reports a trial's progress to Ray Tune so."""
    import torch

    run_dir = Path(run_dir)
    if run_dir.exists() and (run_dir / "config.yaml").exists() and not resume:
        raise ConfigError(f"out: {run_dir} already holds a run; resume it or choose another folder")
    if resume:
        saved = run_dir / "config.yaml"
        if not saved.exists():
            raise ConfigError(f"resume: {run_dir} holds no run to resume")
        before = load_train_config(saved)  # parsed: fields added since compare equal at their defaults

        def comparable(c: TrainConfig) -> dict:  # the length of training and the threads may change on resume
            return c.model_copy(update={"td3": c.td3.model_copy(update={"n_timesteps": 0}), "threads": None}).model_dump()

        if comparable(before) != comparable(config):
            raise ConfigError(f"resume: {run_dir} was trained with another config")
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.yaml").write_text(yaml.safe_dump(json.loads(config.model_dump_json()), sort_keys=False))
    threads_before = torch.get_num_threads()
    if config.threads is not None:
        torch.set_num_threads(config.threads)
    try:
        return _train(config, run_dir, resume, show_progress, callbacks or [])
    finally:
        torch.set_num_threads(threads_before)


def _train(config: TrainConfig, run_dir: Path, resume: bool, show_progress: bool, extra: list) -> dict:
    from farm.service.lookup import open_client

    with open_client(config.env.service_settings(), mode=config.service.mode, store=store_of(config),
                     address=config.service.address) as client:
        return _learn(config, run_dir, resume, show_progress, client, extra)


def _learn(config: TrainConfig, run_dir: Path, resume: bool, show_progress: bool, client, extra: list) -> dict:
    warm(client, config, progress=show_progress)
    train_env = SwarmAllocationEnv(config.env, client=client, estimates=config.service.estimates)
    monitor = Monitor(train_env)
    env = DummyVecEnv([lambda: monitor])
    eval_env = SwarmAllocationEnv(config.env, client=client, estimates=config.service.estimates)
    eval_monitor = Monitor(eval_env)
    # EvalCallback resets without a seed, which would leave the curve's episodes to OS entropy:
    # seeding once here makes evaluations.npz the same on every run of the same config.
    eval_monitor.reset(seed=config.seed + EVAL_SEED_OFFSET)
    p = config.td3
    n_act = env.action_space.shape[0]
    noise = NormalActionNoise(np.zeros(n_act), p.noise_std * np.ones(n_act)) if p.noise_type == "normal" else None
    timer = UpdateTimer()
    evaluation = EvalCallback(eval_monitor, eval_freq=config.eval.freq, n_eval_episodes=config.eval.episodes,
                              log_path=str(run_dir), best_model_save_path=str(run_dir / "best"), deterministic=True,
                              verbose=0)
    state = RunState(train_env, monitor, eval_env, evaluation, timer)

    done_steps = 0
    checkpoint = latest_checkpoint(run_dir) if resume else None
    if checkpoint:
        path, done_steps = checkpoint
        _, buffer, state_file = checkpoint_files(run_dir, done_steps)
        # force_reset=False keeps the saved last observation: training goes on with the episode in progress
        model = TD3.load(path, env=env, force_reset=False, tensorboard_log=str(run_dir / "tb"), device="cpu")
        model.load_replay_buffer(buffer)
        env.reset()  # through the wrappers (the Monitor refuses a step before a reset); the state replaces the episode
        state.restore(model, pickle.loads(state_file.read_bytes()))
    else:
        model = TD3(
            p.policy, env, learning_rate=p.learning_rate, buffer_size=p.buffer_size,
            learning_starts=p.learning_starts, batch_size=p.batch_size, tau=p.tau, gamma=p.gamma,
            train_freq=p.train_freq, gradient_steps=p.gradient_steps, policy_delay=p.policy_delay,
            action_noise=noise, policy_kwargs=dict(p.policy_kwargs), tensorboard_log=str(run_dir / "tb"),
            seed=config.seed, verbose=0, device="cpu",
        )
    remaining = max(0, p.n_timesteps - done_steps)
    callbacks = CallbackList([
        timer,  # first: it times the updates alone
        DivergenceGuard(),  # next: no evaluation or checkpoint sees a step or an update it refuses
        evaluation,
        Checkpointer(run_dir, config.checkpoint_freq, state, done_steps),
        StepProgress(p.n_timesteps, done_steps, show_progress),
        *extra,
    ])
    try:
        try:
            model.learn(total_timesteps=remaining, callback=callbacks, reset_num_timesteps=not checkpoint,
                        tb_log_name="td3", log_interval=config.log_interval)
        except ActionError as e:  # the env refuses a non-finite action before the guard sees it
            raise TrainingDiverged(f"training diverged at step {model.num_timesteps + 1}: the policy's action is "
                                   f"not finite (lower td3.learning_rate?): {e}") from None
    except TrainingDiverged as e:  # the folder says so, for farm report and whoever looks
        (run_dir / DIVERGED).write_text(str(e) + "\n")
        raise
    wall = timer.wall_seconds  # the whole run's, as the other figures: a resumed run's earlier parts too
    model.save(run_dir / "model.zip")
    evals = np.load(run_dir / "evaluations.npz") if (run_dir / "evaluations.npz").exists() else None
    metrics = {
        "name": config.name,
        "timesteps": int(model.num_timesteps),
        "resumed_from": done_steps if checkpoint else None,
        "wall_seconds": wall,
        "steps_per_second": model.num_timesteps / wall if wall > 0 else None,
        "update_seconds": timer.update_seconds,
        "outside_update_share": 1 - timer.update_seconds / wall if wall > 0 else None,
        "engagements": train_env.engagements,  # engaged cells of the training steps
        "estimated_share": train_env.estimated / train_env.engagements if train_env.engagements else 0.0,
        "final_eval_mean_return": float(evals["results"][-1].mean()) if evals is not None else None,
        "final_eval_std_return": float(evals["results"][-1].std()) if evals is not None else None,
        "best_eval_mean_return": float(evals["results"].mean(axis=1).max()) if evals is not None else None,
    }
    (run_dir / "metrics.json").write_text(json.dumps(metrics, indent=2))
    if evals is not None:
        from farm.alloc.plots import plot_training_curve

        plot_training_curve(evals["timesteps"], evals["results"], run_dir / "training_curve.png", config.name)
    return metrics
