"""The `subregions` planner (SubRegions): the paper's second route to larger maps, a map cut
into bands of rows, each planned on its own by another planner, in parallel on Ray.
"""

from __future__ import annotations

import numpy as np

from farm.alloc.allocators.planners.core import _count, _Planner
from farm.alloc.game.config import AllocConfig
from farm.core.errors import ConfigError

__all__ = ["SubRegions", "BAND_ROWS", "check_band_actors"]

BAND_ROWS = 8  # the default bands' rows, at most


def _inner_planner(name: str, config: AllocConfig, client, options: dict) -> _Planner:
    from farm.alloc.game.registry import ALLOCATORS

    planners = [p for p in ALLOCATORS.names("planner") if p != "subregions"]
    if name not in planners:
        raise ConfigError(f"subregions: planner must be one of {', '.join(planners)}, got {name!r}")
    try:
        policy = ALLOCATORS.make(name, config, client, **options)
    except ConfigError as e:
        raise ConfigError(f"subregions: options: {e}") from None
    if not callable(getattr(policy, "probabilities", None)):
        raise ConfigError(f"subregions: planner {name!r} gives no move probabilities (not a planners.core planner)")
    return policy


def _cpus_held() -> float:
    """The CPUs Ray assigned to the task or actor this process runs; 0 in a driver (Ray answers
    get_assigned_resources only in a worker)."""
    import ray

    try:
        return float(ray.get_runtime_context().get_assigned_resources().get("CPU", 0.0))
    except AssertionError:
        return 0.0


def check_band_actors(workers: int, regions: int) -> None:
    """ConfigError (one line naming workers) when the band actors of `workers` (one a band, at
    most min(workers, regions), one CPU each) can never all be scheduled: more than the CPUs of
    the Ray this process is connected to, less those this process holds itself (a Ray task or
    actor planning with subregions keeps its own). Asked of a running Ray only."""
    import ray

    if not ray.is_initialized():
        return
    total = ray.cluster_resources().get("CPU", 0.0)
    held = _cpus_held()
    cpus = total - held
    where = f"the Ray this process is connected to has {total:g} CPUs" + (
        f" and this task holds {held:g} of them" if held else "")
    actors = min(workers, regions)
    if actors > cpus:
        raise ConfigError(f"subregions: workers: {workers} starts {actors} band actors of one CPU each, which can "
                          f"never all run: {where}; set workers <= {max(1, int(cpus))}")


def _client_recipe(client):
    """What a Ray actor needs to open a client like `client`: (settings, a RayBackend's actor
    handle, or a LocalBackend's store path). ConfigError for another backend."""
    from farm.service.client import RayBackend
    from farm.service.lookup import LocalBackend

    backend = client.backend
    if isinstance(backend, RayBackend):
        return client.settings, backend.actor, None
    if isinstance(backend, LocalBackend):
        return client.settings, None, str(backend.store.path)
    raise ConfigError(f"subregions: workers >= 2 needs a client of the capture-time service or of a local store, "
                      f"got a {type(backend).__name__}")


