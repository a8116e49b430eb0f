"""Pickling a registry entry for another process: a maker of the user's own code travels by value."""

from __future__ import annotations

import sys
import sysconfig
from pathlib import Path

__all__ = ["dumps_by_value"]


def _users_module(name: str):
    """The module `name` when it is the user's own code (see dumps_by_value), else None."""
    module = sys.modules.get(name)
    path = getattr(module, "__file__", None)
    if module is None or name == "__main__" or name.split(".")[0] in ("farm", "workers") or path is None:
        return None
    installed = {Path(sysconfig.get_paths()[k]).resolve() for k in ("purelib", "platlib", "stdlib")}
    return None if any(parent in installed for parent in Path(path).resolve().parents) else module


def dumps_by_value(value) -> bytes:
    """cloudpickle's bytes of value, an (entry, options) pair whose entry has a `make`: the module of
    the maker by value when it is the user's own code (not farm's or workers', not an installed
    package: a script, a notebook, a test file), which a worker could not import by name."""
    import cloudpickle

    entry = value[0]
    module = _users_module(getattr(entry.make, "__module__", "") or "")
    if module is None:
        return cloudpickle.dumps(value)
    cloudpickle.register_pickle_by_value(module)
    try:
        return cloudpickle.dumps(value)
    finally:
        cloudpickle.unregister_pickle_by_value(module)
