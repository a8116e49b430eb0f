"""An experiment folder (`farm experiments`, farm/experiments.py) read back, finished or still
running: its manifest, its finished trials, and each point's learning curves over its seeds
(the periodic evaluation's mean return) with the band drawn around their mean.

A trial counts when it is finished: its trials/<trial>/result.json exists (written after its
training and its evaluation; trials.csv's rule). An unfinished trial, whose evaluations.npz
holds fewer evaluations than its seeds' finished ones, is left out; finished trials of a point
are aligned on the evaluation timesteps they all have (the same ones, but for a point whose
trials were trained with other evaluation settings).
"""

from __future__ import annotations

import json
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from farm.errors import ResultsError
from farm.experiments import MANIFEST, RESULT

__all__ = ["is_experiment", "read_manifest", "finished_trials", "PointCurves", "point_curves", "seed_band",
           "write_learning_curves", "LEARNING_CURVES"]

LEARNING_CURVES = "learning_curves.png"

# What a damaged evaluations.npz raises on np.load and reading its arrays (farm.report's list).
_NPZ_DAMAGE = (OSError, EOFError, zipfile.BadZipFile, zlib.error, ValueError, LookupError)


def is_experiment(folder) -> bool:
    """Whether folder holds an experiment (its experiment.json)."""
    return (Path(folder) / MANIFEST).is_file()


def _read_json(path: Path, what: str):
    try:
        return json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ResultsError(f"{path}: unreadable {what} ({type(e).__name__})") from None


def read_manifest(folder) -> dict:
    """folder/experiment.json: {name, digest, config, store, fields (grid fields), trials: [{key,
    point, seed, values}]}; ResultsError (one line) when it is unreadable or not an experiment's."""
    path = Path(folder) / MANIFEST
    doc = _read_json(path, "experiment manifest")
    if not (isinstance(doc, dict) and isinstance(doc.get("trials"), list) and isinstance(doc.get("fields"), list)):
        raise ResultsError(f"{path}: not an experiment manifest (no trials or fields)")
    return doc


def finished_trials(folder, manifest: dict) -> list[dict]:
    """The manifest's finished trials, in grid order: its entries {key, point, seed, values} with
    run (Path: the trial's run folder) and result (dict: its result.json, a row of trials.csv)."""
    out = []
    for t in manifest["trials"]:
        path = Path(folder) / "trials" / t["key"] / RESULT
        if path.exists():
            out.append({**t, "run": path.parent / "run", "result": _read_json(path, "trial result")})
    return out


@dataclass(frozen=True)
class PointCurves:
    """One point's learning curves over its finished seeds: point (its index), label (its grid
    values, `field=value` comma-separated), seeds (S,) ints, timesteps (E,) int64 (the
    evaluations every seed has) and returns (S, E) float64 (each seed's evaluation return,
    the mean over the evaluation's episodes)."""

    point: int
    label: str
    seeds: tuple[int, ...]
    timesteps: np.ndarray
    returns: np.ndarray


def _evaluations(run: Path) -> tuple[np.ndarray, np.ndarray] | None:
    """run/evaluations.npz as (timesteps (E,) int64, mean returns over episodes (E,) float64);
    None without the file; ResultsError when it is damaged."""
    path = run / "evaluations.npz"
    if not path.exists():
        return None
    try:
        data = np.load(path)
        steps, results = np.asarray(data["timesteps"], dtype=np.int64), np.asarray(data["results"], dtype=float)
    except _NPZ_DAMAGE as e:
        raise ResultsError(f"{path}: unreadable evaluations ({type(e).__name__})") from None
    return steps, results.mean(axis=1)


def point_curves(folder, manifest: dict) -> list[PointCurves]:
    """Every point with a finished, evaluated trial, in point order: its seeds' learning curves
    on the timesteps they all have (a point whose seeds share none is left out)."""
    by_point: dict[int, list[tuple[dict, np.ndarray, np.ndarray]]] = {}
    for t in finished_trials(folder, manifest):
        curve = _evaluations(t["run"])
        if curve is not None:
            by_point.setdefault(t["point"], []).append((t, *curve))
    out = []
    for point, seeds in sorted(by_point.items()):
        common = seeds[0][1]
        for _, steps, _ in seeds[1:]:
            common = np.intersect1d(common, steps)
        if not len(common):
            continue
        returns = np.stack([means[np.searchsorted(steps, common)] for _, steps, means in seeds])
        values = seeds[0][0]["values"]
        label = ", ".join(f"{k}={v}" for k, v in values.items()) or "the base config"
        out.append(PointCurves(point=point, label=label, seeds=tuple(t["seed"] for t, _, _ in seeds),
                               timesteps=common, returns=returns))
    return out


def seed_band(returns: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """The mean over seeds of returns (S, E) float64 and the band around it: (mean, low, high),
    each (E,) float64, and the band's kind. S >= 3: the 95% t interval over seeds
    (farm.alloc.evaluate.mean_ci95 at each timestep, "95% CI over seeds"); S == 2: the two
    seeds' min to max ("min-max of 2 seeds"; a 95% t interval of 2 values is 12.7 standard
    errors wide); S == 1: no band, low = high = mean ("1 seed, no band")."""
    from farm.alloc.evaluate import mean_ci95

    mean = returns.mean(axis=0)
    seeds = returns.shape[0]
    if seeds >= 3:
        half = np.array([mean_ci95(column)[1] for column in returns.T])
        return mean, mean - half, mean + half, "95% CI over seeds"
    if seeds == 2:
        return mean, returns.min(axis=0), returns.max(axis=0), "min-max of 2 seeds"
    return mean, mean, mean, "1 seed, no band"


def write_learning_curves(folder) -> Path | None:
    """folder/learning_curves.png: the learning curves of every point over its finished seeds
    (farm.alloc.plots.learning_curves_figure); returns its path, None when no trial is finished."""
    from farm.alloc.plots import learning_curves_figure
    from farm.plots import save_figure

    curves = point_curves(folder, read_manifest(folder))
    if not curves:
        return None
    return save_figure(learning_curves_figure(curves), Path(folder) / LEARNING_CURVES, dpi=90)
