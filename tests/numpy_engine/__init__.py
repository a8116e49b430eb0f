"""The numpy engine (1.1.0) that the compiled engine replaced, kept only as a second,
independent fast implementation for the tests and benchmarks/engine.py.

It plays the game of docs/model.md without escapes and at unit speeds: `simulate_games`
and `step_velocities` as they were. Its input checks, results (workers.GameResults) and
cells' container are the package's own.
"""

from numpy_engine.engine import simulate_games, step_velocities

__all__ = ["simulate_games", "step_velocities"]
