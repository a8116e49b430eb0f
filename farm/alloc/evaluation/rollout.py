"""The one rollout and evaluation loop: allocators on the same seeded episodes.

play runs an allocator on episodes seeded seed .. seed + episodes - 1, stepped together (its
predict() timed, each episode's first observation kept), run_episode on one; evaluate_policies
runs several allocators so and measure_table turns the per-episode rows into a table of
`<measure>_mean` and `<measure>_ci95` (the 95% t interval over episodes, farm.core.stats).
`farm eval`, `farm suite` and the experiments' trials all evaluate through here.

The measures of an episode and of a step: farm.alloc.game.measures.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from farm.alloc.envs.defenders import SwarmAllocationEnv
from farm.alloc.game.dynamics import (
    Layout,
    check_actions,
    episode_end,
    observe,
    start_densities,
    step,
)
from farm.alloc.game.measures import MEASURES, STEP_MEASURES
from farm.alloc.game.model import EngagementModel
from farm.alloc.game.plots import plot_episode
from farm.alloc.intruders.play import EpisodeIntruders, configured_intruders, for_episode, intruder_move
from farm.core.stats import ci_columns

__all__ = ["MEASURES", "STEP_MEASURES", "Episode", "run_episode", "play", "evaluate_policies", "measure_table",
           "steps_table", "step_means", "behaviour_pair"]



@dataclass
class Episode:
    """One episode of an allocator: summary (its measures, in the order return, eliminated,
    breached, length, coverage, engaged, defenders_per_engaged), steps (T, 3) float64 (the
    STEP_MEASURES of each step), frames (the (D, I) densities, (N, N) float64 each, before the
    first step and after each, when recorded, else empty), predict_seconds (wall seconds in
    predict(), summed over the steps), first_obs (2 N^2,) float32 (the observation it started
    from), engagements (when recorded, each step's engaged cells as (cells, n_p, n_e), (k,)
    int64 each, else empty)."""

    summary: dict
    steps: np.ndarray
    frames: list
    predict_seconds: float
    first_obs: np.ndarray
    engagements: list = field(default_factory=list)

    @property
    def length(self) -> int:
        """The episode's steps (predict() calls)."""
        return int(self.summary["length"])


def run_episode(env: SwarmAllocationEnv, policy, seed: int, record: bool = False) -> Episode:
    """One episode of policy (predict(obs, deterministic=True) -> (action, state)) on env's
    settings and client, started as env.reset(seed=seed) starts it (play, for one episode)."""
    return play(env.config, policy, env.client, 1, seed, record_first=record)[0]


def play(config, policy, client, episodes: int, seed: int, record_first: bool = False) -> list[Episode]:
    """policy on episodes seeded seed .. seed + episodes - 1 of the AllocConfig config (their
    engagements answered by client); record_first: keep episode 0's density frames and the
    cells it engaged at each step with their games' team sizes (Episode.engagements).

    The episodes are stepped together, by farm.alloc.game.dynamics.step (the env's own step) over
    the ones still running, so that each step's engagements of every episode are one ask of the
    client (one batch of games under `farm eval --fidelity games`); episode k is, to the last
    bit, SwarmAllocationEnv(config).reset(seed=seed + k) stepped with the policy's actions
    (tests/test_vector_env.py), and the policy is asked for each episode's observation alone.
    A policy or intruder policy that draws its play per episode (for_episode: a mixture) draws
    from the episode's generator after its start, the intruders' first.
    """
    from gymnasium.utils import seeding

    layout = Layout(config.grid_size)
    model = EngagementModel(config, client, False)
    side = configured_intruders(config, client)  # the intruders' policy, None for the drift law
    if record_first:
        model = _Recording(model)
    engaged_cells: list = []
    n, A = config.grid_size, len(layout.src)
    rngs = [seeding.np_random(seed + k)[0] for k in range(episodes)]  # each episode's generator, as the env's
    shares = np.stack([rng.dirichlet(np.ones(n)) for rng in rngs])
    # after the start, a policy that draws its play per episode draws from the episode's generator:
    # the intruders' first (as the env draws them), then the allocator's
    sides = None if side is None else EpisodeIntruders([for_episode(side, rng) for rng in rngs])
    players = [for_episode(policy, rng) for rng in rngs]
    D, I = start_densities(layout, shares)
    obs = observe(D, I)
    first = obs.copy()
    totals, steps = np.zeros(episodes), np.zeros(episodes, dtype=np.int64)
    breached, eliminated, seconds = np.zeros(episodes), np.zeros(episodes), np.zeros(episodes)
    per_step: list[list] = [[] for _ in range(episodes)]
    frames = [(D[0].reshape(n, n).copy(), I[0].reshape(n, n).copy())] if record_first else []
    running = np.arange(episodes)
    while len(running):
        actions = np.empty((len(running), A))
        for row, k in enumerate(running.tolist()):
            t0 = time.perf_counter()
            action, _ = players[k].predict(obs[k], deterministic=True)
            seconds[k] += time.perf_counter() - t0
            actions[row] = check_actions(action, (A,))
        intruders = None if sides is None else intruder_move(sides.subset(running), config.information, D[running],
                                                             I[running])
        r = step(layout, config, model, D[running], I[running], actions, intruders)
        D[running], I[running] = r.D, r.I
        obs[running] = observe(r.D, r.I)
        totals[running] += r.reward
        breached[running] += r.breach
        eliminated[running] += r.eliminated
        steps[running] += 1
        for row, k in enumerate(running.tolist()):
            per_step[k].append([r.coverage[row], r.engaged[row], r.per_engaged[row] if r.engaged[row] else np.nan])
        if record_first and running[0] == 0:
            frames.append((D[0].reshape(n, n).copy(), I[0].reshape(n, n).copy()))
            e, first_rows = model.last, model.last.episode == 0
            engaged_cells.append((e.cells[first_rows].copy(), e.n_p[first_rows].copy(), e.n_e[first_rows].copy()))
        terminated, truncated = episode_end(config, steps[running], r.remaining)
        running = running[~(terminated | truncated)]
    played = []
    for k in range(episodes):
        m = np.array(per_step[k], dtype=np.float64)
        engaged_steps = m[:, 1] > 0
        summary = {"return": float(totals[k]), "eliminated": float(eliminated[k]), "breached": float(breached[k]),
                   "length": int(steps[k]), "coverage": float(m[:, 0].mean()), "engaged": float(m[:, 1].mean()),
                   "defenders_per_engaged": float(np.mean(m[engaged_steps, 2])) if engaged_steps.any() else np.nan}
        played.append(Episode(summary, m, frames if k == 0 else [], float(seconds[k]), first[k],
                              engaged_cells if k == 0 else []))
    return played


