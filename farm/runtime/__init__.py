"""How farm runs on Ray: starting or joining a cluster and submitting many tasks
(cluster.py), and the farm's own Ray metrics (metrics.py). Importing it imports no Ray."""

from farm.runtime.cluster import (DEFAULT_LOCAL_CPUS, LOOPBACK_ENV, NAMESPACE, bounded, check_reachable, check_workers,
                                  connected, joins_cluster, ray_cluster, starts_local_ray, task_result,
                                  tasks_in_flight)

__all__ = ["NAMESPACE", "DEFAULT_LOCAL_CPUS", "LOOPBACK_ENV", "ray_cluster", "connected", "check_reachable", "bounded",
           "joins_cluster", "starts_local_ray", "tasks_in_flight", "check_workers", "task_result"]
