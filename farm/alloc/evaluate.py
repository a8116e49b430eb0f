"""`farm eval RUN_DIR`: the trained policy, the baselines and the planners on the same
seeded episodes; mean return, intruder mass eliminated, breaches, episode length and the
behaviour measures (docs/model.md section 5), each with a 95% CI over episodes:
  coverage: the share of the intruder mass sharing a cell with defenders, per step
            (averaged over the episode's steps);
  engaged: engaged cells per step;
  defenders_per_engaged: defenders per engaged cell, over the steps with any;
density maps of one episode per policy, and behaviour_steps.png: the measures step
by step for the trained policy beside the best baseline.

--fidelity games replaces the service's statistics by simulating every engaged
cell's PE game at each step (all cells' games of a step in parallel as Ray
tasks; in this process, one after another, for a run whose service.mode is local)
and reports how far those outcomes are from the service's. Each engagement
of a case plays the case's next fresh game: game g of the case with the service's
seed, g counting up from the service's number of games, so that these are games the
service did not average and any game can be replayed by run_games.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Iterator

import numpy as np
import pandas as pd

from workers import CaptureStats

from farm.alloc.baselines import BASELINES
from farm.alloc.env import SwarmAllocationEnv
from farm.alloc.plots import plot_episode
from farm.service.lookup import CaptureTimeClient, Lookup


def mean_ci95(x: np.ndarray) -> tuple[float, float]:
    """(mean, half-width of the 95% t interval) of x (n,); the half-width is NaN for n < 2."""
    from scipy import stats

    if len(x) < 2:
        return float(np.mean(x)), math.nan
    return float(np.mean(x)), float(stats.t.ppf(0.975, len(x) - 1) * np.std(x, ddof=1) / math.sqrt(len(x)))


STEP_MEASURES = ("coverage", "engaged_cells", "defenders_per_engaged")


def run_episode(env: SwarmAllocationEnv, policy, seed: int, record: bool = False):
    """One episode; returns (summary dict, density frames if record, per-step measures (T, 3) float64)."""
    obs, _ = env.reset(seed=seed)
    total, frames, steps, per_step = 0.0, [], 0, []
    n = env.n
    if record:
        frames.append((env.D.reshape(n, n).copy(), env.I.reshape(n, n).copy()))
    while True:
        action, _ = policy.predict(obs, deterministic=True)
        obs, r, term, trunc, info = env.step(action)
        total += r
        steps += 1
        per_step.append([info["coverage"], info["engaged_cells"],
                         info["defenders_per_engaged"] if info["engaged_cells"] else np.nan])
        if record:
            frames.append((env.D.reshape(n, n).copy(), env.I.reshape(n, n).copy()))
        if term or trunc:
            m = np.array(per_step)
            engaged_steps = m[:, 1] > 0
            summary = {"return": total, "eliminated": info["eliminated"], "breached": info["breached"],
                       "length": steps, "coverage": float(m[:, 0].mean()), "engaged": float(m[:, 1].mean()),
                       "defenders_per_engaged": float(np.mean(m[engaged_steps, 2])) if engaged_steps.any() else np.nan}
            return summary, frames, m


TABLE_COLUMNS = ("return", "eliminated", "breached", "coverage", "engaged", "defenders_per_engaged", "length")


def evaluate_policies(config, policies: dict, client, episodes: int, seed: int, out: Path | None = None):
    """Every policy on episodes seeded seed..seed+episodes-1; returns (table, per-episode rows,
    per-step measures {policy: list of (T, 3) arrays})."""
    rows, steps = [], {}
    for name, policy in policies.items():
        env = SwarmAllocationEnv(config, client=client)
        steps[name] = []
        for k in range(episodes):
            result, frames, per_step = run_episode(env, policy, seed + k, record=(k == 0 and out is not None))
            rows.append({"policy": name, "episode": k, **result})
            steps[name].append(per_step)
            if frames:
                plot_episode(frames, out / f"density_{name}.png", title=f"{name}: densities through episode 0 "
                             f"(seed {seed}); defenders blue, intruders red")
    per = pd.DataFrame(rows)
    table = []
    for name, g in per.groupby("policy", sort=False):
        row = {"policy": name, "episodes": len(g)}
        for col in TABLE_COLUMNS:
            x = g[col].to_numpy(dtype=float)
            m, h = mean_ci95(x[np.isfinite(x)]) if np.isfinite(x).any() else (math.nan, math.nan)
            row[f"{col}_mean"], row[f"{col}_ci95"] = m, h
        table.append(row)
    return pd.DataFrame(table), per, steps


def step_means(runs: list[np.ndarray]) -> np.ndarray:
    """Per-step measures of several episodes (lists of (T_k, 3)) -> (T, 3) float64 means over the
    episodes still running at each step (NaN-aware)."""
    length = max(len(r) for r in runs)
    stack = np.full((len(runs), length, 3), np.nan)
    for k, r in enumerate(runs):
        stack[k, : len(r)] = r
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a step no episode engaged at: NaN
        return np.nanmean(stack, axis=0)


def steps_table(steps: dict) -> pd.DataFrame:
    """Per-step measures of every policy and episode: one row each (policy, episode, step, ...)."""
    rows = [{"policy": name, "episode": k, "step": t + 1, **dict(zip(STEP_MEASURES, m[t]))}
            for name, runs in steps.items() for k, m in enumerate(runs) for t in range(len(m))]
    return pd.DataFrame(rows)


def plot_behaviour_steps(steps: dict, table: pd.DataFrame, path: Path, trained: str = "td3") -> Path | None:
    """Coverage, engaged cells and defenders per engaged cell, step by step, for the trained
    policy beside the baseline with the best mean return."""
    from farm.plots import new_figure, save_figure

    others = table[table["policy"] != trained].sort_values("return_mean", ascending=False)
    names = [n for n in [trained, *others["policy"].head(1)] if n in steps]
    if not names:
        return None
    fig, axes = new_figure(1, 3, figsize=(12, 3.2))
    axes = axes[0]
    titles = ("coverage (share of intruder mass met)", "engaged cells", "defenders per engaged cell")
    for name in names:
        m = step_means(steps[name])
        for j, ax in enumerate(axes):
            ax.plot(np.arange(1, len(m) + 1), m[:, j], marker="o", label=name)
    for ax, title in zip(axes, titles):
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("step")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)


class FreshGames(Lookup):
    """The games-fidelity backend: the lookup's core without a store, each ask computed as
    the case's next fresh game (see the module doc), a step's games in parallel as Ray
    tasks; each answer is recorded beside the service's for the same cell (`differences`).

    service_client: the CaptureTimeClient of the service being checked; first_game: the
    number of a case's first fresh game (default: the service's games per case);
    in_process: play the games here (the same games: play_shard), not as Ray tasks.
    """

    repeatable = False  # every ask is another game

    def __init__(self, service_client, first_game: int | None = None, in_process: bool = False):
        self.service = service_client
        self.in_process = in_process
        self.first_game = service_client.settings.games if first_game is None else first_game
        self.played: dict[str, int] = {}  # case key -> games played so far
        self.differences: list[dict] = []
        super().__init__(None, self._play)

    def _play(self, keys: list) -> Iterator[tuple[int, CaptureStats]]:
        numbers = []
        for key in keys:
            digest = key.digest()
            numbers.append(self.first_game + self.played.get(digest, 0))
            self.played[digest] = self.played.get(digest, 0) + 1
        rows = self._games(keys, numbers)
        expected = self.service.get_many([key.sizes for key in keys])
        for k, (key, g, v) in enumerate(zip(keys, numbers, expected)):
            stats = CaptureStats.from_games(rows[k])
            self.differences.append({
                "n_pursuers": key.sizes[0], "n_evaders": key.sizes[1], "game": g,
                "game_frac_tau": stats.frac_captured_tau, "service_frac_tau": v.frac_captured_tau,
                "game_mean_capture": stats.mean_capture.mean, "service_mean_capture": v.mean_capture.mean,
                "capture_times": rows[k]["capture_times"].iloc[0].tolist(),
            })
            yield k, stats

    def _games(self, keys: list, numbers: list[int]) -> dict[int, pd.DataFrame]:
        """Game numbers[k] of keys[k]'s case for every k (play_shard's rows), here or as Ray tasks."""
        from farm.shards import play_shard

        jobs = list(range(len(keys)))
        if self.in_process:
            return {k: play_shard(keys[k].case, keys[k].seed, numbers[k], numbers[k] + 1, detail=True) for k in jobs}
        import ray

        from farm.runtime import bounded
        from farm.tasks import _remote_shard

        def submit(k):
            return _remote_shard.remote(keys[k].case, keys[k].seed, numbers[k], numbers[k] + 1, True)

        return {k: ray.get(ref)[0] for k, ref in bounded(submit, jobs, max(1, len(jobs)))}  # a step's cells at once

    def warm(self, keys, progress=None) -> None:
        """Nothing to fill: every ask is a fresh game."""


def evaluate_fidelity(config, policies: dict, client, episodes: int, seed: int,
                      in_process: bool = False) -> tuple[pd.DataFrame, pd.DataFrame]:
    """`farm eval --fidelity games`: every policy on the same seeded episodes with each engaged
    cell's game simulated (each policy meets the same fresh games; in_process: played here,
    else as Ray tasks); returns (the evaluation table, one row per engagement: the game's and
    the service's outcomes)."""
    tables, differences = [], []
    for name, policy in policies.items():
        games = FreshGames(client, in_process=in_process)
        games_client = CaptureTimeClient(client.settings, backend=games)
        tables.append(evaluate_policies(config, {name: policy}, games_client, episodes, seed)[0])
        differences += [{"policy": name, **d} for d in games.differences]
    return pd.concat(tables, ignore_index=True), pd.DataFrame(differences)


def load_policy(run_dir: Path):
    """The trained TD3 policy of a run folder (its model.zip), on the CPU.

    ConfigError without a model.zip; ModelError (one line naming the file) for a file
    stable-baselines3 cannot load (truncated, damaged, not a TD3 model) or whose
    parameters are not all finite."""
    import torch
    from stable_baselines3 import TD3

    from farm.errors import ConfigError, ModelError

    run_dir = Path(run_dir)
    path = run_dir / "model.zip"
    if not path.exists():
        raise ConfigError(f"{run_dir}: no trained model (model.zip); run `farm train CONFIG --out {run_dir}`")
    try:
        model = TD3.load(path, device="cpu")
    except Exception as e:  # any failure to read it: the file is not a model this can evaluate
        problem = (str(e).strip().splitlines() or [""])[0]
        raise ModelError(f"{path}: not a loadable stable-baselines3 model ({type(e).__name__}"
                         f"{': ' + problem if problem else ''})") from None
    with torch.no_grad():
        for name, p in model.policy.named_parameters():
            if not bool(torch.isfinite(p).all()):
                raise ModelError(f"{path}: the policy's {name} is not finite (a run that diverged); "
                                 f"train it again")
    return model


def baselines(grid_size: int) -> dict:
    """Every baseline policy for an N x N grid, by name."""
    return {name: cls(grid_size) for name, cls in BASELINES.items()}


def planners(config, client) -> dict:
    """Every planner (farm.alloc.planners.PLANNERS) for an AllocConfig, planning on the client's
    statistics, by name."""
    from farm.alloc.planners import PLANNERS

    return {name: cls(config, client) for name, cls in PLANNERS.items()}
