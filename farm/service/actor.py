"""The capture-time service deployed as a named Ray actor: ServiceLookup
(farm/service/lookup.py, where the whole lookup reads) run by Ray, one per store.

The actor is threaded: each ask runs in one of MAX_CONCURRENT_ASKS threads, and concurrent
asks for one missing key compute it once. It is kept on the head node, where its store lives.

A store the actor could not open (a folder, read-only, damaged) is refused in the driver
before the actor is made, when the driver runs on that node (check_store); otherwise the
actor's death carries the project error, and get_service raises that error's one line,
not Ray's wrapper (project_error_of).
"""

from __future__ import annotations

import importlib
import re
import time
from contextlib import contextmanager
from pathlib import Path

import ray

from farm.core.errors import ConfigError, SwarmFarmError
from farm.runtime import NAMESPACE
from farm.service.lookup import ServiceLookup
from farm.service.store import check_store

__all__ = ["SERVICE_NAME", "CaptureTimeService", "get_service", "project_error_of", "service_of"]

SERVICE_NAME = "capture-time-service"
MAX_CONCURRENT_ASKS = 64

CaptureTimeService = ray.remote(num_cpus=0, max_restarts=3)(ServiceLookup)

# The last line of a Python traceback: "package.module.ErrorClass: message".
_RAISED = re.compile(r"((?:farm|workers)(?:\.\w+)*)\.([A-Za-z_]\w*): (.+)")


def project_error_of(error: BaseException) -> SwarmFarmError | None:
    """The project error (a SwarmFarmError of farm or workers) that made an actor die in its
    __init__, rebuilt from Ray's actor-died error; None for any other error or cause.

    Ray 2.60's ActorDiedError keeps no exception object of a failed creation task: only
    `actor_init_failed` and `error_msg`, the creation task's traceback as text, whose last
    line names the error's class and its (one-line) message."""
    if not isinstance(error, ray.exceptions.RayActorError) or not error.actor_init_failed:
        return None
    lines = [line for line in str(error.error_msg).splitlines() if line.strip()]
    match = _RAISED.fullmatch(lines[-1].strip()) if lines else None
    if match is None:
        return None
    module, name, message = match.groups()
    try:
        cls = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError):
        return None
    if not (isinstance(cls, type) and issubclass(cls, SwarmFarmError)):
        return None
    try:
        return cls(message)
    except Exception:  # an error class that is not made from one message
        return None


def _driver_sees_the_store() -> bool:
    """Whether this driver runs where the service's store lives (the head node, or the only
    node), so it can check the store's file itself before making the actor."""
    from ray.util.client import ray as client

    if client.is_connected():  # Ray Client: this process is on another machine
        return False
    here = ray.get_runtime_context().get_node_id()
    nodes = [n for n in ray.nodes() if n.get("Alive")]
    heads = [n["NodeID"] for n in nodes if "node:__internal_head__" in n.get("Resources", {})]
    return here in heads if heads else [n["NodeID"] for n in nodes] == [here]


def _running(name: str) -> bool:
    """Whether a service actor of that name runs (it opened its store: no need to check it)."""
    try:
        ray.get_actor(name, namespace=NAMESPACE)
    except ValueError:
        return False
    return True


def get_service(store_path, *, name: str = SERVICE_NAME, max_shards_in_flight: int | None = None):
    """The named service actor of a store, found in the project's namespace or created
    (needs a connected Ray, farm.runtime.ray_cluster). A running actor of that name that
    serves another store is refused (ConfigError naming both files): its values would land
    in a file the caller did not name.

    Before making the actor, a store it could not open is refused in one line, at once
    (farm.service.store.check_store: a folder, read-only, damaged), when this driver runs
    where the store lives; an actor that dies opening its store raises that project error
    (project_error_of), not Ray's wrapper."""
    wanted = str(Path(store_path).resolve())
    if not _running(name) and _driver_sees_the_store():
        check_store(store_path)
    options = dict(name=name, namespace=NAMESPACE, get_if_exists=True, max_concurrency=MAX_CONCURRENT_ASKS)
    if "node:__internal_head__" in ray.cluster_resources():
        options["resources"] = {"node:__internal_head__": 0.001}
    actor = CaptureTimeService.options(**options).remote(wanted, max_shards_in_flight)
    try:
        served = ray.get(actor.store_path.remote())
    except ray.exceptions.RayActorError as e:
        cause = project_error_of(e)
        if cause is None:
            raise
        raise cause from None
    if served != wanted:
        raise ConfigError(f"store: the capture-time service {name!r} running on this cluster serves {served}, "
                          f"not {wanted}; name that store, or stop that service", field="store")
    return actor


STOP_TIMEOUT_S = 60.0


@contextmanager
def service_of(store_path, *, name: str = SERVICE_NAME):
    """get_service for the duration of the block; a service this block made is stopped at its
    end, and its name is free again before the block returns.

    Without this, the actor, a named actor that is not detached, lives until Ray collects its
    last handle: at once, or at the driver's next garbage collection when a handle sits in a
    reference cycle. Until then a later block in the same driver that names another store
    finds the old actor under that name, and get_service refuses it. A service that was
    running before the block (an outer block's) is left running."""
    made = not _running(name)
    actor = get_service(store_path, name=name)
    try:
        yield actor
    finally:
        if made:
            ray.kill(actor, no_restart=True)
            deadline = time.monotonic() + STOP_TIMEOUT_S
            while _running(name) and time.monotonic() < deadline:
                time.sleep(0.05)
