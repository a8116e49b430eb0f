"""`farm train CONFIG`: an allocator trained with stable-baselines3 (TD3, PPO or SAC, the
config's `algo`, after planner-guided pretraining when it has `pretrain:`) on the allocation env,
rewards from the capture-time service, into a run folder (farm.alloc.training.runs). The design (the
config, checkpoints and exact resume, divergence) is docs/training.md."""

from __future__ import annotations

import pickle
import shutil
import sys
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from stable_baselines3 import TD3
from stable_baselines3.common.callbacks import CallbackList, EvalCallback
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.noise import NormalActionNoise
from stable_baselines3.common.vec_env import DummyVecEnv

from farm.alloc.allocators.repair import RepairedActions
from farm.alloc.envs.defenders import SwarmAllocationEnv
from farm.alloc.game.lattice import lattice_groups, warm_lattices
from farm.alloc.networks.trained import algorithm_class
from farm.alloc.training.callbacks import Checkpointer, DivergenceGuard, StepProgress, UpdateTimer
from farm.alloc.training.config import TrainConfig, store_of
from farm.alloc.training.dagger.loop import pretrain
from farm.alloc.training.runs import (
    DAMAGED,
    STATE_MAGIC,
    RunFolder,
    RunMetrics,
    checkpoint_files,
    move_damaged,
    whole_checkpoints,
)
from farm.alloc.training.state import RunState
from farm.core.config import ConfigError
from farm.core.errors import ActionError, SwarmFarmError, TrainingDiverged
from farm.core.output import check_writable_folder

__all__ = ["train", "make_model", "policy_kwargs", "single_env", "training_envs", "EVAL_SEED_OFFSET"]

EVAL_SEED_OFFSET = 1_000_000  # the periodic evaluation's episodes: seeded apart from training's

# What a damaged checkpoint file raises on SB3's load (a zip cut short or with a bad CRC:
# BadZipFile, which SB3 turns into a ValueError, zlib.error; a damaged member: torch's
# RuntimeError, json's ValueError, a missing one: KeyError) and on unpickling a replay buffer
# or a RunState (UnpicklingError, EOFError when cut short; garbage unpickles into many errors).
_CHECKPOINT_DAMAGE = (OSError, EOFError, zipfile.BadZipFile, zlib.error, pickle.UnpicklingError, ValueError,
                      LookupError, RuntimeError, AttributeError, ImportError, TypeError)


def train(config: TrainConfig, run_dir, *, resume: bool = False, show_progress: bool = True,
          callbacks: list | None = None, on_pretrain=None, opponent_procs: int = 1) -> dict:
    """Train (or resume) into run_dir, with the capture-time client of config.service
    (farm.service.lookup.open_client: a local Ray or the cluster named, or in process);
    returns the metrics written to metrics.json.

    opponent_procs: on the intruders' side with n_envs > 1, the processes that answer the
    frozen allocator's moves (farm.alloc.envs.intruders.Opponent: the same run whatever the
    number; more than 1 needs the service on Ray).

    callbacks: more SB3 callbacks, called after the run's own (so in on_step after the
    step's evaluation, and at a rollout's start or the training's end after the checkpoint of
    the steps so far): farm.studies.experiments reports a trial's progress to Ray Tune so.
    on_pretrain(episodes, total, saved): the pretraining's progress (pretrain's on_progress)."""
    import torch

    from farm.alloc.envs.move_helpers import check_procs
    from farm.alloc.training.config import check_allocators, check_pretrain_memory

    check_procs(opponent_procs)
    check_allocators(config)  # before anything is written: a bad expert option names its field
    check_pretrain_memory(config)
    run_dir = check_writable_folder(run_dir, "out")  # before the service, the lattice and the steps
    run = RunFolder(run_dir)
    if run.is_run() and not resume:
        raise ConfigError(f"out: {run_dir} already holds a run; resume it or choose another folder", field="out")
    if resume:
        if not run.is_run():
            raise ConfigError(f"resume: {run_dir} holds no run to resume", field="resume")
        if not config.resumes(run.read_config()):  # parsed: fields added since compare equal at their defaults
            raise ConfigError(f"resume: {run_dir} was trained with another config", field="resume")
    tracker = None
    if config.tracking.mlflow is not None:  # before config.yaml: a store MLflow refuses leaves no run behind
        from farm.alloc.training.tracking import MlflowRun

        tracker = MlflowRun.open(config, run_dir, resume)
    run.write_config(config)
    threads_before = torch.get_num_threads()
    if config.threads is not None:
        torch.set_num_threads(config.threads)
    try:
        metrics = _train(config, run_dir, resume, show_progress, callbacks or [], tracker, on_pretrain,
                         opponent_procs)
    except BaseException as e:
        if tracker is not None:
            tracker.end("KILLED" if isinstance(e, KeyboardInterrupt) else "FAILED")
        raise
    finally:
        torch.set_num_threads(threads_before)
    if tracker is not None:
        tracker.finish(metrics, run_dir)
    return metrics


