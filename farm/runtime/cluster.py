"""The one way swarm-farm starts or joins Ray, and the one way it submits many tasks.

ray_cluster(): join a cluster (an address, or $RAY_ADDRESS) or start a real single-node Ray
of its own, quiet and safe (loopback only, token authentication: its docstring says how).

bounded(): submit tasks with at most a given number pending (ray.wait backpressure),
shared by sweeps, the capture-time service and the games-fidelity evaluation; task_result():
a task's value, or the project error it raised in one line, not Ray's wrapper.

The rules every command shares: joins_cluster / starts_local_ray (whether a command given an
address, or none, joins a cluster or starts its own Ray), tasks_in_flight (how many tasks a
command keeps pending) and check_workers (the one check of a `workers` count).
"""

from __future__ import annotations

import ipaddress
import logging
import os
import socket
import sys
import threading
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from typing import Any
from urllib.parse import urlsplit

from farm.core.checks import is_whole, whole
from farm.core.errors import ClusterError, ConfigError, SwarmFarmError

__all__ = ["NAMESPACE", "DEFAULT_LOCAL_CPUS", "LOOPBACK_ENV", "ray_cluster", "connected", "check_reachable", "bounded",
           "joins_cluster", "starts_local_ray", "tasks_in_flight", "check_workers"]

NAMESPACE = "swarm-farm"
DEFAULT_LOCAL_CPUS = 2
LOOPBACK_ENV = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"  # "0": a single-machine Ray, bound to 127.0.0.1
_AUTH_LOGGER = "ray._private.authentication.authentication_token_setup"  # Ray's "token auth is enabled" warning


def _host_port(address: str) -> tuple[str | None, int | None]:
    """(host, port) of 'host:port', 'ray://host:port', '[::1]:6379'; (None, None) when it has no port."""
    try:
        parts = urlsplit("//" + address.split("://", 1)[-1])
        return parts.hostname, parts.port
    except ValueError:
        return None, None


def check_reachable(address: str, timeout: float = 5.0) -> None:
    """Fail at once, in one line, when an address is not host:port, ray://host:port or "auto",
    or when nothing answers there (Ray itself retries for minutes); "auto" is left to Ray."""
    if address == "auto":
        return
    host, port = _host_port(address)
    if not host or port is None:
        raise ClusterError(f"address {address}: expected host:port (e.g. 127.0.0.1:6379), ray://host:port "
                           "or auto")
    try:
        socket.create_connection((host, port), timeout=timeout).close()
    except OSError as e:
        why = e.strerror or type(e).__name__
        raise ClusterError(f"address {address}: no Ray cluster answers there ({why}); "
                           "start one with `ray start --head` or leave the address out for a local Ray") from None


def _ips(host: str) -> set[str]:
    """The IP addresses a host name resolves to ({host} itself when it does not resolve)."""
    try:
        return {i[4][0] for i in socket.getaddrinfo(host, None)}
    except OSError:
        return {host}


def _on_this_machine(ip: str) -> bool:
    """Whether ip is one of this machine's own addresses: a loopback one, or one a socket binds to."""
    try:
        address = ipaddress.ip_address(ip.split("%", 1)[0])
    except ValueError:
        return False
    if address.is_loopback:
        return True
    family = socket.AF_INET6 if address.version == 6 else socket.AF_INET
    try:
        with socket.socket(family, socket.SOCK_DGRAM) as s:
            s.bind((ip, 0))
        return True
    except OSError:
        return False


def _same_host(a: str, b: str) -> bool:
    """Whether two host names are one machine: they share an address, or both are this machine's
    (127.0.0.1 and the address a Ray head on this machine advertises)."""
    ips_a, ips_b = _ips(a), _ips(b)
    if ips_a & ips_b:
        return True
    return any(map(_on_this_machine, ips_a)) and any(map(_on_this_machine, ips_b))


