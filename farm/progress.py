"""Progress of long work on stderr: games done, games/s and ETA."""

from __future__ import annotations

import sys


class GameProgress:
    def __init__(self, total: int, done: int = 0, *, enabled: bool = True, desc: str = "games", unit: str = "game"):
        self.bar = None
        if enabled:
            from tqdm import tqdm

            self.bar = tqdm(total=total, initial=done, unit=unit, desc=desc, file=sys.stderr,
                            smoothing=0.1, dynamic_ncols=True, mininterval=0.5)

    def update(self, n: int) -> None:
        if self.bar is not None:
            self.bar.update(n)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
