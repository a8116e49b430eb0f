"""`farm suite`: every allocator on every scenario, on the same seeded episodes, as a
leaderboard: the config (config.py), one (scenario, allocator) matchup (matchup.py; its Ray task,
tasks.py), the run (run.py) and the leaderboard (leaderboard.py). docs/suite.md tells how."""

from farm.studies.suite.config import SuiteConfig, available_policies, load_suite_config
from farm.studies.suite.leaderboard import MEASURES, format_leaderboard, leaderboard, leaderboard_view, plot_leaderboard
from farm.studies.suite.matchup import evaluate_matchup
from farm.studies.suite.run import run_suite

__all__ = ["SuiteConfig", "load_suite_config", "available_policies", "evaluate_matchup", "run_suite", "leaderboard",
           "leaderboard_view", "plot_leaderboard", "format_leaderboard", "MEASURES"]
