"""Progress of long work on stderr: games done, games/s and ETA."""

from __future__ import annotations

import sys


class GameProgress:
    """A progress bar on stderr (tqdm) of games done, their rate and the ETA; silent when disabled.

    total: the games (or other units) to do; done: already done, e.g. stored by an
    earlier run; enabled: False makes every method a no-op; desc, unit: the bar's label
    and unit.
    """

    def __init__(self, total: int, done: int = 0, *, enabled: bool = True, desc: str = "games", unit: str = "game"):
        self.bar = None
        if enabled:
            from tqdm import tqdm

            self.bar = tqdm(total=total, initial=done, unit=unit, desc=desc, file=sys.stderr,
                            smoothing=0.1, dynamic_ncols=True, mininterval=0.5)

    def update(self, n: int) -> None:
        """Advance the bar by n units done."""
        if self.bar is not None:
            self.bar.update(n)

    def postfix(self, **values) -> None:
        """Show these name=value pairs after the bar (tqdm's postfix)."""
        if self.bar is not None:
            self.bar.set_postfix(values, refresh=False)

    def advance_to(self, n: int) -> None:
        """Advance the bar to n units done (never back)."""
        if self.bar is not None and n > self.bar.n:
            self.bar.update(n - self.bar.n)

    def close(self) -> None:
        """Close the bar (its last line stays on stderr)."""
        if self.bar is not None:
            self.bar.close()
