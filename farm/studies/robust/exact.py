"""The intruders' exact best response in the meta-game, on maps whose search tree fits: each
allocator's payoff against the exact search (farm.alloc.intruders.exact_search.exact_response) on the
meta-game's own episodes, kept beside the pairs' payoffs, and each iteration's allocators' mixture
valued against it. Under `follower` a mixture drawn per episode is searched member by member, as
if the intruders were told the member drawn (they see each move): the intruders' best gain over the
meta-game's value, to which the trained intruders' response is a lower bound."""

from __future__ import annotations

import numpy as np

from farm.alloc.game.config import AllocConfig
from farm.core.errors import ConfigError
from farm.studies.robust.members import Member
from farm.studies.robust.payoffs import PayoffStore, payoff_key

__all__ = ["exact_member", "deterministic", "searchable", "fill_exact", "exact_values"]


def exact_member(measure: str) -> Member:
    """The search minimising the defenders' measure, as a payoff's column."""
    return Member("intruders", "exact", {"objective": measure})


def deterministic(member: Member) -> bool:
    """Whether an allocator can be searched against: every one but a mixture that draws its members
    (a mixture of mean moves is one deterministic allocator)."""
    return member.name != "mixture" or member.options.get("draw", "episode") == "mean"


def searchable(config: AllocConfig, episodes: int, seed: int) -> bool:
    """Whether every episode's search tree fits the search's default budget of states."""
    from farm.alloc.intruders.exact_search import check_search, episode_start

    try:
        for k in range(episodes):
            check_search(config, episode_start(config, seed + k)[1], seed=seed + k)
    except ConfigError:
        return False
    return True


def fill_exact(store: PayoffStore, config: AllocConfig, allocators: list[Member], episodes: int, seed: int,
               measure: str, client, workers: int) -> int:
    """Search, minimising measure, every allocator the store lacks a payoff against the search for
    (Ray tasks on client's service actor, at most workers at once, each kept as it finishes);
    returns the searches run."""
    exact = exact_member(measure)
    missing = [a for a in allocators
               if store.get(payoff_key(config, a, exact, episodes, seed, store.root)) is None]
    if not missing:
        return 0
    import ray

    from farm.runtime import bounded
    from farm.studies.robust.tasks import remote_exact

    actor = client.backend.actor
    for a, ref in bounded(lambda a: remote_exact.remote(config, a, actor, episodes, seed, measure), missing, workers):
        store.put(payoff_key(config, a, exact, episodes, seed, store.root), ray.get(ref))
    return len(missing)


def exact_values(store: PayoffStore, config: AllocConfig, allocators: list[Member], episodes: int, seed: int,
                 measure: str) -> np.ndarray:
    """(len(allocators),) float64: each allocator's mean measure against the search minimising it,
    every one searched already (fill_exact)."""
    values = [store.get(payoff_key(config, a, exact_member(measure), episodes, seed, store.root))
              for a in allocators]
    if any(v is None for v in values):
        raise RuntimeError("an allocator's exact payoff is missing")
    return np.array([float(np.mean(v[measure])) for v in values])
