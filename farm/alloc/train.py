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
training curve), checkpoints/ (with the replay buffer, for --resume), best/ and
tb/ (TensorBoard). The algorithm is stable-baselines3's TD3 as it ships, on SB3's
DummyVecEnv; metrics.json records the wall time of the gradient updates, timed by
a callback (UpdateTimer), and the share of the run spent outside them.

A run that diverges (a loss, a parameter or an action not finite) stops with
farm.errors.TrainingDiverged naming the step (a callback, DivergenceGuard): no
model.zip or metrics.json is written for it.
"""

from __future__ import annotations

import json
import math
import re
import time
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml
from pydantic import Field, field_validator, model_validator
from stable_baselines3 import TD3
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, CheckpointCallback, EvalCallback
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
    """Times the gradient updates through SB3's public callback hooks: an off-policy
    algorithm calls train() between a rollout's end and the next rollout's start (or the
    end of training), so those intervals add up to the update time (`update_seconds`)."""

    def __init__(self):
        super().__init__()
        self.update_seconds = 0.0
        self._rollout_end: float | None = None

    def _on_rollout_end(self) -> None:
        self._rollout_end = time.perf_counter()

    def _on_rollout_start(self) -> None:
        self._close()

    def _on_training_end(self) -> None:
        self._close()

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


def latest_checkpoint(run_dir: Path) -> tuple[Path, int] | None:
    """(path, steps) of a run folder's last checkpoint, or None."""
    found = []
    for p in (run_dir / "checkpoints").glob("rl_model_*_steps.zip"):
        m = re.match(r"rl_model_(\d+)_steps\.zip", p.name)
        if m:
            found.append((int(m.group(1)), p))
    if not found:
        return None
    steps, path = max(found)
    return path, steps


def train(config: TrainConfig, run_dir, *, resume: bool = False, show_progress: bool = True,
          callbacks: list | None = None) -> dict:
    """Train (or resume) into run_dir, with the capture-time client of config.service
    (farm.service.lookup.open_client: a local Ray or the cluster named, or in process);
    returns the metrics written to metrics.json.

    callbacks: more SB3 callbacks, called after the run's own (so after a step's
    evaluation and checkpoint): farm.experiments reports a trial's progress to Ray Tune so."""
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
    env = DummyVecEnv([lambda: Monitor(train_env)])
    eval_env = Monitor(SwarmAllocationEnv(config.env, client=client, estimates=config.service.estimates))
    # EvalCallback resets without a seed, which would leave the curve's episodes to OS entropy:
    # seeding once here makes evaluations.npz the same on every run of the same config.
    eval_env.reset(seed=config.seed + EVAL_SEED_OFFSET)
    p = config.td3
    n_act = env.action_space.shape[0]
    noise = NormalActionNoise(np.zeros(n_act), p.noise_std * np.ones(n_act)) if p.noise_type == "normal" else None

    done_steps = 0
    checkpoint = latest_checkpoint(run_dir) if resume else None
    if checkpoint:
        path, done_steps = checkpoint
        model = TD3.load(path, env=env, tensorboard_log=str(run_dir / "tb"), device="cpu")
        buffer = path.with_name(f"rl_model_replay_buffer_{done_steps}_steps.pkl")
        if buffer.exists():
            model.load_replay_buffer(buffer)
    else:
        model = TD3(
            p.policy, env, learning_rate=p.learning_rate, buffer_size=p.buffer_size,
            learning_starts=p.learning_starts, batch_size=p.batch_size, tau=p.tau, gamma=p.gamma,
            train_freq=p.train_freq, gradient_steps=p.gradient_steps, policy_delay=p.policy_delay,
            action_noise=noise, policy_kwargs=dict(p.policy_kwargs), tensorboard_log=str(run_dir / "tb"),
            seed=config.seed, verbose=0, device="cpu",
        )
    remaining = max(0, p.n_timesteps - done_steps)
    timer = UpdateTimer()
    callbacks = CallbackList([
        timer,  # first: it times the updates alone
        DivergenceGuard(),  # next: no evaluation or checkpoint sees a step or an update it refuses
        EvalCallback(eval_env, eval_freq=config.eval.freq, n_eval_episodes=config.eval.episodes,
                     log_path=str(run_dir), best_model_save_path=str(run_dir / "best"), deterministic=True,
                     verbose=0),
        CheckpointCallback(save_freq=config.checkpoint_freq, save_path=str(run_dir / "checkpoints"),
                           save_replay_buffer=True, verbose=0),
        StepProgress(p.n_timesteps, done_steps, show_progress),
        *extra,
    ])
    t0 = time.perf_counter()
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
    wall = time.perf_counter() - t0
    model.save(run_dir / "model.zip")
    evals = np.load(run_dir / "evaluations.npz") if (run_dir / "evaluations.npz").exists() else None
    metrics = {
        "name": config.name,
        "timesteps": int(model.num_timesteps),
        "resumed_from": done_steps if checkpoint else None,
        "wall_seconds": wall,
        "steps_per_second": remaining / wall if wall > 0 else None,
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
