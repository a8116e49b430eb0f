"""The capture-time service deployed as a named Ray actor: ServiceLookup
(farm/service/lookup.py, where the whole lookup reads) run by Ray, one per store.

The actor is threaded: each ask runs in one of MAX_CONCURRENT_ASKS threads, and concurrent
asks for one missing key compute it once. It is kept on the head node, where its store lives.
"""

from __future__ import annotations

from pathlib import Path

import ray

from farm.errors import ConfigError
from farm.runtime import NAMESPACE
from farm.service.lookup import ServiceLookup

__all__ = ["SERVICE_NAME", "CaptureTimeService", "get_service"]

SERVICE_NAME = "capture-time-service"
MAX_CONCURRENT_ASKS = 64

CaptureTimeService = ray.remote(num_cpus=0, max_restarts=3)(ServiceLookup)


def get_service(store_path, *, name: str = SERVICE_NAME, max_shards_in_flight: int | None = None):
    """The named service actor of a store, found in the project's namespace or created
    (needs a connected Ray, farm.runtime.ray_cluster). A running actor of that name that
    serves another store is refused (ConfigError naming both files): its values would land
    in a file the caller did not name."""
    wanted = str(Path(store_path).resolve())
    options = dict(name=name, namespace=NAMESPACE, get_if_exists=True, max_concurrency=MAX_CONCURRENT_ASKS)
    if "node:__internal_head__" in ray.cluster_resources():
        options["resources"] = {"node:__internal_head__": 0.001}
    actor = CaptureTimeService.options(**options).remote(wanted, max_shards_in_flight)
    served = ray.get(actor.store_path.remote())
    if served != wanted:
        raise ConfigError(f"store: the capture-time service {name!r} running on this cluster serves {served}, "
                          f"not {wanted}; name that store, or stop that service")
    return actor