def _train(config: TrainConfig, run_dir: Path, resume: bool, show_progress: bool, extra: list, tracker=None,
           on_pretrain=None, opponent_procs: int = 1) -> dict:
    from farm.service.client import open_client

    with open_client(config.env.game_settings(), mode=config.service.mode, store=store_of(config),
                     address=config.service.address) as client:
        return _learn(config, run_dir, resume, show_progress, client, extra, tracker, on_pretrain, opponent_procs)


_ACTIVATIONS = {"relu": "ReLU", "tanh": "Tanh", "elu": "ELU", "leaky_relu": "LeakyReLU", "gelu": "GELU"}


def policy_kwargs(values: dict) -> dict:
    """A config's policy_kwargs as SB3 takes them: activation_fn's name as torch.nn's class."""
    import torch

    kwargs = dict(values)
    if "activation_fn" in kwargs:
        kwargs["activation_fn"] = getattr(torch.nn, _ACTIVATIONS[kwargs["activation_fn"]])
    return kwargs


def make_model(config: TrainConfig, env, run_dir: Path):
    """A new SB3 model of config's algo and section, on env (an SB3 VecEnv), seeded config.seed."""
    from stable_baselines3 import PPO, SAC

    p = config.learner
    policy, kwargs = p.policy, policy_kwargs(p.policy_kwargs)
    if policy == "CellPolicy":
        from farm.alloc.networks.cell_policy import CellPolicy as policy

        kwargs["teams"] = (config.env.n_defenders, config.env.n_intruders)  # the env's, not a setting
    common = dict(policy=policy, env=env, learning_rate=p.learning_rate, gamma=p.gamma,
                  policy_kwargs=kwargs, tensorboard_log=str(run_dir / "tb"),
                  seed=config.seed, verbose=0, device="cpu")
    if config.algo == "ppo":
        return PPO(**common, n_steps=p.n_steps, batch_size=p.batch_size, n_epochs=p.n_epochs,
                   gae_lambda=p.gae_lambda, clip_range=p.clip_range, ent_coef=p.ent_coef, vf_coef=p.vf_coef,
                   max_grad_norm=p.max_grad_norm, target_kl=p.target_kl, normalize_advantage=p.normalize_advantage)
    off_policy = dict(buffer_size=p.buffer_size, learning_starts=p.learning_starts, batch_size=p.batch_size,
                      tau=p.tau, train_freq=p.train_freq, gradient_steps=p.gradient_steps)
    if config.algo == "sac":
        return SAC(**common, **off_policy, ent_coef=p.ent_coef, target_entropy=p.target_entropy)
    n_act = env.action_space.shape[0]
    noise = NormalActionNoise(np.zeros(n_act), p.noise_std * np.ones(n_act)) if p.noise_type == "normal" else None
    return TD3(**common, **off_policy, policy_delay=p.policy_delay, action_noise=noise)


def single_env(config: TrainConfig, client):
    """One env of the side config trains: the allocation env (side defenders), or the intruders'
    env against config.opponent's frozen allocator (side intruders), answered by client."""
    if config.side == "intruders":
        from farm.alloc.envs.intruders import SwarmIntruderEnv

        o = config.opponent
        return SwarmIntruderEnv(config.env, opponent=o.name, opponent_options=o.options, reward=o.reward,
                                actions=o.actions, client=client, estimates=config.service.estimates)
    return SwarmAllocationEnv(config.env, client=client, estimates=config.service.estimates)