def _check_running(ray, address: str | None, num_cpus: int | None, metrics_port: int | None) -> None:
    """ClusterError (one line) when the Ray this process is connected to is not the one asked for."""
    if address and address != "auto" and not address.startswith("ray://"):
        running = ray.get_runtime_context().gcs_address
        (host, port), (r_host, r_port) = _host_port(address), _host_port(running)
        if port is not None and (port != r_port or not _same_host(host, r_host)):
            raise ClusterError(f"address {address}: this process is already connected to the Ray cluster at "
                               f"{running}")
    if num_cpus is not None:
        cpus = int(ray.cluster_resources().get("CPU", 0))
        if cpus != num_cpus:
            raise ClusterError(f"num_cpus: {num_cpus} asked for, but the Ray this process is connected to has "
                               f"{cpus} CPUs", field="num_cpus")
    if metrics_port is not None:
        ports = {n.get("MetricsExportPort") for n in ray.nodes() if n.get("Alive")}
        if metrics_port not in ports:
            raise ClusterError(f"metrics_port: {metrics_port} asked for, but the Ray this process is connected to "
                               f"exports its metrics on {', '.join(str(p) for p in sorted(ports, key=str))}",
                               field="metrics_port")


def connected() -> bool:
    """Whether this process is connected to Ray already (ray_cluster then uses that Ray).

    Never imports Ray: a process that has not imported it is not connected, and importing it
    here would come before ray_cluster sets the loopback switch (LOOPBACK_ENV)."""
    ray = sys.modules.get("ray")
    return ray is not None and ray.is_initialized()


def joins_cluster(address: str | None) -> bool:
    """Whether a command given this address (None: none) joins a cluster: an address, or $RAY_ADDRESS."""
    return bool(address or os.environ.get("RAY_ADDRESS"))


def starts_local_ray(address: str | None) -> bool:
    """Whether ray_cluster(address) starts a local Ray (so that a CPU count is its to choose):
    no cluster to join, and this process not connected to Ray already."""
    return not joins_cluster(address) and not connected()


def tasks_in_flight(workers: int | None, cpus: int, address: str | None) -> int:
    """How many tasks a command keeps pending on a Ray of `cpus` CPUs: `workers` (default: the
    CPUs), at most the CPUs of a local Ray; on a cluster joined, as many as asked (it may grow)."""
    if joins_cluster(address):
        return max(1, workers or cpus)
    return max(1, min(workers or cpus, cpus))


def check_workers(workers, field: str = "workers") -> None:
    """ConfigError (one line naming field) unless workers is None or a whole number >= 1."""
    if workers is not None:
        whole(field, workers, 1)


