"""`farm eval --fidelity games`: the service's statistics replaced by simulating every engaged
cell's PE game at each step, and how far those outcomes are from the service's.

The evaluation's episodes are stepped together (farm.alloc.evaluation.rollout.play), so a step asks for
the games of every engaged cell of every episode at once. They are played as coarse Ray tasks
of about TASK_SECONDS of work each by the engine's cost model (farm.games.sizes.game_seconds,
plus CALL_SECONDS a game; pack_games), less when a step holds fewer than TASKS_PER_CPU such
tasks a CPU (task_seconds: the step split in TASKS_PER_CPU tasks a CPU, none under
MIN_TASK_SECONDS), at most twice the cluster's CPUs pending (backpressure with ray.wait); in
this process, one after another, for a run whose service.mode is local. Both play the same
games, so they give the same outcomes, game for game. Each engagement of a case plays the
case's next fresh game: game g of the case with the service's seed, g counting up from the service's number of
games, so that these are games the service did not average and any game can be replayed by
run_games."""

from __future__ import annotations

from collections.abc import Iterator

import pandas as pd

from farm.alloc.evaluation.rollout import evaluate_policies
from farm.service.client import CaptureTimeClient
from farm.service.lookup import Lookup
from workers import CaptureStats

__all__ = ["TASK_SECONDS", "MIN_TASK_SECONDS", "TASKS_PER_CPU", "CALL_SECONDS", "FreshGames", "pack_games",
           "task_seconds", "evaluate_fidelity"]

TASK_SECONDS = 0.5  # a live-engagement task's work by the engine's cost model, at most
MIN_TASK_SECONDS = 0.05  # and at least (a task well over Ray's per-task overhead)
TASKS_PER_CPU = 4  # a small step's tasks per CPU: the last task of a step waits on the slowest
# what playing one game as play_outcomes does costs above the engine's cost model (its rows and
# statistics in pandas), as measured (docs/results.md, "Measurements behind the code's constants")
CALL_SECONDS = 2.5e-3


def task_seconds(total: float, cpus: int) -> float:
    """The work of one task for a step of `total` seconds of games on `cpus` CPUs: TASK_SECONDS,
    or less when the step holds less than TASKS_PER_CPU such tasks a CPU, so that every CPU
    gets some and the step's end waits on a short task (the step split in TASKS_PER_CPU cpus
    tasks), never below MIN_TASK_SECONDS."""
    return min(TASK_SECONDS, max(MIN_TASK_SECONDS, total / (TASKS_PER_CPU * cpus)))


def pack_games(costs: list[float], target: float = TASK_SECONDS) -> list[list[int]]:
    """The games (their costs, seconds each) cut into consecutive tasks of about target seconds:
    a task closes once its games reach target; returns each task's game indices, in order."""
    tasks, current, total = [], [], 0.0
    for k, cost in enumerate(costs):
        current.append(k)
        total += cost
        if total >= target:
            tasks.append(current)
            current, total = [], 0.0
    if current:
        tasks.append(current)
    return tasks


