"""One way to get a Ray cluster: join one (--address / RAY_ADDRESS) or start a real
single-node Ray on this machine (2 CPUs by default, dashboard on loopback)."""

from __future__ import annotations

import logging
import os
import socket
from contextlib import contextmanager
from urllib.parse import urlsplit

NAMESPACE = "swarm-farm"
DEFAULT_LOCAL_CPUS = 2


def check_reachable(address: str, timeout: float = 5.0) -> None:
    """Fail at once, in one line, when nothing answers at a host:port address (Ray
    itself retries for minutes); "auto" and addresses without a port are left to Ray."""
    from farm.errors import ClusterError

    try:
        parts = urlsplit("//" + address.split("://", 1)[-1])
        host, port = parts.hostname, parts.port  # [::1]:6379 -> ::1, 6379
    except ValueError:
        return
    if not host or port is None:
        return
    try:
        socket.create_connection((host, port), timeout=timeout).close()
    except OSError as e:
        why = e.strerror or type(e).__name__
        raise ClusterError(f"address {address}: no Ray cluster answers there ({why}); "
                          "start one with `ray start --head` or leave the address out for a local Ray") from None


@contextmanager
def ray_cluster(address: str | None = None, *, num_cpus: int | None = None, metrics_port: int | None = None,
                dashboard: bool = True):
    """Connect to Ray for the duration of the block; shut down only what we started.

    address: a cluster to join ("auto", "host:port", "ray://..."); None falls back
    to RAY_ADDRESS, and without it a local single-node Ray is started with
    num_cpus CPUs (default 2) and its dashboard bound to 127.0.0.1.
    """
    import ray

    address = address or os.environ.get("RAY_ADDRESS") or None
    if ray.is_initialized():
        yield ray
        return
    if address:
        check_reachable(address)
        ray.init(address=address, namespace=NAMESPACE, logging_level=logging.WARNING,
                 log_to_driver=False)
    else:
        kwargs = {}
        if metrics_port:
            kwargs["_metrics_export_port"] = metrics_port
        ray.init(
            num_cpus=num_cpus or DEFAULT_LOCAL_CPUS,
            namespace=NAMESPACE,
            include_dashboard=dashboard,
            dashboard_host="127.0.0.1",
            _node_ip_address="127.0.0.1",
            logging_level=logging.WARNING,
            log_to_driver=False,
            **kwargs,
        )
    try:
        yield ray
    finally:
        ray.shutdown()
