"""Pretraining's Ray task: a batch of labelled episodes (play_labelled on a worker). Imports Ray:
imported only by farm.alloc.training.dagger.loop.label_all once Ray is up."""

from __future__ import annotations

import ray

from farm.games.tasks import MAX_RETRIES

__all__ = ["remote_label"]


@ray.remote(num_cpus=1, max_retries=MAX_RETRIES, retry_exceptions=False)
def remote_label(config, spec, learner, share: float, seeds: list[int], coin_key, service, gamma: float) -> dict:
    """play_labelled on a worker, the expert (spec, a Spec) and the engagements answered by
    the shared capture-time service actor `service` (a handle); learner: the learner's SB3
    policy or None. One torch thread: the task is one CPU's."""
    import torch

    from farm.alloc.training.dagger.labels import play_labelled
    from farm.service.client import CaptureTimeClient

    torch.set_num_threads(1)
    client = CaptureTimeClient(config.game_settings(), service=service)
    return play_labelled(config, spec.make(config, client), learner, share, seeds, coin_key, client, gamma)
