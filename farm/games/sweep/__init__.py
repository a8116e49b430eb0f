"""Parametric Monte Carlo sweeps on Ray: a typed config of points (config.py) and
their games run as coarse, resumable, deterministic shards (run.py)."""

from farm.core.errors import SweepError
from farm.games.sweep.config import VARIABLE_FIELDS, Point, SweepConfig, load_sweep_config, varied_names
from farm.games.sweep.run import Shard, SweepRun, format_summary, print_info, run_sweep, simulate_shard, summary_view

__all__ = ["SweepConfig", "Point", "load_sweep_config", "VARIABLE_FIELDS", "varied_names", "SweepError",
           "Shard", "SweepRun", "run_sweep", "simulate_shard", "format_summary", "summary_view", "print_info"]
