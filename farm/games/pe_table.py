"""The paper's pursuit-evasion tables (section 4.1; docs/model.md section 3).

The team speeds default to the paper's (1 and 1); other speeds rerun the same
cases as a sensitivity check, the paper's figures beside them unchanged.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pandas as pd

from workers import Case, run_case, run_games

from farm.core.errors import ConfigError
from farm.core.output import write_table

# (table, n_pursuers, pursuer policy, evader policy, the paper's mean capture time in s)
PAPER_CASES = [
    ("Table 1: pure-distance pursuit", 1, "pure_pursuit", "target", 3.373),
    ("Table 1: pure-distance pursuit", 3, "pure_pursuit", "target", 2.856),
    ("Table 1: pure-distance pursuit", 5, "pure_pursuit", "target", 2.0),
    ("Table 2: area minimization", 1, "area_min", "constant_area", 3.3103),
    ("Table 2: area minimization", 3, "area_min", "centroid", 3.276),
    ("Table 2: area minimization", 5, "area_min", "centroid", 3.222),
]

COLUMNS = ["mean", "std", "ci95_low", "ci95_high", "min", "max"]
SPEEDS = ("pursuer_speed", "evader_speed")


def paper_case(base: Case, n_pursuers: int, pursuer_policy: str, evader_policy: str) -> Case:
    """One paper case (1 evader) with the rest of the settings (speeds, r_c...) from base."""
    return replace(base, n_pursuers=n_pursuers, n_evaders=1, pursuer_policy=pursuer_policy,
                   evader_policy=evader_policy)


MIN_GAMES = 2  # games a case at least: a confidence interval needs two


def check_games(n_games: int) -> None:
    """ConfigError naming games when a case would get fewer than MIN_GAMES games."""
    if n_games < MIN_GAMES:
        raise ConfigError(f"games: need at least {MIN_GAMES} games per case for a CI, got {n_games}", field="games")


def paper_speeds(base: Case) -> bool:
    """Whether base's team speeds are the paper's (1 and 1)."""
    return base.pursuer_speed == base.evader_speed == 1.0


def default_folder(base: Case) -> str:
    """Where the tables at base's speeds go by default: results/pe-table at the paper's speeds,
    else results/pe-table-speeds-P-E."""
    if paper_speeds(base):
        return "results/pe-table"
    return f"results/pe-table-speeds-{base.pursuer_speed:g}-{base.evader_speed:g}"


def pe_size(n_games: int, base: Case | None = None):
    """The PE tables' size (farm.games.sizes.JobSize): PAPER_CASES, n_games games each."""
    from farm.games.sizes import GAME_ROW_BYTES, JobSize, game_seconds

    base = base or Case(1, 1)
    seconds = sum(game_seconds(paper_case(base, n_p, pp, ep)) for _, n_p, pp, ep, _ in PAPER_CASES)
    cases = len(PAPER_CASES)
    return JobSize("pe-table", cases, "case", cases * n_games, seconds * n_games, cases * n_games * GAME_ROW_BYTES)


