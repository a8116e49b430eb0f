"""Custom Ray metrics of the farm, exported through Ray's Prometheus endpoint.

Ray prefixes every name with `ray_`, and exports a Counter as `<name>_total`;
EXPORTED lists the names as Prometheus sees them (the Grafana dashboard in
dashboards/ queries exactly these).
"""

from __future__ import annotations

from functools import cache

TAGS = ("sweep",)

EXPORTED = {
    "ray_swarm_farm_games_simulated_total": "games simulated (counter)",
    "ray_swarm_farm_game_steps_total": "game-steps simulated, summed over games (counter)",
    "ray_swarm_farm_game_steps_per_second": "game-steps per second of the last shard of a worker (gauge)",
    "ray_swarm_farm_shards_done_total": "shards stored (counter)",
    "ray_swarm_farm_pending_shards": "shards queued or running (gauge)",
    "ray_swarm_farm_service_hits_total": "capture-time service: keys answered from the cache (counter)",
    "ray_swarm_farm_service_misses_total": "capture-time service: keys not in the cache (counter)",
    "ray_swarm_farm_service_computations_total": "capture-time service: cases computed on the farm (counter)",
    "ray_swarm_farm_service_compute_seconds_total": "capture-time service: seconds spent computing cases (counter)",
    "ray_swarm_farm_service_inflight": "capture-time service: cases being computed now (gauge)",
}


def _ray_ready() -> bool:
    try:
        import ray
    except ImportError:  # pragma: no cover
        return False
    return ray.is_initialized()


@cache
def _worker_metrics():
    from ray.util.metrics import Counter, Gauge

    return (
        Counter("swarm_farm_games_simulated", description=EXPORTED["ray_swarm_farm_games_simulated_total"],
                tag_keys=TAGS),
        Counter("swarm_farm_game_steps", description=EXPORTED["ray_swarm_farm_game_steps_total"], tag_keys=TAGS),
        Gauge("swarm_farm_game_steps_per_second", description=EXPORTED["ray_swarm_farm_game_steps_per_second"],
              tag_keys=TAGS),
    )


def record_shard(sweep: str, games: int, steps: int, seconds: float) -> None:
    """Count one simulated shard on the worker: games, game-steps and the steps' rate.

    sweep: the sweep's tag; games and steps: simulated in the shard (steps summed over
    its games); seconds: its wall time. Does nothing outside a Ray worker or driver.
    """
    if not _ray_ready():
        return
    games_c, steps_c, rate = _worker_metrics()
    tags = {"sweep": sweep}
    games_c.inc(games, tags=tags)
    if steps:
        steps_c.inc(steps, tags=tags)
    rate.set(steps / max(seconds, 1e-9), tags=tags)


class DriverMetrics:
    """Driver side: shards done and pending of one sweep, tagged with the sweep's name.

    Ray's own `ray_tasks{IsRetry!="0"}` counts the shard attempts it retried after a
    worker or node died. Made inside a Ray driver (ray.init called).
    """

    def __init__(self, sweep: str):
        from ray.util.metrics import Counter, Gauge

        self.tags = {"sweep": sweep}
        self._done = Counter("swarm_farm_shards_done", description=EXPORTED["ray_swarm_farm_shards_done_total"],
                             tag_keys=TAGS)
        self._pending = Gauge("swarm_farm_pending_shards", description=EXPORTED["ray_swarm_farm_pending_shards"],
                              tag_keys=TAGS)

    def done(self) -> None:
        """Count one shard stored."""
        self._done.inc(1, tags=self.tags)

    def pending(self, n: int) -> None:
        """Set the number of shards queued or running."""
        self._pending.set(n, tags=self.tags)


class ServiceMetrics:
    """The capture-time service's counters: hits, misses, computations, compute seconds, in-flight.

    Made inside the service's Ray actor; the names it exports are EXPORTED's.
    """

    def __init__(self):
        from ray.util.metrics import Counter, Gauge

        d = EXPORTED
        self._hits = Counter("swarm_farm_service_hits", description=d["ray_swarm_farm_service_hits_total"])
        self._misses = Counter("swarm_farm_service_misses", description=d["ray_swarm_farm_service_misses_total"])
        self._computations = Counter("swarm_farm_service_computations",
                                     description=d["ray_swarm_farm_service_computations_total"])
        self._seconds = Counter("swarm_farm_service_compute_seconds",
                                description=d["ray_swarm_farm_service_compute_seconds_total"])
        self._inflight = Gauge("swarm_farm_service_inflight", description=d["ray_swarm_farm_service_inflight"])

    def hit(self) -> None:
        """Count one key answered from the cache."""
        self._hits.inc(1)

    def miss(self) -> None:
        """Count one key not in the cache."""
        self._misses.inc(1)

    def computed(self, seconds: float) -> None:
        """Count one case computed on the farm and the seconds it took (if any)."""
        self._computations.inc(1)
        if seconds > 0:
            self._seconds.inc(seconds)

    def inflight(self, n: int) -> None:
        """Set the number of cases being computed now."""
        self._inflight.set(n)
