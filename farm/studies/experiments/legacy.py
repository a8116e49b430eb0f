"""Names under which Ray Tune's saved state of older experiment folders pickles swarm-farm's
objects, mapped to today's objects so that such a folder still resumes.

Tune pickles an experiment's trial-folder namer and its callbacks by module path. Older
folders' state names `farm.experiments._trial_dirname` and
`farm.experiments_tune.Progress`; old_names() makes those paths importable for the block in
which run_experiment restores and runs an experiment, and for no longer. Kept until 0.7.
"""

from __future__ import annotations

import sys
import types
from contextlib import contextmanager

__all__ = ["ALIASES", "old_names"]

# old module path -> {name in it: today's module path and name}
ALIASES = {
    "farm.experiments": {"_trial_dirname": ("farm.studies.experiments.trial", "trial_dirname")},
    "farm.experiments_tune": {"Progress": ("farm.studies.experiments.tune", "Progress")},
}


@contextmanager
def old_names():
    """For the block, every module path of ALIASES imports as a module holding today's objects
    under their old names; paths already importable are left alone."""
    import importlib

    added = []
    for old, names in ALIASES.items():
        if old in sys.modules:
            continue
        module = types.ModuleType(old, f"swarm-farm's old name for {', '.join(m for m, _ in names.values())}")
        for name, (path, attribute) in names.items():
            setattr(module, name, getattr(importlib.import_module(path), attribute))
        sys.modules[old] = module
        added.append(old)
    try:
        yield
    finally:
        for old in added:
            sys.modules.pop(old, None)
