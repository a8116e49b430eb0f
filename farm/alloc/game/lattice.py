"""The capture-time lattice: the team-size pairs a `team_sizes: lattice` env can meet
(lattice_pairs), grouped by service settings over many envs (lattice_groups), and computed
up front with a progress bar (warm_lattices), the one warm-up of `farm train`, `farm suite`
and `farm experiments`."""

from __future__ import annotations

from collections.abc import Iterable

from farm.alloc.game.config import AllocConfig
from farm.alloc.game.model import LATTICE, snap

__all__ = ["lattice_pairs", "lattice_groups", "warm_lattices", "memo_client"]


def lattice_pairs(env: AllocConfig) -> list[tuple[int, int]]:
    """The team-size pairs of the lattice up to the env's team sizes (team_sizes: lattice)."""
    top_p, top_e = snap(env.n_defenders), snap(env.n_intruders)
    return [(p, e) for p in LATTICE if p <= top_p for e in LATTICE if e <= top_e]


def lattice_groups(envs: Iterable[AllocConfig]) -> list[tuple[AllocConfig, list[tuple[int, int]]]]:
    """Each distinct service setting's lattice pairs over the envs having it, as (the first such
    env, its sorted pairs); an env whose team_sizes are exact has no lattice and is left out."""
    groups: dict = {}
    for env in envs:
        if env.team_sizes != "lattice":
            continue
        digest = env.game_settings().key(1, 1).settings_digest()
        _, pairs = groups.setdefault(digest, (env, set()))
        pairs.update(lattice_pairs(env))
    return [(env, sorted(pairs)) for env, pairs in groups.values()]


def warm_lattices(client, groups: list[tuple[AllocConfig, list[tuple[int, int]]]], show_progress: bool = True) -> int:
    """Have every group's pairs computed (on Ray, in parallel on the farm) and remembered, with
    one progress bar over all of them; returns the cases asked.

    client: a CaptureTimeClient; a group of other settings is asked through a client of its
    settings on the same backend (CaptureTimeClient.with_settings)."""
    from farm.core.progress import GameProgress

    total = sum(len(pairs) for _, pairs in groups)
    if not total:
        return 0
    bar = GameProgress(total, enabled=show_progress, desc="capture-time lattice", unit="case")
    try:
        for env, pairs in groups:
            settings = env.game_settings()
            (client if client.settings == settings else client.with_settings(settings)).warm(pairs, progress=bar.update)
    finally:
        bar.close()
    return total


def memo_client(envs: Iterable[AllocConfig], mode: str, store) -> tuple:
    """(an in-process CaptureTimeClient over store whose memo holds every lattice pair of envs,
    the pairs, the seconds the warm-up took): the store warmed first through a client of `mode`
    (local, or ray: on the farm), so that the returned client answers each lattice query from
    memory, never by a game or a store read (the benchmarks time policies on it). envs must
    share their service settings."""
    import time

    from farm.service import CaptureTimeClient
    from farm.service.client import open_client

    envs = list(envs)
    settings = envs[0].game_settings()
    if any(env.game_settings() != settings for env in envs):
        raise ValueError("memo_client: the configs' service settings differ")
    pairs = sorted({p for env in envs for p in lattice_pairs(env)})
    t0 = time.perf_counter()
    with open_client(settings, mode=mode, store=store) as warm_client:
        warm_client.warm(pairs)
    seconds = time.perf_counter() - t0
    client = CaptureTimeClient(settings, local_store=store)
    client.get_many(pairs)
    return client, pairs, seconds
