"""The paper's three qualitative claims (docs/model.md section 5, (a)-(c)), measured on evaluated
training runs (`farm eval` output, or an experiment's trials) and stated with their numbers:

(a) with C_capture = 0 the allocator spreads the defenders over the intruder cells,
    engaging them all in the same step: the trained policy's coverage at the first
    step the two sides can meet (step 1: the intruders' first column advance meets the
    defenders' first move), and the share of episodes with every intruder cell engaged;
(b) with C_capture = 1.5 it destroys them "in a sequential manner": fewer engaged
    cells per step and more defenders per engaged cell than under (a)'s run;
(c) training plateaus within minutes: the wall time at which the evaluation return
    first comes within 5% (of the range of the evaluations) of its best.

claims() states them on one run per setting (`farm claims results/runs`: each run's
eval_steps.csv, eval_table.csv, evaluations.npz and metrics.json), claims_over_seeds() over an
experiment's seeds (`farm claims results/experiments/paper`: its trials' run folders).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from farm.alloc.training.runs import RunFolder
from farm.core.errors import ResultsError
from farm.core.stats import format_ci, mean_ci95
from farm.studies.experiment_folder import ExperimentFolder, finished_trials, read_manifest

__all__ = ["plateau_minutes", "measure_a", "measure_b", "claims", "check_claim_runs", "PAIR_C_CAPTURE", "SeedClaims",
           "claims_over_seeds", "find_pairs",
           "write_claims", "write_claims_over_seeds", "COVERAGE_THRESHOLD", "PLATEAU_MINUTES"]

COVERAGE_THRESHOLD = 0.9  # (a): the lower end of the coverage CI at least this
PLATEAU_MINUTES = 10.0  # (c): the plateau within this many minutes of training
CLAIM_A = "(a) C_capture = 0: all intruder cells engaged in the same (first) step"
CLAIM_B = "(b) C_capture = 1.5 vs 0: fewer engaged cells per step, more defenders per engaged cell"
CLAIM_C = "(c) training plateaus within minutes"
RULE_A = f"per seed: the coverage CI over episodes above {COVERAGE_THRESHOLD}"
RULE_B = "per seed: non-overlapping 95% CIs over episodes, fewer engaged cells and more defenders per engaged cell"
RULE_C = (f"per trial: the plateau (the evaluation return within 5% of the range of evaluation returns below the "
          f"best) within {PLATEAU_MINUTES:g} minutes of training on 2 cores")
RULE_OVER_SEEDS = "confirmed when every {unit} confirms, not confirmed when none does, else mixed"


def plateau_minutes(run: Path) -> tuple[float, float, float] | None:
    """When a training run's evaluation return plateaued: claim (c)'s measure of one run.

    The plateau is the first evaluation whose mean return comes within 5% (of the range
    of the evaluations' mean returns) of the best. Reads run/evaluations.npz and
    run/metrics.json; returns (minutes of training to the plateau, its timestep, the
    run's training minutes), or None when either file is missing. The minutes scale the
    run's wall time by the share of its timesteps.
    """
    folder = RunFolder(run)
    evaluations, m = folder.evaluations(), folder.read_metrics()
    if evaluations is None or m is None:
        return None
    steps, returns = evaluations[0], evaluations[1].mean(axis=1)
    best = returns.max()
    reached = np.flatnonzero(returns >= best - 0.05 * max(best - returns.min(), 1e-12))[0]
    total = m.timesteps
    minutes = m.wall_seconds / 60
    return float(steps[reached] / total * minutes), int(steps[reached]), float(minutes)


def _steps(run: Path) -> pd.DataFrame | None:
    return RunFolder(run).eval_steps()


def _learner(run: Path, policy: str | None) -> str:
    """The policy whose measures a claim reads: policy, else the run's learner (its algo)."""
    return policy or RunFolder(run).learner()


def _h(h: float) -> float:
    """A CI half-width, 0 when there is none (one value)."""
    return h if math.isfinite(h) else 0.0


def measure_a(run: Path, policy: str | None = None) -> dict | None:
    """Claim (a)'s measures of one C_capture = 0 run (its eval_steps.csv; None without it):
    coverage_mean, coverage_ci95 (float: the policy's coverage at step 1, mean and 95% CI
    half-width over episodes), all_engaged (float: the share of episodes with every intruder
    cell engaged at step 1) and verdict ("confirmed" when the CI's lower end is at least
    COVERAGE_THRESHOLD, else "not confirmed")."""
    steps = _steps(run)
    if steps is None:
        return None
    policy = _learner(run, policy)
    first = steps[(steps.policy == policy) & (steps.step == 1)]
    m, h = mean_ci95(first.coverage.to_numpy(dtype=float))
    all_engaged = float(np.mean(first.engaged_cells.to_numpy() >= _intruder_cells_at_step1(run)))
    return {"coverage_mean": m, "coverage_ci95": h, "all_engaged": all_engaged,
            "verdict": "confirmed" if m - _h(h) >= COVERAGE_THRESHOLD else "not confirmed"}


def _per_episode(steps: pd.DataFrame, policy: str) -> dict[str, float]:
    """Engaged cells per step and defenders per engaged cell, each averaged over an episode,
    then mean and 95% CI half-width over episodes: {engaged_mean, engaged_ci95, dpe_mean, dpe_ci95}."""
    e = steps[steps.policy == policy]
    per = e.groupby("episode").agg(engaged=("engaged_cells", "mean"), dpe=("defenders_per_engaged", "mean"))
    engaged, dpe = mean_ci95(per.engaged.to_numpy(dtype=float)), mean_ci95(per.dpe.dropna().to_numpy(dtype=float))
    return {"engaged_mean": engaged[0], "engaged_ci95": engaged[1], "dpe_mean": dpe[0], "dpe_ci95": dpe[1]}


def measure_b(run0: Path, run15: Path, policy: str | None = None) -> dict | None:
    """Claim (b)'s measures of a C_capture = 0 run and a 1.5 run (their eval_steps.csv; None
    without either): for each run (suffix _c0, _c15) engaged_mean, engaged_ci95 (engaged cells
    per step) and dpe_mean, dpe_ci95 (defenders per engaged cell), floats over episodes; fewer,
    more (bool: the 1.5 run's CI entirely below, resp. above, the 0 run's) and verdict
    ("confirmed" for both, "partly confirmed" for one, else "not confirmed")."""
    s0, s15 = _steps(run0), _steps(run15)
    if s0 is None or s15 is None:
        return None
    c0, c15 = _per_episode(s0, _learner(run0, policy)), _per_episode(s15, _learner(run15, policy))
    fewer = c15["engaged_mean"] + _h(c15["engaged_ci95"]) < c0["engaged_mean"] - _h(c0["engaged_ci95"])
    more = c15["dpe_mean"] - _h(c15["dpe_ci95"]) > c0["dpe_mean"] + _h(c0["dpe_ci95"])
    verdict = "confirmed" if fewer and more else ("partly confirmed" if fewer or more else "not confirmed")
    return {**{f"{k}_c0": v for k, v in c0.items()}, **{f"{k}_c15": v for k, v in c15.items()},
            "fewer": bool(fewer), "more": bool(more), "verdict": verdict}


def _plateau_confirmed(minutes: float) -> bool:
    return minutes <= PLATEAU_MINUTES


def claims(runs_dir: Path, c0: str = "paper_3x3_c1_0", c15: str = "paper_3x3_c1_1.5",
           policy: str | None = None) -> list[dict]:
    """Measure the paper's three claims on evaluated runs: rows {claim, measured, verdict}.

    runs_dir: the folder of training runs; c0, c15: the names of the C_capture = 0 and
    1.5 runs in it; policy: the evaluated policy whose measures count (eval_steps.csv's
    `policy` column). Claims (a) and (b) need the runs' eval_steps.csv (columns policy,
    episode, step, coverage, engaged_cells, defenders_per_engaged) and are left out
    without it; (c) takes every run in runs_dir with its evaluations. Each row's values
    are strings.

    Each verdict compares 95% confidence intervals over evaluation episodes; none is
    assumed, and the thresholds are stated with them.
    """
    out = []
    a = measure_a(runs_dir / c0, policy)
    if a is not None:
        out.append({"claim": CLAIM_A,
                    "measured": f"{policy} coverage at step 1: {format_ci(a['coverage_mean'], a['coverage_ci95'])} "
                                f"of the intruder mass; every intruder cell engaged at step 1 in "
                                f"{100 * a['all_engaged']:.0f}% of episodes",
                    "verdict": f"{a['verdict']} (threshold: the coverage CI above {COVERAGE_THRESHOLD})"})
    b = measure_b(runs_dir / c0, runs_dir / c15, policy)
    if b is not None:
        out.append({"claim": CLAIM_B,
                    "measured": f"engaged cells per step {format_ci(b['engaged_mean_c15'], b['engaged_ci95_c15'])} vs "
                                f"{format_ci(b['engaged_mean_c0'], b['engaged_ci95_c0'])}; defenders per engaged cell "
                                f"{format_ci(b['dpe_mean_c15'], b['dpe_ci95_c15'])} vs "
                                f"{format_ci(b['dpe_mean_c0'], b['dpe_ci95_c0'])}",
                    "verdict": f"{b['verdict']} (fewer: {'yes' if b['fewer'] else 'no'}, more: "
                               f"{'yes' if b['more'] else 'no'}; non-overlapping 95% CIs)"})
    runs = sorted(r for r in runs_dir.iterdir() if r.is_dir()) if runs_dir.exists() else []
    plateaus = {r.name: plateau_minutes(r) for r in runs}
    plateaus = {k: v for k, v in plateaus.items() if v is not None}
    if plateaus:
        every = all(_plateau_confirmed(v[0]) for v in plateaus.values())
        out.append({"claim": CLAIM_C,
                    "measured": "; ".join(f"{k}: {v[0]:.1f} min (step {v[1]}) of {v[2]:.1f}"
                                          for k, v in plateaus.items()),
                    "verdict": f"{'confirmed' if every else 'not confirmed'} (threshold: every run within "
                               f"{PLATEAU_MINUTES:g} minutes of training on 2 cores; plateau: within 5% of the range "
                               f"of evaluation returns below the best)"})
    return out


def write_claims(runs_dir, rows: list[dict]) -> Path:
    """Write claims()' rows to runs_dir/claims.csv; returns its path."""
    from farm.core.output import write_table

    return write_table(pd.DataFrame(rows), Path(runs_dir) / "claims", "csv")


def _intruder_cells_at_step1(run: Path) -> int:
    """Cells holding intruders after their first advance: the second column from the right, N cells."""
    return RunFolder(run).read_config().env.grid_size


# ----------------------------------------------------------------------------- over seeds
@dataclass(frozen=True)
class SeedClaims:
    """The claims over an experiment's seeds (claims_over_seeds).

    rows: one dict per claim, {claim, verdict, measured, rule}, strings (claims.csv);
    seeds: one row per seed with both trials of the pair finished and evaluated: seed, (a)'s
    coverage_mean, coverage_ci95, all_engaged, a_verdict, (b)'s measure_b columns with
    b_verdict (claims_seeds.csv); trials: one row per finished trial with its evaluations:
    trial, point, seed, plateau_minutes, plateau_step, train_minutes, confirmed (bool);
    pair: the (C_capture 0, 1.5) points or None; note: one line naming the pair, or why
    (a) and (b) are left out.
    """

    rows: list[dict]
    seeds: pd.DataFrame
    trials: pd.DataFrame
    pair: tuple[int, int] | None
    note: str


PAIR_C_CAPTURE = (0.0, 1.5)  # the C_capture of (a)'s and (b)'s two runs, in the paper's order


def check_claim_runs(runs_dir: Path, c0: str, c15: str, named: tuple[bool, bool] = (True, True)) -> str | None:
    """ResultsError (one line naming --c0 or --c15) unless c0 and c15 are two run folders of
    runs_dir trained at C_capture 0 and 1.5 (their config.yaml); a run that is missing is an
    error when its flag was given (named), else the note returned says (a) and (b) are left out."""
    if c0 == c15:
        raise ResultsError(f"--c15: names the same run as --c0 ({c0}); (a) and (b) compare two runs")
    missing = []
    for flag, name, want, given in (("--c0", c0, PAIR_C_CAPTURE[0], named[0]),
                                    ("--c15", c15, PAIR_C_CAPTURE[1], named[1])):
        run = RunFolder(Path(runs_dir) / name)
        values = run.read_config_values() if run.path.is_dir() else None
        if values is None:
            if given:
                raise ResultsError(f"{flag}: {run.path} is not a trained run folder")
            missing.append(f"{flag} {name}")
            continue
        found = (values.get("env") or {}).get("c_capture")
        if found != want:
            raise ResultsError(f"{flag}: {run.path} was trained at C_capture {found}, not {want:g}")
    if missing:
        return f"(a), (b) left out: no run folder {' or '.join(missing)} in {runs_dir}"
    return None


def _point_configs(folder: Path, manifest: dict) -> dict[int, dict]:
    """Each started point's training config (its first trial's run/config.yaml, plain values)."""
    configs: dict[int, dict] = {}
    for t in manifest["trials"]:
        if t["point"] in configs:
            continue
        values = RunFolder(ExperimentFolder(folder).run_dir(t["key"])).read_config_values()
        if values is not None:
            configs[t["point"]] = values
    return configs


def _without_c_capture(config: dict) -> dict:
    """A training config without what may differ between the two points of a pair: the name,
    the seed, the scenario's name and env.c_capture."""
    rest = {k: v for k, v in config.items() if k not in ("name", "seed", "scenario")}
    rest["env"] = {k: v for k, v in (config.get("env") or {}).items() if k != "c_capture"}
    return rest


def find_pairs(folder: Path, manifest: dict) -> list[tuple[int, int]]:
    """The pairs of points (C_capture 0, C_capture 1.5), in point order, whose training configs
    (their trials' run/config.yaml) are otherwise the same (farm.studies.claims' settings for (a)
    and (b), e.g. the paper's 3x3 maps); points not started yet have no config and are left out."""
    configs = _point_configs(folder, manifest)
    capture = {p: (c.get("env") or {}).get("c_capture") for p, c in configs.items()}
    return [(p0, p15) for p0 in sorted(configs) for p15 in sorted(configs)
            if capture[p0] == 0 and capture[p15] == 1.5
            and _without_c_capture(configs[p0]) == _without_c_capture(configs[p15])]


def _count(confirmed: list[bool], unit: str) -> str:
    """The count rule's verdict of per-seed (or per-trial) verdicts, with the count."""
    k, n = sum(confirmed), len(confirmed)
    word = "confirmed" if k == n else ("not confirmed" if k == 0 else "mixed")
    return f"{word} (confirmed in {k} of {n} {unit}{'s' if n != 1 else ''})"


def _spread(values, fmt: str = ".3f", unit: str = "") -> str:
    """Mean ± 95% CI over seeds of values (n,), then the values: `m ± h<unit> (per seed v, ...)`."""
    x = np.asarray(values, dtype=float)
    shown = format_ci(*mean_ci95(x), fmt)
    return f"{shown}{unit} (per seed {', '.join(f'{v:{fmt}}' for v in x)})"


def _row_a(seeds: pd.DataFrame) -> dict:
    confirmed = list(seeds.a_verdict == "confirmed")
    per_seed = "; ".join(f"seed {r.seed}: {r.a_verdict} (coverage {format_ci(r.coverage_mean, r.coverage_ci95)})"
                         for r in seeds.itertuples())
    return {"claim": CLAIM_A, "verdict": _count(confirmed, "seed"),
            "measured": f"coverage at step 1 over seeds {_spread(seeds.coverage_mean)}; share of episodes with every "
                        f"intruder cell engaged at step 1 {_spread(seeds.all_engaged, '.2f')}; {per_seed}",
            "rule": f"{RULE_A}; over seeds: {RULE_OVER_SEEDS.format(unit='seed')}"}


def _verdict_b(seeds: pd.DataFrame) -> str:
    """(b)'s verdict over seeds: each half by the count rule, then both halves together."""
    n = len(seeds)
    fewer, more = int(seeds.fewer.sum()), int(seeds.more.sum())
    halves = {fewer, more}
    if halves == {n}:
        word = "confirmed"
    elif halves == {0}:
        word = "not confirmed"
    elif halves == {0, n}:
        word = "partly confirmed"
    else:
        word = "mixed"
    return (f"{word} (fewer engaged cells in {fewer} of {n} seed{'s' if n != 1 else ''}, more defenders per engaged "
            f"cell in {more} of {n})")


def _row_b(seeds: pd.DataFrame) -> dict:
    per_seed = "; ".join(f"seed {r.seed}: {r.b_verdict} (engaged cells {r.engaged_mean_c15:.3f} vs "
                         f"{r.engaged_mean_c0:.3f}, defenders per engaged cell {r.dpe_mean_c15:.3f} vs "
                         f"{r.dpe_mean_c0:.3f})" for r in seeds.itertuples())
    return {"claim": CLAIM_B, "verdict": _verdict_b(seeds),
            "measured": f"engaged cells per step, C_capture 1.5 - 0, over seeds "
                        f"{_spread(seeds.engaged_mean_c15 - seeds.engaged_mean_c0)}; defenders per engaged cell, "
                        f"1.5 - 0, {_spread(seeds.dpe_mean_c15 - seeds.dpe_mean_c0)}; {per_seed}",
            "rule": f"{RULE_B}; over seeds: each half {RULE_OVER_SEEDS.format(unit='seed')}; (b) confirmed or not "
                    f"confirmed when both halves are, partly confirmed when one half is confirmed and the other "
                    f"not, else mixed"}


def _row_c(trials: pd.DataFrame) -> dict:
    per_point = "; ".join(
        f"point {point}: {_spread(g.plateau_minutes, '.1f', ' min')} of "
        f"{', '.join(f'{m:.1f}' for m in g.train_minutes)} min of training" for point, g in trials.groupby("point"))
    return {"claim": CLAIM_C, "verdict": _count(list(trials.confirmed), "trial"),
            "measured": f"minutes to the plateau over seeds: {per_point}",
            "rule": f"{RULE_C}; over trials: {RULE_OVER_SEEDS.format(unit='trial')}"}


def _seed_measures(folder: Path, finished: list[dict], pair: tuple[int, int], policy: str) -> pd.DataFrame:
    """(a)'s and (b)'s measures of every seed whose two trials of the pair are finished and evaluated."""
    runs = {(t["point"], t["seed"]): t["run"] for t in finished}
    rows = []
    for seed in sorted({s for p, s in runs if p == pair[0]} & {s for p, s in runs if p == pair[1]}):
        run0, run15 = runs[pair[0], seed], runs[pair[1], seed]
        a, b = measure_a(run0, policy), measure_b(run0, run15, policy)
        if a is not None and b is not None:
            a["a_verdict"], b["b_verdict"] = a.pop("verdict"), b.pop("verdict")
            rows.append({"seed": seed, **a, **b})
    return pd.DataFrame(rows)


def _trial_plateaus(finished: list[dict]) -> pd.DataFrame:
    """(c)'s measure of every finished trial with its evaluations and metrics."""
    rows = []
    for t in finished:
        plateau = plateau_minutes(t["run"])
        if plateau is not None:
            rows.append({"trial": t["key"], "point": t["point"], "seed": t["seed"], "plateau_minutes": plateau[0],
                         "plateau_step": plateau[1], "train_minutes": plateau[2],
                         "confirmed": _plateau_confirmed(plateau[0])})
    return pd.DataFrame(rows)


def _pair_note(pairs: list[tuple[int, int]]) -> str:
    """One line naming the pair found, or saying there is none."""
    if not pairs:
        return "(a), (b): no pair of points with C_capture 0 and 1.5 and otherwise the same settings; only (c)"
    more = f", the first of {len(pairs)} pairs (--points names another)" if len(pairs) > 1 else ""
    return f"(a), (b): points {pairs[0][0]} (C_capture 0) and {pairs[0][1]} (C_capture 1.5){more}"


def claims_over_seeds(folder, points: tuple[int, int] | None = None, policy: str | None = None) -> SeedClaims:
    """The paper's claims over an experiment's seeds: SeedClaims.

    The same per-run measures (measure_a, measure_b, plateau_minutes) and per-run verdicts, for
    every seed whose C_capture = 0 and 1.5 trials are both finished ((a), (b)) and for every
    finished trial ((c)); then a verdict per claim by a count rule: confirmed when every seed
    (for (c): every trial) confirms, not confirmed when none does, else mixed. (b) counts its
    two halves (fewer engaged cells; more defenders per engaged cell) so each, and is confirmed
    or not confirmed when both halves are, partly confirmed when one half is confirmed in every
    seed and the other in none, else mixed. The spread across seeds: each measure's per-seed
    values and their mean ± 95% CI over seeds (farm.core.stats.mean_ci95; no CI for one seed),
    and for (b) the per-seed differences C_capture 1.5 - 0.

    folder: a `farm experiments` folder (experiment.json, trials/<trial>/run); only finished
    trials count (their result.json). points: the (C_capture 0, C_capture 1.5) points of (a)
    and (b); default: the first pair find_pairs finds (none: only (c), the note says so).
    ResultsError (one line) for an unreadable manifest or a named point the experiment lacks.
    """
    folder = Path(folder)
    manifest = read_manifest(folder)
    finished = finished_trials(folder, manifest)
    if points is not None:
        known = sorted({t["point"] for t in manifest["trials"]})
        for p in points:
            if p not in known:
                raise ResultsError(f"points: {p} is not a point of {folder} (points {known[0]}-{known[-1]})",
                                   field="points")
        if points[0] == points[1]:
            raise ResultsError(f"points: names point {points[0]} twice; (a) and (b) compare a C_capture 0 point "
                               f"with a C_capture 1.5 one", field="points")
        configs = _point_configs(folder, manifest)
        for p, want in zip(points, PAIR_C_CAPTURE):
            found = (configs.get(p, {}).get("env") or {}).get("c_capture")
            if found is not None and found != want:
                raise ResultsError(f"points: point {p} trains at C_capture {found:g}, not {want:g}", field="points")
        pair, note = tuple(points), f"(a), (b): points {points[0]} and {points[1]}, as named"
    else:
        pairs = find_pairs(folder, manifest)
        pair, note = (pairs[0] if pairs else None), _pair_note(pairs)
    seeds = _seed_measures(folder, finished, pair, policy) if pair else pd.DataFrame()
    if pair:
        note += f"; {len(seeds)} seed(s) with both trials finished and evaluated"
    trials = _trial_plateaus(finished)
    rows = ([_row_a(seeds), _row_b(seeds)] if len(seeds) else []) + ([_row_c(trials)] if len(trials) else [])
    return SeedClaims(rows=rows, seeds=seeds, trials=trials, pair=pair, note=note)


def write_claims_over_seeds(folder, found: SeedClaims) -> list[Path]:
    """Write found's rows to folder/claims.csv and its seeds' measures to folder/claims_seeds.csv
    (when there are any); returns the paths written."""
    from farm.core.output import write_table

    folder = Path(folder)
    written = [write_table(pd.DataFrame(found.rows), folder / "claims", "csv")]
    if len(found.seeds):
        written.append(write_table(found.seeds, folder / "claims_seeds", "csv"))
    return written
