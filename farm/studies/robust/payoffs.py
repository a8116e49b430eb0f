"""The meta-game's payoffs: each (allocator, intruder policy) pair's seeded episodes, played once and
kept (PayoffStore), the missing ones as Ray tasks on the farm (fill)."""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import numpy as np

from farm.alloc.game.config import AllocConfig
from farm.core.errors import ConfigError
from farm.core.output import atomic_write_bytes
from farm.studies.robust.members import MEASURES, Member

__all__ = ["payoff_key", "PayoffStore", "fill", "claim_folder", "KIND_FILE", "write_state", "read_state"]

KIND_FILE = ".swarm-farm-kind"  # what a folder of payoffs holds: "exploit" or "robust"
MANIFESTS = {"exploit": "exploit.json", "robust": "robust.json"}  # each kind's own state file
ARTICLES = {"exploit": "an", "robust": "a"}

def _state_digest(kind: str, values: dict) -> str:
    return hashlib.sha256(json.dumps({"kind": kind, "values": values}, sort_keys=True).encode()).hexdigest()


def write_state(path: Path, kind: str, values: dict) -> None:
    """A run's state file (exploit.json, robust.json): values with a SHA-256 of them and of the
    kind of run, written atomically."""
    atomic_write_bytes(path, json.dumps({**values, "sha256": _state_digest(kind, values)}, indent=1).encode())


def read_state(path: Path, kind: str) -> dict | None:
    """A state file's values (write_state's), None without one; a file that is not one whole
    (cut short, edited, of another kind of run, or without its checksum) is moved
    into damaged/ beside it, said in one line, and None returned: its run computes it again from
    what it keeps (the payoffs, the trainings)."""
    from farm.alloc.training.runs import move_damaged

    if not path.exists():
        return None
    try:
        saved = json.loads(path.read_text())
        values = {k: v for k, v in saved.items() if k != "sha256"}
        if saved["sha256"] != _state_digest(kind, values):
            raise ValueError("checksum")
        return values
    except (OSError, UnicodeDecodeError, ValueError, KeyError, TypeError, AttributeError) as e:
        aside = move_damaged(path)
        print(f"{kind}: {path} is damaged ({type(e).__name__}); moved to {aside}/ and computed again from the "
              f"kept payoffs and trainings", file=sys.stderr)
        return None


def claim_folder(out: Path, kind: str) -> None:
    """Say that the folder out holds a run of kind ("exploit" or "robust"), before any work; a
    ConfigError (one line naming out) when it holds the other kind (its kind file, or the other's
    state file), whose payoffs/ would mix with this run's."""
    said = (out / KIND_FILE).read_text().strip() if (out / KIND_FILE).is_file() else None
    others = [k for k, manifest in MANIFESTS.items() if k != kind and (out / manifest).exists()]
    held = said if said not in (None, kind) else (others[0] if others else None)
    if held is not None:
        raise ConfigError(f"out: {out} holds {ARTICLES[held]} {held} run, not {ARTICLES[kind]} {kind} one; choose "
                          f"another folder", field="out")
    out.mkdir(parents=True, exist_ok=True)
    if said is None:
        atomic_write_bytes(out / KIND_FILE, f"{kind}\n".encode())


def payoff_key(config: AllocConfig, allocator: Member, intruders: Member, episodes: int, seed: int,
               root=None) -> str:
    """The digest of everything that decides a pair's episodes: the env settings, both members
    (a trained member's run under root, the run's folder, relative to it), the episodes and their
    first seed."""
    blob = json.dumps({"env": config.model_dump(mode="json"), "allocator": allocator.key(root),
                       "intruders": intruders.key(root), "episodes": episodes, "seed": seed}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()[:32]


class PayoffStore:
    """Pairs' per-episode measures on disk, one JSON file a pair (folder/<key>.json, written
    atomically, with a SHA-256 of its values and its key): a pair played once is never played
    again, and a damaged file (or one of another pair) is said in one line and played again."""

    def __init__(self, folder):
        self.folder = Path(folder)
        self.root = self.folder.parent  # the run's folder: trained members' runs are keyed relative to it

    def path(self, key: str) -> Path:
        """The pair's file."""
        return self.folder / f"{key}.json"

    def get(self, key: str) -> dict | None:
        """{measure: (episodes,) float64} of a pair kept, else None."""
        path = self.path(key)
        if not path.exists():
            return None
        try:
            saved = json.loads(path.read_text())
            values = saved["values"]
            if saved["sha256"] != _digest(key, values):  # a file of another pair, or one edited
                raise ValueError("checksum")
        except (OSError, ValueError, KeyError, TypeError) as e:
            print(f"robust: payoff file {path.name} is damaged ({type(e).__name__}); played again", file=sys.stderr)
            return None
        return {m: np.asarray(values[m], dtype=np.float64) for m in MEASURES}

    def put(self, key: str, values: dict) -> None:
        """Keep a pair's measures ({measure: sequence of floats})."""
        plain = {m: [float(x) for x in values[m]] for m in MEASURES}
        atomic_write_bytes(self.path(key), json.dumps({"values": plain, "sha256": _digest(key, plain)}).encode())


def _digest(key: str, values: dict) -> str:
    """The checksum of a pair's file: its values and the pair's key, so that a file moved to another
    pair's name is no payoff of that pair."""
    return hashlib.sha256(json.dumps({"key": key, "values": values}, sort_keys=True).encode()).hexdigest()


def fill(store: PayoffStore, config: AllocConfig, pairs: list[tuple[Member, Member]], episodes: int, seed: int,
         client, workers: int, progress=None) -> int:
    """Play every pair the store lacks, as Ray tasks on client's service actor (at most workers at
    once, farm.runtime.bounded), each kept as it finishes; returns the pairs played. progress(n):
    called with each finished pair's count."""
    missing = [(a, b) for a, b in pairs if store.get(payoff_key(config, a, b, episodes, seed, store.root)) is None]
    if not missing:
        return 0
    import ray

    from farm.runtime import bounded
    from farm.studies.robust.tasks import remote_pair

    actor = client.backend.actor
    for (a, b), ref in bounded(lambda pair: remote_pair.remote(config, pair[0], pair[1], actor, episodes, seed),
                               missing, workers):
        store.put(payoff_key(config, a, b, episodes, seed, store.root), ray.get(ref))
        if progress is not None:
            progress(1)
    return len(missing)
