"""`farm table CONFIG`: fill the store over ranges of (n_p, n_e) and policies;
`farm table show CONFIG`: print the tables and plot heatmaps.

    name: small
    store: results/capture_times.sqlite
    settings: {games: 64, seed: 0, tau: 5.0, t_max: 60}      # ServiceSettings fields
    n_pursuers: [1, 2, 3, 4]
    n_evaders: [1, 2, 3]
    policies:                                                 # default: area_min vs centroid
      - {pursuer_policy: area_min, evader_policy: centroid}
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pandas as pd
from pydantic import BaseModel, ConfigDict, Field, model_validator

from farm.config import ConfigError, GameModel, load_yaml_model
from farm.service.keys import ServiceSettings

DEFAULT_STORE = "results/capture_times.sqlite"


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class SettingsModel(GameModel):
    """The game settings of a table (team sizes come from n_pursuers / n_evaders)."""

    games: int = Field(64, ge=2, le=1_000_000)
    seed: int = Field(0, ge=0)

    @model_validator(mode="after")
    def _no_team_sizes(self):
        if "n_pursuers" in self.model_fields_set or "n_evaders" in self.model_fields_set:
            raise ValueError("team sizes go in the table's n_pursuers / n_evaders lists, not in settings")
        return self


class PolicyPair(_Strict):
    pursuer_policy: str
    evader_policy: str


class TableConfig(_Strict):
    name: str = Field(min_length=1, max_length=100, pattern=r"^[A-Za-z0-9_.-]+$")
    store: str = DEFAULT_STORE
    settings: SettingsModel = SettingsModel()
    n_pursuers: list[int] = Field(min_length=1)
    n_evaders: list[int] = Field(min_length=1)
    policies: list[PolicyPair] | None = None

    def settings_list(self) -> list[ServiceSettings]:
        s = self.settings
        base = ServiceSettings(s.to_case(validate=False), s.games, s.seed)  # each key validates its case
        pairs = self.policies or [PolicyPair(pursuer_policy=s.pursuer_policy, evader_policy=s.evader_policy)]
        return [base.with_(pursuer_policy=p.pursuer_policy, evader_policy=p.evader_policy) for p in pairs]

    def keys(self):
        """(settings, n_p, n_e, StatsKey) for every cell of every table."""
        out = []
        for settings in self.settings_list():
            for n_p in self.n_pursuers:
                for n_e in self.n_evaders:
                    out.append((settings, n_p, n_e, settings.key(n_p, n_e)))
        return out


def load_table_config(path) -> TableConfig:
    return load_yaml_model(path, TableConfig, "table", check=TableConfig.keys)


def fill_table(config: TableConfig, *, store=None, address=None, workers=None, show_progress=True) -> dict:
    """Ask the service for every cell (misses computed on the farm); returns counts."""
    from farm.progress import GameProgress
    from farm.runtime import ray_cluster
    from farm.service.actor import get_service

    keys = config.keys()
    t0 = time.perf_counter()
    with ray_cluster(address, num_cpus=workers) as ray:
        wanted = Path(store or config.store).resolve()
        service = get_service(wanted)
        before = ray.get(service.stats.remote())
        if Path(before["store"]) != wanted:
            raise ConfigError(f"--store: this cluster's capture-time service uses {before['store']}, not {wanted}")
        bar = GameProgress(len(keys), enabled=show_progress, desc="cases", unit="case")
        pending = [service.get_many.remote([k]) for *_, k in keys]
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            ray.get(ready)
            bar.update(len(ready))
        bar.close()
        after = ray.get(service.stats.remote())
    computed = len(after["computations"]) - len(before["computations"])
    return {"cases": len(keys), "computed": computed, "seconds": time.perf_counter() - t0}


def table_frames(config: TableConfig, store=None) -> list[tuple[ServiceSettings, pd.DataFrame, pd.DataFrame]]:
    """Per policy pair: mean capture time and fraction within tau, n_p rows x n_e columns."""
    from farm.service.store import StatsStore

    path = Path(store or config.store)
    if not path.exists():
        raise ConfigError(f"{path}: no capture-time store yet; run `farm table CONFIG` first")
    db = StatsStore(path)
    values = db.load_all()
    out = []
    for settings in config.settings_list():
        mean = pd.DataFrame(np.nan, index=config.n_pursuers, columns=config.n_evaders)
        frac = mean.copy()
        for n_p in config.n_pursuers:
            for n_e in config.n_evaders:
                v = values.get(settings.key(n_p, n_e).digest())
                if v is not None:
                    mean.loc[n_p, n_e] = v["mean_capture_mean"]
                    frac.loc[n_p, n_e] = v["expected_frac_captured_tau"]
        for df in (mean, frac):
            df.index.name, df.columns.name = "n_pursuers", "n_evaders"
        out.append((settings, mean, frac))
    db.close()
    return out


def plot_heatmaps(settings: ServiceSettings, mean: pd.DataFrame, frac: pd.DataFrame, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6))
    for ax, df, title, cmap in [
        (axes[0], mean, "mean capture time (s)", "viridis"),
        (axes[1], frac, f"fraction captured within tau = {settings.game.tau:g} s", "magma"),
    ]:
        im = ax.imshow(df.to_numpy(dtype=float), origin="lower", aspect="auto", cmap=cmap)
        ax.set_xticks(range(len(df.columns)), df.columns)
        ax.set_yticks(range(len(df.index)), df.index)
        ax.set_xlabel("evaders n_e")
        ax.set_ylabel("pursuers n_p")
        ax.set_title(title)
        fig.colorbar(im, ax=ax)
    fig.suptitle(f"{settings.game.pursuer_policy} vs {settings.game.evader_policy} ({settings.games} games per case)")
    fig.tight_layout()
    from farm.plots import save_figure

    return save_figure(fig, path)
