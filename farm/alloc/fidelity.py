"""`farm eval --fidelity games`: the service's statistics replaced by simulating every engaged
cell's PE game at each step (all cells' games of a step in parallel as Ray tasks; in this
process, one after another, for a run whose service.mode is local), and how far those
outcomes are from the service's. Each engagement of a case plays the case's next fresh game:
game g of the case with the service's seed, g counting up from the service's number of
games, so that these are games the service did not average and any game can be replayed by
run_games."""

from __future__ import annotations

from typing import Iterator

import pandas as pd

from workers import CaptureStats

from farm.alloc.rollout import evaluate_policies
from farm.service.client import CaptureTimeClient
from farm.service.lookup import Lookup

__all__ = ["FreshGames", "evaluate_fidelity"]


class FreshGames(Lookup):
    """The games-fidelity backend: the lookup's core without a store, each ask computed as
    the case's next fresh game (see the module doc), a step's games in parallel as Ray
    tasks; each answer is recorded beside the service's for the same cell (`differences`).

    service_client: the CaptureTimeClient of the service being checked; first_game: the
    number of a case's first fresh game (default: the service's games per case);
    in_process: play the games here (the same games: play_shard), not as Ray tasks.
    """

    repeatable = False  # every ask is another game

    def __init__(self, service_client, first_game: int | None = None, in_process: bool = False):
        self.service = service_client
        self.in_process = in_process
        self.first_game = service_client.settings.games if first_game is None else first_game
        self.played: dict[str, int] = {}  # case key -> games played so far
        self.differences: list[dict] = []
        super().__init__(None, self._play)

    def _play(self, keys: list) -> Iterator[tuple[int, CaptureStats]]:
        numbers = []
        for key in keys:
            digest = key.digest()
            numbers.append(self.first_game + self.played.get(digest, 0))
            self.played[digest] = self.played.get(digest, 0) + 1
        rows = self._games(keys, numbers)
        expected = self.service.get_many([key.sizes for key in keys])
        for k, (key, g, v) in enumerate(zip(keys, numbers, expected)):
            stats = CaptureStats.from_games(rows[k])
            self.differences.append({
                "n_pursuers": key.sizes[0], "n_evaders": key.sizes[1], "game": g,
                "game_frac_tau": stats.frac_captured_tau, "service_frac_tau": v.frac_captured_tau,
                "game_mean_capture": stats.mean_capture.mean, "service_mean_capture": v.mean_capture.mean,
                "capture_times": rows[k]["capture_times"].iloc[0].tolist(),
            })
            yield k, stats

    def _games(self, keys: list, numbers: list[int]) -> dict[int, pd.DataFrame]:
        """Game numbers[k] of keys[k]'s case for every k (play_shard's rows), here or as Ray tasks."""
        from farm.games.shards import play_shard

        jobs = list(range(len(keys)))
        if self.in_process:
            return {k: play_shard(keys[k].case, keys[k].seed, numbers[k], numbers[k] + 1, detail=True) for k in jobs}
        import ray

        from farm.runtime import bounded
        from farm.games.tasks import _remote_shard

        def submit(k):
            return _remote_shard.remote(keys[k].case, keys[k].seed, numbers[k], numbers[k] + 1, True)

        return {k: ray.get(ref)[0] for k, ref in bounded(submit, jobs, max(1, len(jobs)))}  # a step's cells at once

    def warm(self, keys, progress=None) -> None:
        """Nothing to fill: every ask is a fresh game."""


def evaluate_fidelity(config, policies: dict, client, episodes: int, seed: int,
                      in_process: bool = False) -> tuple[pd.DataFrame, pd.DataFrame]:
    """`farm eval --fidelity games`: every policy on the same seeded episodes with each engaged
    cell's game simulated (each policy meets the same fresh games; in_process: played here,
    else as Ray tasks); returns (the evaluation table, one row per engagement: the game's and
    the service's outcomes)."""
    tables, differences = [], []
    for name, policy in policies.items():
        games = FreshGames(client, in_process=in_process)
        games_client = CaptureTimeClient(client.settings, backend=games)
        tables.append(evaluate_policies(config, {name: policy}, games_client, episodes, seed)[0])
        differences += [{"policy": name, **d} for d in games.differences]
    return pd.concat(tables, ignore_index=True), pd.DataFrame(differences)