@contextmanager
def ray_cluster(address: str | None = None, *, num_cpus: int | None = None, metrics_port: int | None = None,
                dashboard: bool = True):
    """Be connected to Ray for the duration of the block; shut down only what was started here.

    address: a cluster to join ("auto", "host:port", "ray://..."); None falls back to
    $RAY_ADDRESS, and without it a local single-node Ray is started (below)
    with num_cpus CPUs (default 2), its Prometheus metrics on metrics_port (default: Ray's
    choice) and, with dashboard, its dashboard on 127.0.0.1. When this process is already
    connected to Ray, that Ray is used, and asking for an address, a CPU count or a metrics
    port it does not have is a ClusterError; a metrics port outside 1-65535 is a ConfigError,
    before Ray starts. Yields the `ray` module.

    The local Ray is a real single-node Ray on this machine, its own: never one it finds on
    the machine (a `ray start` cluster, or the pointer file a killed one left behind). It is
    quiet and safe:
    - loopback only: Ray's servers listen on every interface and advertise the machine's
      address, whatever ray.init is given (it turns 127.0.0.1 into the machine's address on
      purpose). Its one switch for a single-machine Ray is the environment variable
      RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0 (named for the systems where it is the default),
      read when Ray is imported: every Ray process then binds 127.0.0.1. ray_cluster sets it
      when it starts a local Ray in a process that has not imported Ray yet (the `farm`
      commands; the test suite sets it before importing Ray). A process that imported Ray
      before gets Ray's default binding.
    - token authentication on, as Ray 2.60 chooses for a new local cluster (unless
      RAY_AUTH_MODE says otherwise), without Ray's warning that it chose it (that one Ray
      logger's level is raised while Ray starts).
    A cluster you join keeps its own settings and Ray's own behaviour. The metrics port has no
    public ray.init argument, only the private `_metrics_export_port` (the public way is
    `ray start --metrics-export-port`, a separate process); it is used here and nowhere else.
    """
    if metrics_port is not None and not (is_whole(metrics_port, numpy=False) and 1 <= metrics_port <= 65535):
        raise ConfigError(f"metrics_port: must be a TCP port from 1 to 65535, got {metrics_port!r}",
                          field="metrics_port")
    address = address or os.environ.get("RAY_ADDRESS") or None
    if not address and "ray" not in sys.modules:
        os.environ.setdefault(LOOPBACK_ENV, "0")  # read by Ray at import, and by every process it starts
    import ray

    if ray.is_initialized():
        _check_running(ray, address, num_cpus, metrics_port)
        yield ray
        return
    if address:
        check_reachable(address)
        ray.init(address=address, namespace=NAMESPACE, logging_level=logging.WARNING, log_to_driver=False)
    else:
        kwargs = {"_metrics_export_port": metrics_port} if metrics_port else {}
        auth_log = logging.getLogger(_AUTH_LOGGER)
        level = auth_log.level
        auth_log.setLevel(logging.ERROR)
        try:
            # "local": a Ray of its own, even beside a `ray start` cluster or its stale pointer file
            # (/tmp/ray/ray_current_cluster), which ray.init() without an address would join.
            ray.init(address="local", num_cpus=num_cpus or DEFAULT_LOCAL_CPUS, namespace=NAMESPACE,
                     include_dashboard=dashboard,
                     dashboard_host="127.0.0.1", logging_level=logging.WARNING, log_to_driver=False, **kwargs)
        finally:
            auth_log.setLevel(level)
    try:
        yield ray
    finally:
        ray.shutdown()


def bounded(submit: Callable[[Any], Any], items: Iterable, max_in_flight: int, *,
            slots: threading.Semaphore | None = None) -> Iterator[tuple[Any, Any]]:
    """Submit submit(item) (a Ray ObjectRef) for each item, with at most max_in_flight
    pending at once, waiting with ray.wait; yields (item, ref) of each finished task, in the
    order they finish (ray.get(ref) then returns at once, or raises the task's error).

    slots: a semaphore shared by several threads submitting at once (the capture-time
    service), so that all of them together keep at most its count pending; each thread
    then waits for its own tasks before asking for more slots.
    """
    import ray

    queue = deque(items)
    in_flight: dict = {}
    held = 0
    try:
        while queue or in_flight:
            while queue and len(in_flight) < max_in_flight:
                if slots is not None:
                    if not slots.acquire(blocking=not in_flight):  # free own slots first, never deadlock
                        break
                    held += 1
                item = queue.popleft()
                in_flight[submit(item)] = item
            ready, _ = ray.wait(list(in_flight), num_returns=1)
            for ref in ready:
                item = in_flight.pop(ref)
                if slots is not None:
                    slots.release()
                    held -= 1
                yield item, ref
    finally:
        for _ in range(held):
            slots.release()


def task_result(ref, where: str) -> Any:
    """ray.get(ref); a project error (SwarmFarmError) the task raised comes back as that error,
    its one line prefixed with `where: ` (not Ray's wrapper with the worker's traceback)."""
    import ray

    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as e:
        cause = getattr(e, "cause", None)
        if not isinstance(cause, SwarmFarmError):
            raise
        try:
            error = type(cause)(f"{where}: {cause}")
        except Exception:  # an error class that is not made from one message
            error = cause
        raise error from None