def training_envs(config: TrainConfig, client, opponent_procs: int = 1):
    """(the SB3 VecEnv trained on, the env whose state a checkpoint keeps, its monitor): one env
    (single_env) in a DummyVecEnv under Monitor, or n_envs > 1 episodes in the batched vector env
    of its side under VecMonitor (the intruders' with opponent_procs processes answering the
    allocator's moves)."""
    if config.n_envs == 1:
        train_env = single_env(config, client)
        monitor = Monitor(train_env)
        return DummyVecEnv([lambda: monitor]), train_env, monitor
    from farm.alloc.envs.sb3_vec import make_vec_env, monitored

    if config.side == "intruders":
        from farm.alloc.envs.intruders import SwarmIntruderVectorEnv

        o = config.opponent
        monitor = monitored(SwarmIntruderVectorEnv(config.env, num_envs=config.n_envs, opponent=o.name,
                                                   opponent_options=o.options, reward=o.reward, actions=o.actions,
                                                   client=client, estimates=config.service.estimates,
                                                   opponent_procs=opponent_procs))
    else:
        monitor = make_vec_env(config.env, config.n_envs, client, config.service.estimates)
    return monitor, monitor.venv.env, monitor


def _eval_envs(config: TrainConfig, client):
    """(the periodic evaluation's env, as EvalCallback takes it, the env whose state a checkpoint
    keeps), seeded once (config.seed + EVAL_SEED_OFFSET)."""
    eval_env = single_env(config, client)
    played = RepairedActions(eval_env) if config.repair == "levels" else eval_env  # as the allocator acts after
    if config.n_envs == 1:
        eval_monitor = Monitor(played)
        # EvalCallback resets without a seed, which would leave the curve's episodes to OS entropy:
        # seeding once here makes evaluations.npz the same on every run of the same config.
        eval_monitor.reset(seed=config.seed + EVAL_SEED_OFFSET)
        return eval_monitor, eval_env
    from stable_baselines3.common.vec_env import VecMonitor

    eval_env.reset(seed=config.seed + EVAL_SEED_OFFSET)
    return VecMonitor(DummyVecEnv([lambda: played])), eval_env  # the training env's type: EvalCallback's check


def _learn(config: TrainConfig, run_dir: Path, resume: bool, show_progress: bool, client, extra: list,
           tracker=None, on_pretrain=None, opponent_procs: int = 1) -> dict:
    """The training on client's statistics into run_dir: its model and envs made or resumed
    (_start), its steps learned (_run_steps), then the model kept and the metrics written
    (_finish); returns the metrics."""
    training = _start(config, run_dir, resume, show_progress, client, tracker, on_pretrain, opponent_procs)
    try:
        _run_steps(training, config, run_dir, show_progress, extra)
        return _finish(training, config, run_dir)
    finally:
        _close_opponent(training.train_env)


def _close_opponent(train_env) -> None:
    """The intruders' side: its allocator's helper processes stop with the training."""
    opponent = getattr(train_env, "opponent", None)
    if opponent is not None:
        opponent.close()


@dataclass
class _Training:
    """A training's model and what its steps go through: model (SB3's), env (the VecEnv trained
    on), train_env (the env whose state a checkpoint keeps), evaluation (the periodic
    EvalCallback), timer (UpdateTimer), state (the RunState checkpoints save), done_steps (the
    steps of the checkpoint resumed from, else 0), resumed (whether it goes on from a
    checkpoint), pretrained (pretrain's outcome when it pretrained now, else None)."""

    model: object
    env: object
    train_env: object
    evaluation: EvalCallback
    timer: UpdateTimer
    state: RunState
    done_steps: int
    resumed: bool
    pretrained: object


