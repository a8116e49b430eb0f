"""A training run's folder: the one reader and writer of its files (a damaged file is one line,
ResultsError naming it, never a traceback).

    config.yaml        the TrainConfig it was trained with (plain values)
    model.zip          the trained model (stable-baselines3's file)
    metrics.json       RunMetrics: steps, timings, the periodic evaluation's figures
    evaluations.npz    the periodic evaluation (SB3's EvalCallback layout: timesteps, results, ep_lengths)
    training_curve.png the curve of evaluations.npz
    DIVERGED           written, with the reason, into a run that diverged: not a result
    checkpoints/       rl_model_<n>_steps.zip, rl_model_replay_buffer_<n>_steps.pkl, rl_model_state_<n>_steps.pkl
                       (the RunState sealed with the others' SHA-256; damaged/: those --resume could not load)
    best/, tb/         SB3's best model and TensorBoard logs
    eval_table.csv, eval_episodes.csv, eval_steps.csv          farm eval (and an experiment's trial)
    eval_table_games.csv, fidelity_differences.csv            farm eval --fidelity games
    behaviour_steps.png, density_<policy>.png                 farm eval's figures
"""

from __future__ import annotations

import json
import re
import time
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from pydantic import BaseModel, ConfigDict

from farm.core.errors import ConfigError, ResultsError

__all__ = ["RunFolder", "RunMetrics", "checkpoint_files", "latest_checkpoint", "whole_checkpoints", "move_damaged",
           "CONFIG", "MODEL", "METRICS", "EVALUATIONS", "DIVERGED", "LEARNER", "DAMAGED", "STATE_MAGIC"]

CONFIG = "config.yaml"
MODEL = "model.zip"
METRICS = "metrics.json"
EVALUATIONS = "evaluations.npz"
DIVERGED = "DIVERGED"
LEARNER = "td3"  # the learner of a run whose config has no `algo` (RunFolder.learner)
DAMAGED = "damaged"  # checkpoints/damaged/, pretrain/damaged/: files a resume could not load (move_damaged)
STATE_MAGIC = b"swarm-farm checkpoint state\n"  # a sealed RunState's first line (farm.core.sealed)

# What a damaged or unreadable evaluations.npz raises on np.load and reading its arrays:
# OSError (missing, a folder, unreadable), EOFError (empty), zipfile.BadZipFile (cut short,
# a bad CRC), zlib.error (a damaged compressed member), ValueError (not an .npz: numpy
# refuses it as pickled data; object arrays), LookupError (KeyError: no such array in the
# archive; IndexError: a plain .npy array indexed by name).
_NPZ_DAMAGE = (OSError, EOFError, zipfile.BadZipFile, zlib.error, ValueError, LookupError)


class RunMetrics(BaseModel):
    """metrics.json: what a training run measured. Fields in the file's order; an older file
    without a field reads it as None."""

    model_config = ConfigDict(extra="ignore")

    name: str | None = None
    algo: str | None = None  # None: a config without `algo` (td3)
    timesteps: int | None = None
    resumed_from: int | None = None
    wall_seconds: float | None = None
    steps_per_second: float | None = None
    update_seconds: float | None = None
    outside_update_share: float | None = None
    engagements: int | None = None
    estimated_share: float | None = None
    final_eval_mean_return: float | None = None
    final_eval_std_return: float | None = None
    best_eval_mean_return: float | None = None
    kept: str | None = None  # model.zip: the final model or the best evaluated (`keep`)
    pretrain_states: int | None = None
    pretrain_seconds: float | None = None
    pretrain_loss: float | None = None
    pretrained_eval_mean_return: float | None = None
    pretrain_resumed_after: int | None = None  # the saved iteration a resumed pretraining went on after