class FreshGames(Lookup):
    """The games-fidelity backend: the lookup's core without a store, each ask computed as
    the case's next fresh game (see the module doc), a step's games as coarse Ray tasks;
    each answer is recorded beside the service's for the same cell (`differences`).

    service_client: the CaptureTimeClient of the service being checked; first_game: the
    number of a case's first fresh game (default: the service's games per case);
    in_process: play the games here (the same games: play_shard), not as Ray tasks;
    progress: called with this FreshGames once each ask's games (one ask a step) are played, or None.
    """

    repeatable = False  # every ask is another game

    def __init__(self, service_client, first_game: int | None = None, in_process: bool = False, progress=None):
        self.service = service_client
        self.progress = progress
        self.in_process = in_process
        self.first_game = service_client.settings.games if first_game is None else first_game
        self.played: dict[str, int] = {}  # case key -> games played so far
        self.differences: list[dict] = []
        self.games = 0  # games played
        self.tasks = 0  # Ray tasks they were played in
        self.seconds = 0.0  # wall seconds spent playing them
        self._cpus: int | None = None
        super().__init__(None, self._play)

    def _play(self, keys: list) -> Iterator[tuple[int, CaptureStats]]:
        numbers = []
        for key in keys:
            digest = key.digest()
            numbers.append(self.first_game + self.played.get(digest, 0))
            self.played[digest] = self.played.get(digest, 0) + 1
        outcomes = self._games(keys, numbers)
        expected = self.service.get_many([key.sizes for key in keys])
        for k, (key, g, v) in enumerate(zip(keys, numbers, expected)):
            stats, capture_times = outcomes[k]
            self.differences.append({
                "n_pursuers": key.sizes[0], "n_evaders": key.sizes[1], "game": g,
                "game_frac_tau": stats.frac_captured_tau, "service_frac_tau": v.frac_captured_tau,
                "game_mean_capture": stats.mean_capture.mean, "service_mean_capture": v.mean_capture.mean,
                "capture_times": capture_times[0].tolist(),
            })
            yield k, stats

    def _games(self, keys: list, numbers: list[int]) -> dict[int, tuple]:
        """Game numbers[k] of keys[k]'s case for every k (farm.games.shards.play_outcomes: its
        CaptureStats and capture times), here or as coarse Ray tasks (the module doc)."""
        import time

        from farm.games.shards import play_outcomes

        t0 = time.perf_counter()
        jobs = [(key.case, key.seed, g, g + 1) for key, g in zip(keys, numbers)]
        if self.in_process:
            outcomes = {k: play_outcomes(*job) for k, job in enumerate(jobs)}
        else:
            outcomes = self._on_ray(jobs)
        self.games += len(jobs)
        self.seconds += time.perf_counter() - t0
        if self.progress is not None:
            self.progress(self)
        return outcomes

    def _on_ray(self, jobs: list) -> dict[int, tuple]:
        import ray

        from farm.games.sizes import game_seconds
        from farm.games.tasks import _remote_games
        from farm.runtime import bounded

        if self._cpus is None:  # the cluster's CPUs, asked once, not at every step
            self._cpus = max(1, int(ray.cluster_resources().get("CPU", 1)))
        cpus = self._cpus
        costs = [game_seconds(case) + CALL_SECONDS for case, *_ in jobs]
        tasks = pack_games(costs, task_seconds(sum(costs), cpus))
        self.tasks += len(tasks)
        limit = 2 * cpus
        rows = {}
        for task, ref in bounded(lambda t: _remote_games.remote([jobs[k] for k in t]), tasks, limit):
            rows.update(zip(task, ray.get(ref)))
        return rows

    def live(self) -> dict:
        """What playing the games took: games, tasks (0 in process), seconds and games/s."""
        return {"games": self.games, "tasks": self.tasks, "seconds": self.seconds,
                "games_per_second": self.games / self.seconds if self.seconds > 0 else float("nan")}

    def warm(self, keys, progress=None) -> None:
        """Nothing to fill: every ask is a fresh game."""


def evaluate_fidelity(config, policies: dict, client, episodes: int, seed: int,
                      in_process: bool = False, show_progress: bool = True) -> tuple[pd.DataFrame, pd.DataFrame, dict]:
    """`farm eval --fidelity games`: every policy on the same seeded episodes with each engaged
    cell's game simulated (each policy meets the same fresh games; in_process: played here,
    else as Ray tasks); returns (the evaluation table, one row per engagement: the game's and
    the service's outcomes, FreshGames.live() summed over the policies). show_progress: a bar
    on stderr over the policies' steps (max_steps each, the episodes stepped together; the ETA
    an upper bound, since episodes may end sooner) with the games played and their games/s."""
    from farm.core.progress import GameProgress

    tables, differences = [], []
    live = {"games": 0, "tasks": 0, "seconds": 0.0}
    bar = GameProgress(len(policies) * config.max_steps, enabled=show_progress, desc="live engagements", unit="step")

    def played(games: FreshGames) -> None:
        bar.update(1)
        done, seconds = live["games"] + games.games, live["seconds"] + games.seconds
        bar.postfix(games=f"{done:,}", games_per_s=f"{done / seconds:.0f}" if seconds > 0 else "-")

    try:
        for k, (name, policy) in enumerate(policies.items()):
            games = FreshGames(client, in_process=in_process, progress=played)
            games_client = CaptureTimeClient(client.settings, backend=games)
            tables.append(evaluate_policies(config, {name: policy}, games_client, episodes, seed)[0])
            differences += [{"policy": name, **d} for d in games.differences]
            for key in live:
                live[key] += games.live()[key]
            bar.advance_to((k + 1) * config.max_steps)  # the steps of episodes that ended early
    finally:
        bar.close()
    live["games_per_second"] = live["games"] / live["seconds"] if live["seconds"] > 0 else float("nan")
    return pd.concat(tables, ignore_index=True), pd.DataFrame(differences), live
