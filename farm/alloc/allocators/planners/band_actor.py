"""The Ray actor that plans sub-regions' bands (farm.alloc.allocators.planners.subregions):
defined once, at import; imported only by code that runs on Ray."""

from __future__ import annotations

import ray

__all__ = ["BandPlanner"]


@ray.remote(num_cpus=1, max_restarts=3, max_task_retries=3)
class BandPlanner:
    """An inner planner and its capture-time client, kept between calls (its statistics memo
    with them). A restarted actor builds them again: the planners are deterministic."""

    def __init__(self, config, planner: str, options: dict, settings, service=None, store: str | None = None):
        """config: AllocConfig; planner, options: the inner planner; settings: GameSettings;
        service: the capture-time service actor, or store: a local store's path."""
        from farm.alloc.game.registry import ALLOCATORS
        from farm.service import CaptureTimeClient

        if service is not None:
            client = CaptureTimeClient(settings, service=service)
        else:
            client = CaptureTimeClient(settings, local_store=store)
        self.policy = ALLOCATORS.make(planner, config, client, **options)

    def probabilities(self, D, I):
        """The inner planner's move probabilities: D, I: (N^2,) float64 -> (A,) float64."""
        return self.policy.probabilities(D, I)