class _Recording:
    """An EngagementModel that keeps the Engagements of its last engage_many (play's record_first)."""

    def __init__(self, model: EngagementModel):
        self.model = model
        self.last = None

    def engage_many(self, D: np.ndarray, I: np.ndarray):
        """model.engage_many(D, I), kept as self.last."""
        self.last = self.model.engage_many(D, I)
        return self.last


def measure_table(per: pd.DataFrame, by: list[str], measures=MEASURES) -> pd.DataFrame:
    """One row per group of per-episode rows (by: the grouping columns, groups in order of
    appearance): the group's values, episodes, then `<m>_mean` and `<m>_ci95` for each m of
    measures over its episodes (NaN values left out; NaN half-width for one episode)."""
    rows = []
    for values, g in per.groupby(by, sort=False):
        values = values if isinstance(values, tuple) else (values,)
        rows.append({**dict(zip(by, values)), "episodes": len(g), **ci_columns({m: g[m].to_numpy(dtype=float)
                                                                                 for m in measures})})
    return pd.DataFrame(rows)


def evaluate_policies(config, policies: dict, client, episodes: int, seed: int, out: Path | None = None):
    """Every policy ({name: allocator}) on episodes seeded seed .. seed + episodes - 1; returns
    (table: measure_table by policy, per-episode rows: policy, episode and the measures,
    per-step measures {policy: list of (T, 3) arrays}). out: a folder for each policy's density
    maps of episode 0 (density_<policy>.png); None draws none."""
    rows, steps = [], {}
    for name, policy in policies.items():
        played = play(config, policy, client, episodes, seed, record_first=out is not None)
        rows += [{"policy": name, "episode": k, **e.summary} for k, e in enumerate(played)]
        steps[name] = [e.steps for e in played]
        if out is not None:
            plot_episode(played[0].frames, out / f"density_{name}.png", title=f"{name}: densities through episode 0 "
                         f"(seed {seed}); defenders blue, intruders red")
    per = pd.DataFrame(rows)
    return measure_table(per, ["policy"]), per, steps


def step_means(runs: list[np.ndarray]) -> np.ndarray:
    """Per-step measures of several episodes (lists of (T_k, 3)) -> (T, 3) float64 means over the
    episodes still running at each step (NaN-aware)."""
    length = max(len(r) for r in runs)
    stack = np.full((len(runs), length, 3), np.nan)
    for k, r in enumerate(runs):
        stack[k, : len(r)] = r
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a step no episode engaged at: NaN
        return np.nanmean(stack, axis=0)


def steps_table(steps: dict) -> pd.DataFrame:
    """Per-step measures of every policy and episode: one row each (policy, episode, step, ...)."""
    rows = [{"policy": name, "episode": k, "step": t + 1, **dict(zip(STEP_MEASURES, m[t]))}
            for name, runs in steps.items() for k, m in enumerate(runs) for t in range(len(m))]
    return pd.DataFrame(rows)


def behaviour_pair(steps: dict, table: pd.DataFrame, trained: str) -> dict[str, np.ndarray]:
    """The step-by-step means (step_means) of the trained policy and of the other policy with
    the best mean return, {name: (T, 3) float64}, for farm.alloc.game.plots.plot_behaviour_steps."""
    others = table[table["policy"] != trained].sort_values("return_mean", ascending=False)
    names = [n for n in [trained, *others["policy"].head(1)] if n in steps]
    return {name: step_means(steps[name]) for name in names}