def pe_tables(n_games: int = 50, seed: int = 0, base: Case | None = None,
              progress=None) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Run every paper case (PAPER_CASES) for n_games games each; returns (summary, per_game).

    summary: one row per case, columns table, n_pursuers, pursuer_policy, evader_policy,
    pursuer_speed, evader_speed, games, not_captured (games whose evader was not caught
    by t_max), mean, std, ci95_low, ci95_high, min, max (of the capture time, s),
    paper_mean (the paper's mean, s) and case_key. per_game: one row per game, columns
    table and n_pursuers then
    workers.game_statistics' columns. base: the settings every case shares (default
    Case's: the paper's); progress: called with a line of text after each case.
    """
    base = (base or Case(1, 1)).validate()
    rows, games = [], []
    for table, n_p, pp, ep, paper in PAPER_CASES:
        case = paper_case(base, n_p, pp, ep)
        per_game, summary = run_case(case, n_games, seed)
        row = {
            "table": table,
            "n_pursuers": n_p,
            "pursuer_policy": pp,
            "evader_policy": ep,
            **{name: getattr(case, name) for name in SPEEDS},
            "games": summary.n_games,
            "not_captured": summary.last_capture.n_censored,
        }
        row.update({c: getattr(summary.last_capture, c) for c in COLUMNS})
        row["paper_mean"] = paper
        row["case_key"] = case.key()
        rows.append(row)
        per_game.insert(0, "n_pursuers", n_p)
        per_game.insert(0, "table", table)
        games.append(per_game)
        if progress:
            progress(f"{table}, {n_p} pursuer(s): mean {row['mean']:.3f} s (paper {paper})")
    return pd.DataFrame(rows), pd.concat(games, ignore_index=True)


def format_tables(summary: pd.DataFrame) -> str:
    """The tables as text: one block per table, the paper's figure beside ours.

    summary: pe_tables' summary. Each block's header states the games per case and the
    speeds (the paper's games had equal speeds, 1 and 1).
    """
    lines = []
    for table, block in summary.groupby("table", sort=False):
        lines.append(table + f" (capture time, s; {int(block['games'].iloc[0])} games per case; "
                     f"{speeds_text(block.iloc[0])})")
        lines.append(f"{'case':<12}{'mean':>8}{'std':>8}{'95% CI':>18}{'min':>8}{'max':>8}{'paper':>9}")
        for _, r in block.iterrows():
            ci = f"[{r['ci95_low']:.3f}, {r['ci95_high']:.3f}]"
            case = f"{r['n_pursuers']} pursuer" + ("s" if r["n_pursuers"] > 1 else "")
            miss = f"  ({r['not_captured']} not captured)" if r["not_captured"] else ""
            lines.append(
                f"{case:<12}{r['mean']:>8.3f}{r['std']:>8.3f}{ci:>18}{r['min']:>8.2f}{r['max']:>8.2f}"
                f"{r['paper_mean']:>9.4g}{miss}"
            )
        lines.append("")
    return "\n".join(lines)


def speeds_text(row) -> str:
    """The team speeds as text, e.g. 'pursuer speed 2, evader speed 1'.

    row: a summary row (dict or Series with pursuer_speed and evader_speed) or a Case;
    "(the paper's)" is added when both speeds are 1.
    """
    p, e = (float(row[name] if isinstance(row, (dict, pd.Series)) else getattr(row, name)) for name in SPEEDS)
    return f"pursuer speed {p:g}, evader speed {e:g}" + (" (the paper's)" if p == e == 1.0 else "")


def write_pe_tables(out: Path, n_games: int, seed: int, fmt: str, progress=None,
                    figures: bool = True, base: Case | None = None) -> tuple[list[Path], pd.DataFrame]:
    """Run the paper's cases and write their tables, plus one figure per case, into `out`.

    Writes out/pe_tables.<fmt> (the summary) and out/pe_games.<fmt> (per game), fmt
    "csv" or "parquet", and with figures=True fig_<pursuer>_vs_<evader>_<n>p.png of game
    0 of each case. base: the settings every case shares (default Case's: the paper's,
    equal speeds); progress: as pe_tables'. Returns (the paths written, the summary).
    """
    from farm.core.plots import plot_game

    base = (base or Case(1, 1)).validate()
    summary, per_game = pe_tables(n_games, seed, base=base, progress=progress)
    out.mkdir(parents=True, exist_ok=True)
    written = [write_table(summary, out / "pe_tables", fmt), write_table(per_game, out / "pe_games", fmt)]
    if figures:
        for _, n_p, pp, ep, _ in PAPER_CASES:
            case = paper_case(base, n_p, pp, ep)
            res = run_games(case, seed, 0, 1, record=True)
            name = f"fig_{pp}_vs_{ep}_{n_p}p.png"
            written.append(
                plot_game(res, out / name, title=f"{n_p} pursuer(s) {pp} vs evader {ep} (game 0, seed {seed}; "
                                                 f"{speeds_text(case)})")
            )
    return written, summary