class SubRegions(_Planner):
    """The map planned as independent bands of rows, in parallel.

    Why bands of rows: the intruders advance along the rows, one column a step, towards the
    defenders' side (docs/model.md section 5); a band's intruders stay in the band, but for
    drift across its edges. The defenders start at one base cell, so the bands cannot each keep
    the defenders they hold; instead every band gets a share of the force, in proportion to
    its intruder mass, taken from every cell alike.

    One call, for defenders D and intruders I over the N x N cells:
    1. bands: rows cut into `regions` contiguous bands of N / regions rows (numpy.array_split);
       m_b the intruder mass of band b's rows, w_b = m_b / sum(m) its share of the force.
    2. sub-map b: intruders I_b (I on band b's rows, nothing elsewhere), defenders w_b D; the
       inner planner plans it alone, with the whole grid's moves and the env's advance (so
       intruders that drift out of the band stay its own), as if the other bands were empty.
       The sub-maps do not depend on each other, so they are planned at once: with `workers`
       >= 2, by that many Ray actors (each holding its own inner planner and client), else one
       after another here.
    3. the plans joined: band b holds the share w_b of every cell's defenders, so cell c's move
       probabilities are sum_b w_b p_b[c] (each p_b[c] sums to 1 and so does sum_b w_b). This is
       exact as mass: every band's defenders go where its plan sends them.

    What it gives up against planning the whole map: a band's plan does not know the others', so
    two bands may meet intruders in the same cell (near a band's edge, under drift), where the
    joint game is not the one either priced; and the force is split by intruder mass, not by
    what the defenders can reach. What it was meant to gain, smaller programs run in parallel,
    it does not: every band holds a share of every cell's defenders, so its program still has
    every node they can reach. How it compares with receding_horizon on the whole map
    (benchmarks/theatre.py --subregions): docs/model.md section 7.

    config: AllocConfig; client: a CaptureTimeClient of config.game_settings() (the inner
    planner's); regions: int >= 1 bands, at most grid_size (default None: bands of at most
    BAND_ROWS rows, so one band, the inner planner itself, up to 8 x 8); planner: the inner
    planner, a registry planner other than subregions (default receding_horizon); options:
    dict, the inner planner's options; workers: int >= 1, the Ray actors that plan the bands
    (default 1: in this process; >= 2 on Ray: the one this process is connected to, else the one
    farm.runtime starts, a local Ray of its own or the cluster $RAY_ADDRESS names; with a client
    whose backend is the capture-time service actor or a local store every actor can open; at
    most one actor a band is started, and more actors than the Ray could ever start at once, check_band_actors, are
    refused). A bad value is a ConfigError naming the option.

    Attribute last: the last call's dict, shares (per band, its w_b).
    """

    name = "subregions"

    def __init__(self, config: AllocConfig, client=None, *, regions: int | None = None,
                 planner: str = "receding_horizon", options: dict | None = None, workers: int = 1, **unknown):
        super().__init__(config, client, unknown)
        if regions is None:
            regions = -(-self.n // BAND_ROWS)
        self.regions = _count("subregions", "regions", regions)
        if self.regions > self.n:
            raise ConfigError(f"subregions: regions must be at most grid_size {self.n}, got {regions}")
        if options is not None and not isinstance(options, dict):
            raise ConfigError(f"subregions: options must be a mapping of the inner planner's options, got {options!r}")
        self.planner_name, self.options = planner, dict(options or {})
        self.inner = _inner_planner(planner, config, client, self.options)
        self.workers = _count("subregions", "workers", workers)
        if self.workers >= 2:
            check_band_actors(self.workers, self.regions)
        row_band = np.concatenate([np.full(len(rows), b) for b, rows in
                                   enumerate(np.array_split(np.arange(self.n), self.regions))])
        self.band_of = np.repeat(row_band, self.n)  # (N^2,) int64 each cell's band
        self._actors: list | None = None
        self._ray = None  # the Ray started for the band actors, when none was running
        self.last: dict = {}

    def shares(self, I: np.ndarray) -> np.ndarray:
        """Each band's share of the force: I: (N^2,) float64 -> (regions,) float64, proportional to
        the band's intruder mass, summing to 1 (all zero without intruders)."""
        mass = np.bincount(self.band_of, weights=I, minlength=self.regions)
        total = mass.sum()
        return mass / total if total > 0 else np.zeros(self.regions)

    def probabilities(self, D, I):
        """The bands' plans joined (see the class doc)."""
        w = self.shares(I)
        bands = np.flatnonzero(w > 0)
        if len(bands) == 0:
            p = self.inner.probabilities(D, I)
        else:
            jobs = [(D * w[b], np.where(self.band_of == b, I, 0.0)) for b in bands]
            plans = self._plan(jobs)
            p = sum(w[b] * plan for b, plan in zip(bands, plans))
        self.last = {"shares": w.tolist()}
        return p

    def _plan(self, jobs: list) -> list[np.ndarray]:
        """The inner planner's probabilities(D_b, I_b) of each job, in order: here, or on the actors."""
        if self.workers == 1:
            return [self.inner.probabilities(D, I) for D, I in jobs]
        import ray

        if self._actors is None:
            if not ray.is_initialized():  # the one runtime rule: a local Ray of its own, or the cluster asked for
                from contextlib import ExitStack

                from farm.runtime import ray_cluster

                self._ray = ExitStack()
                self._ray.enter_context(ray_cluster())
            try:
                check_band_actors(self.workers, self.regions)
            except ConfigError:
                self.close()
                raise
            from farm.alloc.allocators.planners.band_actor import BandPlanner

            settings, service, store = _client_recipe(self.client)
            self._actors = [BandPlanner.remote(self.config, self.planner_name, self.options, settings, service, store)
                            for _ in range(min(self.workers, self.regions))]
        refs = [self._actors[k % len(self._actors)].probabilities.remote(D, I) for k, (D, I) in enumerate(jobs)]
        return ray.get(refs)

    def close(self) -> None:
        """Stop the band actors (if any were started), and the Ray started for them (if one was)."""
        if self._actors:
            import ray

            for actor in self._actors:
                ray.kill(actor)
        self._actors = None
        if self._ray is not None:
            self._ray.close()
            self._ray = None