def checkpoint_files(run_dir: Path, steps: int) -> tuple[Path, Path, Path]:
    """The files of a run folder's checkpoint at `steps`, in checkpoints/: (the model, SB3's
    rl_model_<steps>_steps.zip; the replay buffer, rl_model_replay_buffer_<steps>_steps.pkl;
    the RunState, rl_model_state_<steps>_steps.pkl, written last and whole)."""
    folder = Path(run_dir) / "checkpoints"
    return (folder / f"rl_model_{steps}_steps.zip", folder / f"rl_model_replay_buffer_{steps}_steps.pkl",
            folder / f"rl_model_state_{steps}_steps.pkl")


def whole_checkpoints(run_dir: Path, replay_buffer: bool = True) -> list[int]:
    """The steps of a run folder's whole checkpoints, newest first: those whose RunState file,
    which is written last, is there, and so is the model and, with replay_buffer (an off-policy
    learner's checkpoint: TD3's, SAC's), its replay buffer. Whole is not sound: a file may
    still be damaged (--resume moves such a checkpoint aside, move_damaged, and tries the next)."""
    found = []
    for p in (Path(run_dir) / "checkpoints").glob("rl_model_state_*_steps.pkl"):
        m = re.fullmatch(r"rl_model_state_(\d+)_steps\.pkl", p.name)
        if m is None:
            continue
        model, buffer, state = checkpoint_files(run_dir, int(m.group(1)))
        if model.exists() and state.exists() and (buffer.exists() or not replay_buffer):
            found.append(int(m.group(1)))
    return sorted(found, reverse=True)


def latest_checkpoint(run_dir: Path, replay_buffer: bool = True) -> tuple[Path, int] | None:
    """(model file, steps) of a run folder's last whole checkpoint (whole_checkpoints' first), or None."""
    found = whole_checkpoints(run_dir, replay_buffer)
    if not found:
        return None
    return checkpoint_files(run_dir, found[0])[0], found[0]


def move_damaged(*paths: Path) -> Path:
    """Move the files of paths that exist into the damaged/ folder beside them (DAMAGED: kept,
    never read again), under their own names (a name already taken there gets the time,
    .<YYYYmmddTHHMMSS>, added); returns that folder (the first path's)."""
    folder = Path(paths[0]).parent / DAMAGED
    for path in map(Path, paths):
        if not path.exists():
            continue
        aside = path.parent / DAMAGED / path.name
        aside.parent.mkdir(exist_ok=True)
        if aside.exists():
            aside = aside.with_name(f"{path.name}.{time.strftime('%Y%m%dT%H%M%S')}")
        path.replace(aside)
    return folder


