"""The capture-time service: "how fast do n_p pursuers catch n_e evaders?"

The whole lookup reads in farm/service/lookup.py, its client side in client.py: a
CaptureTimeClient (the only thing callers touch) in front of one core (memo, store, estimate, compute) that runs in this
process or as a named Ray actor (farm/service/actor.py) over a persistent SQLite store.
"""

from farm.core.errors import StoreCorruptError
from farm.service.client import CaptureTimeClient, open_client
from farm.service.keys import GameSettings, StatsKey
from farm.service.store import StatsStore

__all__ = ["CaptureTimeClient", "open_client", "GameSettings", "StatsKey", "StatsStore", "StoreCorruptError",
           "get_service"]


def get_service(*args, **kwargs):
    """The named service actor (found or created); see farm.service.actor.get_service (imports Ray)."""
    from farm.service.actor import get_service as _get

    return _get(*args, **kwargs)
