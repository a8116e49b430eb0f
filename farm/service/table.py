"""`farm table CONFIG`: fill the store over ranges of (n_p, n_e) and policies;
`farm table show CONFIG`: print the tables and plot heatmaps.

    name: small
    store: results/capture_times.sqlite                       # default: farm.service.store.default_store_path()
    settings: {games: 64, seed: 0, tau: 5.0, t_max: 60}      # games, seed, workers.Case fields
    n_pursuers: [1, 2, 3, 4]
    n_evaders: [1, 2, 3]
    policies:                                                 # default: area_min vs centroid
      - {pursuer_policy: area_min, evader_policy: centroid}
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from pydantic import Field, field_validator

from farm.core.config import SETTING_FIELDS, ConfigError, Strict, case_from, check_game_names, load_yaml_model
from farm.service.keys import SERVICE_FIELDS, GameSettings
from farm.service.store import default_store_path


class PolicyPair(Strict):
    """One table's policies."""

    pursuer_policy: str  # the pursuers' policy of this table (a workers pursuer policy)
    evader_policy: str  # the evaders' policy of this table (a workers evader policy)


class TableConfig(Strict):
    """A `farm table` config: the store, the settings, the team sizes and the policy pairs."""

    name: str = Field(min_length=1, max_length=100, pattern=r"^[A-Za-z0-9_.-]+$")  # names the heatmap files
    store: str | None = Field(None, min_length=1)  # None: default_store_path()
    settings: dict[str, Any] = {}  # games, seed and workers.Case fields but the team sizes
    n_pursuers: list[int] = Field(min_length=1)  # the tables' rows: team sizes of the pursuers
    n_evaders: list[int] = Field(min_length=1)  # the tables' columns: team sizes of the evaders
    policies: list[PolicyPair] | None = None  # one table per pair; None: the settings' policies (or Case's)

    @field_validator("settings")
    @classmethod
    def _setting_names(cls, v):
        if "n_pursuers" in v or "n_evaders" in v:
            raise ValueError("team sizes go in the table's n_pursuers / n_evaders lists, not in settings")
        check_game_names(v, SETTING_FIELDS + SERVICE_FIELDS)
        return v

    def game_settings(self) -> GameSettings:
        """The table's settings with the policies named in `settings` (or Case's defaults)."""
        game = {k: v for k, v in self.settings.items() if k not in SERVICE_FIELDS}
        own = {k: v for k, v in self.settings.items() if k in SERVICE_FIELDS}
        return GameSettings(case_from({"n_pursuers": 1, "n_evaders": 1, **game}), **own)

    def store_path(self, store=None) -> Path:
        """The store: `store` if given (the CLI's --store), else the config's, else the default."""
        return Path(store or self.store or default_store_path())

    def settings_list(self) -> list[GameSettings]:
        """One GameSettings per policy pair (the settings alone without pairs)."""
        base = self.game_settings()
        if not self.policies:
            return [base]
        return [base.with_(pursuer_policy=p.pursuer_policy, evader_policy=p.evader_policy) for p in self.policies]

    def check(self) -> None:
        """Validate every policy pair and team size once (a key per value, not per cell)."""
        for settings in self.settings_list():
            for n_p in self.n_pursuers:
                settings.key(n_p, self.n_evaders[0])
            for n_e in self.n_evaders:
                settings.key(self.n_pursuers[0], n_e)

    def size(self):
        """Cases, games and CPU seconds by the cost model (farm.games.sizes.JobSize; at most 4096 cells sampled)."""
        from farm.games.sizes import ITEM_BYTES, JobSize, game_seconds

        settings = self.settings_list()
        cells = len(self.n_pursuers) * len(self.n_evaders)
        picks = np.linspace(0, cells - 1, min(cells, 4096)).round().astype(int)
        mean = float(np.mean([game_seconds(s.key(self.n_pursuers[i // len(self.n_evaders)],
                                                 self.n_evaders[i % len(self.n_evaders)]).case)
                              for s in settings for i in picks]))
        cases = len(settings) * cells
        games = cases * settings[0].games
        return JobSize("table", cases, "case", games, mean * games, cases * ITEM_BYTES)

    def keys(self):
        """(settings, n_p, n_e, StatsKey) for every cell of every table."""
        out = []
        for settings in self.settings_list():
            for n_p in self.n_pursuers:
                for n_e in self.n_evaders:
                    out.append((settings, n_p, n_e, settings.key(n_p, n_e)))
        return out


def load_table_config(path) -> TableConfig:
    """Read and validate a table YAML; raises ConfigError with one line."""
    return load_yaml_model(path, TableConfig, "table", check=TableConfig.check)


def fill_table(config: TableConfig, *, store=None, address=None, workers=None, show_progress=True) -> dict:
    """Have the service compute every cell of every table (misses on the farm, in parallel);
    returns counts: cases, computed (the rest came from the store) and seconds."""
    from farm.core.progress import GameProgress
    from farm.games.shards import warn_coarse_steps
    from farm.runtime import check_workers
    from farm.service.client import open_client

    check_workers(workers)
    settings = config.settings_list()
    pairs = [(n_p, n_e) for n_p in config.n_pursuers for n_e in config.n_evaders]
    warn_coarse_steps(s.game for s in settings)
    t0 = time.perf_counter()
    with open_client(settings[0], store=config.store_path(store), address=address, num_cpus=workers) as client:
        before = len(client.stats()["computations"])
        bar = GameProgress(len(settings) * len(pairs), enabled=show_progress, desc="cases", unit="case")
        for s in settings:
            client.with_settings(s).warm(pairs, progress=bar.update)
        bar.close()
        computed = len(client.stats()["computations"]) - before
    return {"cases": len(settings) * len(pairs), "computed": computed, "seconds": time.perf_counter() - t0}


def table_frames(config: TableConfig, store=None) -> list[tuple[GameSettings, pd.DataFrame, pd.DataFrame]]:
    """Per policy pair: mean capture time and fraction within tau, n_p rows x n_e columns."""
    from farm.service.store import StatsStore

    path = config.store_path(store)
    if not path.exists():
        raise ConfigError(f"{path}: no capture-time store yet; run `farm table CONFIG` first")
    db = StatsStore(path, read_only=True)
    values = db.load_all()
    out = []
    for settings in config.settings_list():
        mean = pd.DataFrame(np.nan, index=config.n_pursuers, columns=config.n_evaders)
        frac = mean.copy()
        for n_p in config.n_pursuers:
            for n_e in config.n_evaders:
                v = values.get(settings.key(n_p, n_e).digest())
                if v is not None:
                    mean.loc[n_p, n_e] = v.mean_capture.mean
                    frac.loc[n_p, n_e] = v.frac_captured_tau
        for df in (mean, frac):
            df.index.name, df.columns.name = "n_pursuers", "n_evaders"
        out.append((settings, mean, frac))
    db.close()
    return out


def plot_heatmaps(settings: GameSettings, mean: pd.DataFrame, frac: pd.DataFrame, path: Path) -> Path:
    """The two tables of a policy pair (table_frames) as heatmaps side by side, written to path."""
    from farm.core.plots import draw_heatmap, new_figure, save_figure

    fig, axes = new_figure(1, 2, figsize=(11, 4.6))
    draw_heatmap(fig, axes[0, 0], mean, "mean capture time (s)", "viridis")
    draw_heatmap(fig, axes[0, 1], frac, f"fraction captured within tau = {settings.game.tau:g} s", "magma")
    fig.suptitle(f"{settings.game.pursuer_policy} vs {settings.game.evader_policy} ({settings.games} games per case)")
    fig.tight_layout()
    return save_figure(fig, path)