class RunFolder:
    """One training run's folder (see the module doc). path: the folder."""

    def __init__(self, path):
        self.path = Path(path)

    def __repr__(self) -> str:
        return f"RunFolder({str(self.path)!r})"

    def file(self, name: str) -> Path:
        """The path of one of the run's files (the names of the module doc)."""
        return self.path / name

    # ------------------------------------------------------------------ config and model
    def is_run(self) -> bool:
        """Whether the folder holds a run (its config.yaml)."""
        return self.file(CONFIG).exists()

    def has_model(self) -> bool:
        """Whether the run is trained (its model.zip)."""
        return self.file(MODEL).exists()

    def read_config(self):
        """The run's TrainConfig; ConfigError (one line) without config.yaml or for a bad one."""
        from farm.alloc.training.config import load_train_config

        if not self.is_run():
            raise ConfigError(f"{self.path}: not a training run (no {CONFIG})")
        return load_train_config(self.file(CONFIG), trainable=False)  # the record of what was trained

    def learner(self) -> str:
        """The policy name the run's trained model is evaluated under: its config's algo (td3 for a
        config without `algo`, or without a readable config)."""
        values = self.read_config_values() if self.is_run() else None
        algo = values.get("algo") if isinstance(values, dict) else None
        return algo if isinstance(algo, str) else LEARNER

    def read_config_values(self) -> dict | None:
        """config.yaml as plain values (None without it)."""
        path = self.file(CONFIG)
        return yaml.safe_load(path.read_text()) if path.exists() else None

    def write_config(self, config) -> None:
        """Write config.yaml (a TrainConfig), creating the folder."""
        self.path.mkdir(parents=True, exist_ok=True)
        self.file(CONFIG).write_text(yaml.safe_dump(json.loads(config.model_dump_json()), sort_keys=False))

    def model_path(self) -> Path:
        """model.zip's path."""
        return self.file(MODEL)

    # ------------------------------------------------------------------ metrics and evaluations
    def write_metrics(self, metrics: RunMetrics) -> None:
        """Write metrics.json."""
        self.file(METRICS).write_text(json.dumps(metrics.model_dump(), indent=2))

    def read_metrics(self) -> RunMetrics | None:
        """metrics.json (None without it); ResultsError (one line) when it is unreadable."""
        path = self.file(METRICS)
        if not path.exists():
            return None
        try:
            return RunMetrics.model_validate(json.loads(path.read_text()))
        except (OSError, UnicodeDecodeError, ValueError) as e:
            raise ResultsError(f"{path}: unreadable metrics ({type(e).__name__})") from None

    def evaluations(self) -> tuple[np.ndarray, np.ndarray] | None:
        """evaluations.npz as (timesteps (E,) int64, results (E, episodes) float64); None without
        the file; ResultsError (one line) when it is damaged."""
        path = self.file(EVALUATIONS)
        if not path.exists():
            return None
        try:
            with np.load(path) as data:
                return np.asarray(data["timesteps"], dtype=np.int64), np.asarray(data["results"], dtype=float)
        except _NPZ_DAMAGE as e:
            raise ResultsError(f"{path}: unreadable evaluations ({type(e).__name__})") from None

    def diverged(self) -> str | None:
        """Why the run diverged (its DIVERGED file), or None."""
        path = self.file(DIVERGED)
        return path.read_text(errors="replace").strip() if path.exists() else None

    def mark_diverged(self, why: str) -> None:
        """Say in the folder that the run diverged (farm report shows it)."""
        self.file(DIVERGED).write_text(why + "\n")

    # ------------------------------------------------------------------ farm eval's files
    def write_evaluation(self, table: pd.DataFrame, per: pd.DataFrame, steps: pd.DataFrame) -> list[Path]:
        """eval_table.csv, eval_episodes.csv and eval_steps.csv (farm.alloc.evaluation.rollout's tables)."""
        from farm.core.output import write_table

        return [write_table(table, self.path / "eval_table", "csv"),
                write_table(per, self.path / "eval_episodes", "csv"),
                write_table(steps, self.path / "eval_steps", "csv")]

    def write_fidelity(self, table: pd.DataFrame, differences: pd.DataFrame) -> list[Path]:
        """eval_table_games.csv and fidelity_differences.csv (farm eval --fidelity games)."""
        from farm.core.output import write_table

        return [write_table(table, self.path / "eval_table_games", "csv"),
                write_table(differences, self.path / "fidelity_differences", "csv")]

    def eval_steps(self) -> pd.DataFrame | None:
        """eval_steps.csv (None without it); ResultsError (one line) when it is not the table
        farm eval writes: unreadable, or missing a column, or with a non-numeric measure."""
        from farm.alloc.game.measures import STEP_MEASURES

        path = self.file("eval_steps.csv")
        if not path.exists():
            return None
        try:
            steps = pd.read_csv(path)
        except (OSError, UnicodeDecodeError, ValueError) as e:  # pandas' ParserError and EmptyDataError are ValueErrors
            raise ResultsError(f"{path}: unreadable per-step evaluation ({type(e).__name__}); "
                               "rerun farm eval") from None
        missing = [c for c in ("policy", "episode", "step", *STEP_MEASURES) if c not in steps.columns]
        if missing:
            raise ResultsError(f"{path}: not farm eval's per-step table (no column {missing[0]!r}); rerun farm eval")
        for column in ("episode", "step", *STEP_MEASURES):
            if not pd.api.types.is_numeric_dtype(steps[column]):
                raise ResultsError(f"{path}: column {column!r} holds values that are not numbers; rerun farm eval")
        return steps
