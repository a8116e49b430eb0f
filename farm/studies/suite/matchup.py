"""One (scenario, allocator) of the suite: its episodes through the one rollout loop
(farm.alloc.evaluation.rollout.play), as episodes.csv's rows."""

from __future__ import annotations

from farm.alloc.allocators import Spec
from farm.alloc.evaluation.rollout import play
from farm.alloc.game.config import AllocConfig

__all__ = ["evaluate_matchup"]


def evaluate_matchup(config: AllocConfig, spec: Spec, client, episodes: int, seed: int) -> list[dict]:
    """The allocator of spec on episodes seeded seed .. seed + episodes - 1 of the scenario's env
    settings config, its engagements answered by client (a CaptureTimeClient); one dict per
    episode: episode, seed, the episode's measures (farm.alloc.evaluation.rollout.Episode.summary), steps
    and predict_seconds (wall seconds in the allocator's predict(), summed over the episode's
    steps), and intruders_start (the right-most column's intruder densities it first
    observed, rows top to bottom, as text)."""
    n = config.grid_size
    rows = []
    for k, e in enumerate(play(config, spec.make(config, client), client, episodes, seed)):
        start = e.first_obs[n * n:].reshape(n, n)[:, -1]
        rows.append({"episode": k, "seed": seed + k, **e.summary, "steps": e.length,
                     "predict_seconds": e.predict_seconds,
                     "intruders_start": " ".join(repr(float(x)) for x in start)})
    return rows
