"""The capture-time service: "how fast do n_p pursuers catch n_e evaders?"

A named Ray actor holds a cache over a persistent SQLite store and computes
misses on the farm; CaptureTimeClient puts a memo in front of it.
"""

from farm.service.client import CaptureTimeClient
from farm.service.keys import ServiceSettings, StatsKey
from farm.errors import StoreCorruptError
from farm.service.store import StatsStore

__all__ = ["CaptureTimeClient", "ServiceSettings", "StatsKey", "StatsStore", "StoreCorruptError", "get_service"]


def get_service(*args, **kwargs):
    """The named service actor (found or created); see farm.service.actor.get_service."""
    from farm.service.actor import get_service as _get

    return _get(*args, **kwargs)
