"""How big a job is, said before it starts: a sweep's points and games, a table's cases, the
PE tables' games, and their CPU time by the engine's cost model
(workers.engine.estimated_game_seconds, good to a factor of 2-3).

Above ANNOUNCE_CPU_SECONDS the job says how big it is and how long it will take; above
LIMIT_CPU_SECONDS of CPU time, or when what it keeps in memory (a sweep's planned points, a
table's cases, the PE tables' per-game rows) would take more than half of this machine's
memory, it is refused in one line unless the caller says yes (`--yes`). Counting never
materialises the job: a sweep's size comes from its axes' lengths and a sample of its points.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass

from farm.core.errors import ConfigError
from workers import Case
from workers.engine import estimated_game_seconds

__all__ = ["ANNOUNCE_CPU_SECONDS", "LIMIT_CPU_SECONDS", "ITEM_BYTES", "GAME_ROW_BYTES", "JobSize", "game_seconds",
           "check_size", "duration", "memory_limit"]

ANNOUNCE_CPU_SECONDS = 600.0  # ten CPU-minutes
LIMIT_CPU_SECONDS = 7 * 24 * 3600.0  # a CPU-week (three and a half days on a 2-CPU machine)
ITEM_BYTES = 4096  # a planned sweep point or table case in memory, its manifest entry included (generous)
GAME_ROW_BYTES = 256  # a game's statistics row kept in memory (the PE tables keep every game's)


def memory_limit() -> int:
    """Half of this machine's memory, in bytes."""
    import os

    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") // 2


def game_seconds(case: Case) -> float:
    """One game's single-core seconds by the engine's cost model."""
    return estimated_game_seconds(case.n_pursuers, case.n_evaders, case.pursuer_policy, case.evader_policy,
                                  case.t_max, case.dt, case.pursuer_speed, case.evader_speed)


def duration(seconds: float) -> str:
    """A wall or CPU time in the unit that reads best: '40 s', '12 min', '3.5 h', '9.1 days'."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    if seconds < 2 * 86400:
        return f"{seconds / 3600:.1f} h"
    if seconds < 2 * 365 * 86400:
        return f"{seconds / 86400:.1f} days"
    return f"{seconds / (365.25 * 86400):,.0f} years"


@dataclass(frozen=True)
class JobSize:
    """A job's size: what it is (`sweep`, `table`, `pe-table`), its items (points or cases)
    and games, and its CPU seconds by the cost model."""

    what: str
    items: int
    item_name: str
    games: int
    cpu_seconds: float
    memory_bytes: int

    def describe(self, cpus: int) -> str:
        """'sweep of 1,000 points, 40,000 games: about 3.1 h of CPU time (1.6 h on 2 CPUs)'."""
        return (f"{self.what} of {self.items:,} {self.item_name}{'s' if self.items != 1 else ''}, "
                f"{self.games:,} games: "
                f"about {duration(self.cpu_seconds)} of CPU time by the engine's cost model "
                f"({duration(self.cpu_seconds / max(1, cpus))} on {cpus} CPU{'s' if cpus != 1 else ''})")


def check_size(size: JobSize, *, yes: bool, cpus: int = 2, file=None) -> None:
    """Say a large job's size before it starts; refuse (ConfigError, one line) one over the
    limits unless yes."""
    over = []
    if size.memory_bytes > memory_limit():
        over.append(f"about {size.memory_bytes / 2**30:,.0f} GiB to keep in memory, more than half of this machine's")
    if size.cpu_seconds > LIMIT_CPU_SECONDS:
        over.append(f"more than {duration(LIMIT_CPU_SECONDS)} of CPU time")
    if over and not yes:
        raise ConfigError(f"{size.describe(cpus)}; that is {' and '.join(over)}: give --yes to run it anyway")
    if over or size.cpu_seconds > ANNOUNCE_CPU_SECONDS:
        print(f"farm: {size.describe(cpus)}", file=file or sys.stderr)