def _start(config: TrainConfig, run_dir: Path, resume: bool, show_progress: bool, client, tracker,
           on_pretrain, opponent_procs: int = 1) -> _Training:
    """The training ready for its steps: the lattice warmed (service.warm_lattice), the envs,
    the periodic evaluation (each logged to tracker's MLflow run as it is made), and the model:
    resumed from run_dir's newest checkpoint that loads (with resume), else a new one, pretrained
    when the config has `pretrain:` and that pretraining evaluated first in the curve."""
    if config.service.warm_lattice:
        warm_lattices(client, lattice_groups(config.envs()), show_progress)
    env, train_env, monitor = training_envs(config, client, opponent_procs)
    try:
        eval_vec, eval_env = _eval_envs(config, client)
        timer = UpdateTimer()
        evaluation = EvalCallback(eval_vec, eval_freq=max(1, config.eval.freq // config.n_envs),
                                  n_eval_episodes=config.eval.episodes, log_path=str(run_dir),
                                  best_model_save_path=str(run_dir / "best"), deterministic=True, verbose=0,
                                  # MLflow: each evaluation logged as it is made (farm.alloc.training.tracking)
                                  callback_after_eval=tracker.eval_logger if tracker is not None else None)
        state = RunState(train_env, monitor, eval_env, evaluation, timer, config.n_envs)
        cls = algorithm_class(config.algo)

        done_steps, pretrained = 0, None
        checkpoint = _resume_point(cls, config, run_dir, env) if resume else None
        if checkpoint:
            model, saved, done_steps = checkpoint
            env.reset()  # through the wrappers (the Monitor refuses a step before a reset); the state replaces it
            state.restore(model, saved)
        else:
            model = make_model(config, env, run_dir)
            if config.pretrain is not None:
                pretrained = pretrain(model, config, client, run_dir, show_progress=show_progress,
                                      on_progress=on_pretrain)
                returns = _evaluate_pretrained(model, evaluation, eval_vec, config, run_dir)
                state.pretrain = _pretrain_figures(pretrained, returns)  # every checkpoint keeps them
        return _Training(model, env, train_env, evaluation, timer, state, done_steps, bool(checkpoint), pretrained)
    except BaseException:  # nothing trains: the helpers the env started stop now
        _close_opponent(train_env)
        raise


def _run_steps(training: _Training, config: TrainConfig, run_dir: Path, show_progress: bool, extra: list) -> None:
    """The model's steps up to the learner's n_timesteps, through the run's callbacks (the
    update timer, the divergence guard, the evaluation, the checkpoints, the progress bar) and
    then extra. A divergence (a non-finite action, loss or parameter) is a TrainingDiverged
    naming the step, and the run folder is marked diverged."""
    t, p = training, config.learner
    callbacks = CallbackList([
        t.timer,  # first: it times the updates alone
        DivergenceGuard(),  # next: no evaluation or checkpoint sees a step or an update it refuses
        t.evaluation,
        Checkpointer(run_dir, config.checkpoint_freq, t.state, t.done_steps),
        StepProgress(p.n_timesteps, t.done_steps, show_progress),
        *extra,
    ])
    try:
        try:
            t.model.learn(total_timesteps=max(0, p.n_timesteps - t.done_steps), callback=callbacks,
                          reset_num_timesteps=not t.resumed, tb_log_name=config.algo,
                          log_interval=config.log_interval)
        except ActionError as e:  # the env refuses a non-finite action before the guard sees it
            raise TrainingDiverged(f"training diverged at step {t.model.num_timesteps + 1}: the policy's action is "
                                   f"not finite (lower {config.algo}.learning_rate?): {e}") from None
    except TrainingDiverged as e:  # the folder says so, for farm report and whoever looks
        RunFolder(run_dir).mark_diverged(str(e))
        raise


def _finish(training: _Training, config: TrainConfig, run_dir: Path) -> dict:
    """The trained run's files: model.zip (the best evaluated model with `keep: best` when it
    beats the last, else the last), metrics.json and training_curve.png; returns the metrics."""
    t = training
    wall = t.timer.wall_seconds  # the whole run's, as the other figures: a resumed run's earlier parts too
    run = RunFolder(run_dir)
    best = run_dir / "best" / "best_model.zip"
    kept = "final"
    if config.keep == "best" and best.exists() and t.evaluation.best_mean_reward > t.evaluation.last_mean_reward:
        shutil.copyfile(best, run.model_path())
        kept = "best"
    else:
        t.model.save(run.model_path())
    evals = run.evaluations()
    steps, results = evals if evals is not None else (None, None)
    previous = run.read_metrics() if t.resumed else None  # a checkpoint without the figures: metrics.json's
    metrics = RunMetrics(**{
        "name": config.name,
        "algo": config.algo,
        "timesteps": int(t.model.num_timesteps),
        "resumed_from": t.done_steps if t.resumed else None,
        "wall_seconds": wall,
        "steps_per_second": t.model.num_timesteps / wall if wall > 0 else None,
        "update_seconds": t.timer.update_seconds,
        "outside_update_share": 1 - t.timer.update_seconds / wall if wall > 0 else None,
        "engagements": t.train_env.engagements,  # engaged cells of the training steps
        "estimated_share": t.train_env.estimated / t.train_env.engagements if t.train_env.engagements else 0.0,
        "final_eval_mean_return": float(results[-1].mean()) if evals is not None else None,
        "final_eval_std_return": float(results[-1].std()) if evals is not None else None,
        "best_eval_mean_return": float(results.mean(axis=1).max()) if evals is not None else None,
        "kept": kept,
        **_pretrain_metrics(t.state.pretrain, previous),
    })
    run.write_metrics(metrics)
    if evals is not None:
        from farm.alloc.game.plots import plot_training_curve

        plot_training_curve(steps, results, run.file("training_curve.png"), config.name)
    return metrics.model_dump()


def _resume_point(cls, config: TrainConfig, run_dir: Path, env):
    """(the model with its replay buffer, the RunState's dict, the steps) of run_dir's newest
    checkpoint that loads, or None when it has no whole checkpoint (whole_checkpoints). A
    checkpoint that does not load is moved to checkpoints/damaged/ (move_damaged), said in one
    line on stderr, and the one before it tried; ConfigError (field resume) when none loads. A
    failed load leaves nothing the resumed run sees: the model is the one loaded, whose load
    seeds SB3's generators and the env's next reset again, and the RunState sets them after."""
    damaged = []  # said once the outcome is known (the checkpoint resumed from), or counted in the error
    try:
        for steps in whole_checkpoints(run_dir, replay_buffer=config.replay_buffer):
            model, saved, problem = _load_checkpoint(cls, config, run_dir, steps, env)
            if problem is None:
                for line in damaged:
                    print(f"train {run_dir}: {line}; moved to checkpoints/{DAMAGED}/, resumed from the checkpoint "
                          f"of {steps} steps", file=sys.stderr)
                return model, saved, steps
            move_damaged(*checkpoint_files(run_dir, steps))
            damaged.append(f"the checkpoint of {steps} steps is damaged ({problem})")
    except ConfigError:  # an older checkpoint of another map (an edited config.yaml): what was moved, first
        for line in damaged:
            print(f"train {run_dir}: {line}; moved to checkpoints/{DAMAGED}/", file=sys.stderr)
        raise
    if damaged:
        raise ConfigError(f"resume: {run_dir} has no whole checkpoint ({len(damaged)} damaged, moved to "
                          f"checkpoints/{DAMAGED}/); train it again into another folder", field="resume")
    return None


def _load_checkpoint(cls, config: TrainConfig, run_dir: Path, steps: int, env):
    """(the model with its replay buffer, the RunState's dict, None) of the checkpoint of `steps`,
    or (None, None, what is damaged: its file's name and the error's type, or "fails its
    checksum"). A sealed RunState (farm.core.sealed) is checked first, and the model's and the
    replay buffer's files against the checksums its header holds, before anything is loaded; a
    RunState written without a seal is read as it is (its model zip's own CRCs still hold).
    ConfigError when its model was trained on another map than config's (an edited config.yaml)."""
    from farm.core.sealed import SealProblem, is_sealed, unseal

    model_file, buffer, state_file = checkpoint_files(run_dir, steps)
    try:
        payload = state_file.read_bytes()
    except OSError as e:
        return None, None, _damage(state_file, e)
    if is_sealed(payload, STATE_MAGIC):
        try:
            header, payload = unseal(payload, STATE_MAGIC)
        except SealProblem as e:
            return None, None, f"{state_file.name}: {e}"
        problem = _files_problem(header.get("files"), state_file, (model_file, buffer))
        if problem is not None:
            return None, None, problem
    # force_reset=False keeps the saved last observation: training goes on with the episode in progress
    try:
        model = cls.load(model_file, env=env, force_reset=False, tensorboard_log=str(run_dir / "tb"), device="cpu")
    except SwarmFarmError:
        raise
    except _CHECKPOINT_DAMAGE as e:
        if isinstance(e, ValueError) and "spaces do not match" in str(e):
            # SB3 checks the saved model's spaces against the env's: an edited config.yaml (another grid)
            raise ConfigError(f"resume: {model_file.name} was trained on another map than config.yaml's "
                              f"{config.env.grid_size}x{config.env.grid_size} (was config.yaml edited?): "
                              f"{str(e).splitlines()[0]}", field="resume") from None
        return None, None, _damage(model_file, e)
    if buffer.exists():
        try:
            model.load_replay_buffer(buffer)
        except _CHECKPOINT_DAMAGE as e:
            return None, None, _damage(buffer, e)
    try:
        saved = pickle.loads(payload)
    except _CHECKPOINT_DAMAGE as e:
        return None, None, _damage(state_file, e)
    if not isinstance(saved, dict):
        return None, None, f"{state_file.name}: not a RunState"
    return model, saved, None


def _files_problem(files, state_file: Path, own: tuple[Path, ...]) -> str | None:
    """What is wrong with a checkpoint's files against a sealed RunState's header's `files`
    ({file name: SHA-256}, names of its own checkpoint's files only): a file missing or
    failing its checksum; None when each is whole."""
    from farm.core.sealed import file_sha256

    names = {p.name: p for p in own}
    if not isinstance(files, dict) or not files or any(name not in names for name in files):
        return f"{state_file.name}: its header"
    for name, digest in files.items():
        if not names[name].exists():
            return f"{name}: missing"
        if file_sha256(names[name]) != digest:
            return f"{name}: fails its checksum"
    return None


def _damage(path: Path, e: BaseException) -> str:
    """What is wrong with a checkpoint's file, in a few words: its name and the error's type (its
    cause's when SB3 wraps one: the ValueError of a file that is not a zip holds the BadZipFile)."""
    return f"{path.name}: {type(e.__cause__ or e).__name__}"


def _evaluate_pretrained(model, evaluation: EvalCallback, eval_vec, config: TrainConfig, run_dir: Path) -> float:
    """Evaluate the pretrained model as EvalCallback would (its episodes, from the eval env's
    generator) and put it first in the evaluation's history, at step 0, as the best so far (so
    that `keep: best` keeps it unless RL does better); returns its mean return."""
    from stable_baselines3.common.evaluation import evaluate_policy

    returns, lengths = evaluate_policy(model, eval_vec, n_eval_episodes=config.eval.episodes, deterministic=True,
                                       return_episode_rewards=True)
    evaluated = float(np.mean(returns))
    evaluation.evaluations_timesteps.append(0)
    evaluation.evaluations_results.append(list(returns))
    evaluation.evaluations_length.append(list(lengths))
    np.savez(evaluation.log_path, timesteps=evaluation.evaluations_timesteps,
             results=evaluation.evaluations_results, ep_lengths=evaluation.evaluations_length)
    evaluation.best_mean_reward = evaluation.last_mean_reward = evaluated
    (run_dir / "best").mkdir(parents=True, exist_ok=True)
    model.save(run_dir / "best" / "best_model.zip")
    return evaluated


PRETRAIN_FIGURES = ("pretrain_states", "pretrain_seconds", "pretrain_loss", "pretrained_eval_mean_return",
                    "pretrain_resumed_after")  # metrics.json's fields of the pretraining


def _pretrain_figures(pretrained, evaluated: float) -> dict:
    """metrics.json's PRETRAIN_FIGURES of a pretraining (pretrain's Pretrained) whose model's
    evaluation had the mean return `evaluated`."""
    return {"pretrain_states": pretrained.states, "pretrain_seconds": pretrained.seconds,
            "pretrain_loss": pretrained.loss, "pretrained_eval_mean_return": evaluated,
            "pretrain_resumed_after": pretrained.resumed_after}


def _pretrain_metrics(figures: dict | None, previous) -> dict:
    """The PRETRAIN_FIGURES metrics.json gets: figures (the RunState's: set when this process
    pretrained, or restored with the checkpoint resumed from), else those of a previous
    metrics.json (a checkpoint that holds no figures), else none."""
    if figures is not None:
        return {k: figures.get(k) for k in PRETRAIN_FIGURES}
    if previous is not None:
        return {k: getattr(previous, k) for k in PRETRAIN_FIGURES}
    return {}
