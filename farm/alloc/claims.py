"""The paper's three qualitative claims (docs/model.md section 5, (a)-(c)), measured on
evaluated training runs (`farm eval` output) and stated with their numbers:

(a) with C_capture = 0 the allocator spreads the defenders over the intruder cells,
    engaging them all in the same step: the trained policy's coverage at the first
    step the two sides can meet (step 1: the intruders' first column advance meets the
    defenders' first move), and the share of episodes with every intruder cell engaged;
(b) with C_capture = 1.5 it destroys them "in a sequential manner": fewer engaged
    cells per step and more defenders per engaged cell than under (a)'s run;
(c) training plateaus within minutes: the wall time at which the evaluation return
    first comes within 5% (of the range of the evaluations) of its best.

Each verdict compares 95% confidence intervals over evaluation episodes; none is
assumed, and the thresholds are stated with them.

    farm claims results/runs     (reads <run>/eval_steps.csv, eval_table.csv,
                                  evaluations.npz and metrics.json)
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd

from farm.alloc.evaluate import mean_ci95

__all__ = ["plateau_minutes", "claims"]


def plateau_minutes(run: Path) -> tuple[float, float, float] | None:
    """When a training run's evaluation return plateaued: claim (c)'s measure of one run.

    The plateau is the first evaluation whose mean return comes within 5% (of the range
    of the evaluations' mean returns) of the best. Reads run/evaluations.npz and
    run/metrics.json; returns (minutes of training to the plateau, its timestep, the
    run's training minutes), or None when either file is missing. The minutes scale the
    run's wall time by the share of its timesteps.
    """
    npz, metrics = run / "evaluations.npz", run / "metrics.json"
    if not npz.exists() or not metrics.exists():
        return None
    ev = np.load(npz)
    steps, returns = ev["timesteps"], ev["results"].mean(axis=1)
    m = json.loads(metrics.read_text())
    best = returns.max()
    reached = np.flatnonzero(returns >= best - 0.05 * max(best - returns.min(), 1e-12))[0]
    total = m["timesteps"]
    minutes = m["wall_seconds"] / 60
    return float(steps[reached] / total * minutes), int(steps[reached]), float(minutes)


def _steps(run: Path) -> pd.DataFrame | None:
    p = run / "eval_steps.csv"
    return pd.read_csv(p) if p.exists() else None


def _fmt(m: float, h: float) -> str:
    return f"{m:.3f} ± {h:.3f}" if math.isfinite(h) else f"{m:.3f}"


def claims(runs_dir: Path, c0: str = "paper_3x3_c1_0", c15: str = "paper_3x3_c1_1.5", policy: str = "td3") -> list[dict]:
    """Measure the paper's three claims on evaluated runs: rows {claim, measured, verdict}.

    runs_dir: the folder of training runs; c0, c15: the names of the C_capture = 0 and
    1.5 runs in it; policy: the evaluated policy whose measures count (eval_steps.csv's
    `policy` column). Claims (a) and (b) need the runs' eval_steps.csv (columns policy,
    episode, step, coverage, engaged_cells, defenders_per_engaged) and are left out
    without it; (c) takes every run in runs_dir with its evaluations. Each row's values
    are strings.
    """
    out = []
    a, b = runs_dir / c0, runs_dir / c15
    sa, sb = _steps(a), _steps(b)
    if sa is not None:
        first = sa[(sa.policy == policy) & (sa.step == 1)]
        cov = mean_ci95(first.coverage.to_numpy(dtype=float))
        all_engaged = float(np.mean(first.engaged_cells.to_numpy() >= _intruder_cells_at_step1(a)))
        verdict = "confirmed" if cov[0] - (cov[1] if math.isfinite(cov[1]) else 0) >= 0.9 else "not confirmed"
        out.append({"claim": "(a) C_capture = 0: all intruder cells engaged in the same (first) step",
                    "measured": f"{policy} coverage at step 1: {_fmt(*cov)} of the intruder mass; every intruder "
                                f"cell engaged at step 1 in {100 * all_engaged:.0f}% of episodes",
                    "verdict": f"{verdict} (threshold: the coverage CI above 0.9)"})
    if sa is not None and sb is not None:
        def measures(s):
            e = s[s.policy == policy]
            per_episode = e.groupby("episode").agg(engaged=("engaged_cells", "mean"),
                                                   dpe=("defenders_per_engaged", "mean"))
            return mean_ci95(per_episode.engaged.to_numpy(dtype=float)), mean_ci95(per_episode.dpe.dropna().to_numpy(dtype=float))
        (e0, d0), (e1, d1) = measures(sa), measures(sb)
        fewer = e1[0] + _h(e1) < e0[0] - _h(e0)
        more = d1[0] - _h(d1) > d0[0] + _h(d0)
        verdict = "confirmed" if fewer and more else ("partly confirmed" if fewer or more else "not confirmed")
        out.append({"claim": "(b) C_capture = 1.5 vs 0: fewer engaged cells per step, more defenders per engaged cell",
                    "measured": f"engaged cells per step {_fmt(*e1)} vs {_fmt(*e0)}; defenders per engaged cell "
                                f"{_fmt(*d1)} vs {_fmt(*d0)}",
                    "verdict": f"{verdict} (fewer: {'yes' if fewer else 'no'}, more: {'yes' if more else 'no'}; "
                               f"non-overlapping 95% CIs)"})
    plateaus = {r.name: plateau_minutes(r) for r in sorted(runs_dir.iterdir()) if r.is_dir()} if runs_dir.exists() else {}
    plateaus = {k: v for k, v in plateaus.items() if v is not None}
    if plateaus:
        worst = max(v[0] for v in plateaus.values())
        out.append({"claim": "(c) training plateaus within minutes",
                    "measured": "; ".join(f"{k}: {v[0]:.1f} min (step {v[1]}) of {v[2]:.1f}" for k, v in plateaus.items()),
                    "verdict": f"{'confirmed' if worst <= 10 else 'not confirmed'} (threshold: every run within 10 "
                               f"minutes of training on 2 cores; plateau: within 5% of the range of evaluation "
                               f"returns below the best)"})
    return out


def _h(ci: tuple[float, float]) -> float:
    return ci[1] if math.isfinite(ci[1]) else 0.0


def _intruder_cells_at_step1(run: Path) -> int:
    """Cells holding intruders after their first advance: the second column from the right, N cells."""
    from farm.alloc.train import load_train_config

    return load_train_config(run / "config.yaml").env.grid_size
