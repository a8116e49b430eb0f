"""A pretraining's iteration files (pretrain/iteration_<i>.pkl): written with the iteration and
the run they hold and a checksum (write_iteration), and read back only when all three hold
(read_iteration); resume_iteration finds the newest one that does and moves the others aside.
run_digest is what identifies a run's pretraining.
"""

from __future__ import annotations

import hashlib
import json
import pickle
import re
import sys
from pathlib import Path

import numpy as np

from farm.alloc.training.dagger.labels import FIELDS
from farm.core.sealed import SealProblem, seal, unseal

__all__ = ["MAGIC", "iteration_file", "saved_iterations", "latest_iteration", "run_digest", "write_iteration",
           "read_iteration", "check_state", "resume_iteration", "IterationProblem"]

MAGIC = b"swarm-farm pretrain iteration\n"  # an iteration file's first line; a JSON header line follows
STATE_KEYS = ("iteration", "data", "policy", "rng", "seconds", "loss")  # what an iteration's state holds

# What unpickling a damaged state raises: UnpicklingError or EOFError when it is cut short;
# garbage, and a damaged tensor inside, unpickle into many errors.
_UNPICKLING_DAMAGE = (EOFError, pickle.UnpicklingError, ValueError, LookupError, RuntimeError, AttributeError,
                      ImportError, TypeError, MemoryError, OverflowError)


class IterationProblem(Exception):
    """Why an iteration file cannot be resumed from: its message says it in a few words."""


def iteration_file(run_dir, iteration: int) -> Path:
    """A pretraining iteration's state in a run folder: pretrain/iteration_<i>.pkl."""
    return Path(run_dir) / "pretrain" / f"iteration_{iteration}.pkl"


def saved_iterations(run_dir) -> list[int]:
    """The pretraining iterations saved in a run folder (pretrain/iteration_<i>.pkl), newest first."""
    found = [int(m.group(1)) for p in (Path(run_dir) / "pretrain").glob("iteration_*.pkl")
             if (m := re.fullmatch(r"iteration_(\d+)\.pkl", p.name))]
    return sorted(found, reverse=True)


def latest_iteration(run_dir) -> int | None:
    """The last pretraining iteration saved in a run folder, or None."""
    found = saved_iterations(run_dir)
    return found[0] if found else None


def run_digest(config) -> str:
    """The digest of everything in a TrainConfig that decides its pretraining's iterations: the
    whole config but the length of training, the threads, the tracking and where the
    capture-time statistics come from (service mode, address, store, warm_lattice), which a
    resumed run may change without changing what the iterations hold."""
    values = json.loads(config.with_timesteps(0).model_dump_json())
    for name in ("threads", "tracking"):
        values.pop(name, None)
    values["service"] = {"estimates": values.get("service", {}).get("estimates")}
    return hashlib.sha256(json.dumps(values, sort_keys=True).encode()).hexdigest()[:16]


def write_iteration(run_dir, state: dict, digest: str) -> Path:
    """Write an iteration's state (a dict of STATE_KEYS) to its file, atomically, sealed
    (farm.core.sealed: MAGIC, a JSON line {"iteration", "run": digest, "sha256", "bytes"}, the
    pickled state, the checksum and length being the pickle's); returns the path."""
    from farm.core.output import atomic_write_bytes

    path = iteration_file(run_dir, state["iteration"])
    atomic_write_bytes(path, seal(MAGIC, pickle.dumps(state), iteration=int(state["iteration"]), run=digest))
    return path


def read_iteration(path: Path, iteration: int | None = None, digest: str | None = None) -> dict:
    """The state an iteration file holds, once its pickle has the header's length and checksum
    and the header says it is `iteration` of the run `digest` (each None: any);
    IterationProblem otherwise: unreadable, without the header (a file written without a
    checksum cannot be told from a damaged one, so it is not read), failing its checksum,
    another run's, or another iteration's (a stale file under a newer name)."""
    try:
        data = Path(path).read_bytes()
    except OSError as e:
        raise IterationProblem(f"is unreadable ({type(e).__name__})") from None
    try:
        header, payload = unseal(data, MAGIC)
    except SealProblem as e:
        if str(e) == "no checksum":
            raise IterationProblem("has no checksum (an iteration file without one cannot be verified)") from None
        raise IterationProblem(f"is damaged ({e})") from None
    if not {"iteration", "run"} <= set(header):
        raise IterationProblem("is damaged (its header)")
    if digest is not None and header["run"] != digest:
        raise IterationProblem(f"is another run's (config digest {header['run']}, not {digest})")
    if iteration is not None and header["iteration"] != iteration:
        raise IterationProblem(f"holds iteration {header['iteration']}'s state, not iteration {iteration}'s")
    try:
        state = pickle.loads(payload)
    except _UNPICKLING_DAMAGE as e:
        raise IterationProblem(f"is damaged ({type(e).__name__})") from None
    return state


def check_state(state, iteration: int, policy_state: dict, maps: int) -> None:
    """IterationProblem unless state is an iteration's whole state for this run: a dict of
    STATE_KEYS holding `iteration`, labels of each of `maps` maps (play_labelled's FIELDS, of one
    length each), a policy state of policy_state's keys, shapes and dtypes, a PCG64 generator's
    state, and finite seconds."""
    if not isinstance(state, dict):
        raise IterationProblem("is damaged (not an iteration's state)")
    missing = [k for k in STATE_KEYS if k not in state]
    if missing:
        raise IterationProblem(f"is damaged (no {missing[0]!r})")
    if state["iteration"] != iteration:
        raise IterationProblem(f"holds iteration {state['iteration']}'s state, not iteration {iteration}'s")
    data = state["data"] if maps > 1 else [state["data"]]
    if not isinstance(data, list) or len(data) != maps:
        raise IterationProblem(f"is damaged (labels of another number of maps than {maps})")
    for part in data:
        if not isinstance(part, dict) or any(not isinstance(part.get(k), np.ndarray) for k in FIELDS) \
                or len({len(part[k]) for k in FIELDS}) != 1 or len(part["obs"]) == 0:
            raise IterationProblem("is damaged (its labels)")
    policy = state["policy"]
    if not isinstance(policy, dict) or policy.keys() != policy_state.keys() or any(
            getattr(policy[k], "shape", None) != v.shape or getattr(policy[k], "dtype", None) != v.dtype
            for k, v in policy_state.items()):
        raise IterationProblem("is damaged (its policy does not fit the run's model)")
    try:
        np.random.default_rng(0).bit_generator.state = state["rng"]
    except (TypeError, ValueError, KeyError) as e:
        raise IterationProblem(f"is damaged (its generator's state: {type(e).__name__})") from None
    if not all(isinstance(state[k], (int, float)) and not isinstance(state[k], bool) for k in ("seconds", "loss")) \
            or not np.isfinite(state["seconds"]):
        raise IterationProblem("is damaged (its figures)")


def resume_iteration(run_dir, digest: str, iterations: int, policy_state: dict, maps: int) -> tuple[int, dict] | None:
    """(the iteration, its state) of the newest iteration file of run_dir that read_iteration
    reads and check_state passes, or None. One that does not, or of an iteration at or beyond
    `iterations`, is moved to pretrain/damaged/ (farm.alloc.training.runs.move_damaged) and said in one
    line on stderr, and the one before it tried. policy_state: the run's model's policy
    state_dict (the shapes a saved policy must have); maps: the maps the pretraining plays."""
    from farm.alloc.training.runs import DAMAGED, move_damaged

    damaged, found = [], None
    for iteration in saved_iterations(run_dir):
        path = iteration_file(run_dir, iteration)
        try:
            if iteration >= iterations:
                raise IterationProblem(f"is of iteration {iteration}, past the pretraining's {iterations}")
            state = read_iteration(path, iteration, digest)
            check_state(state, iteration, policy_state, maps)
        except IterationProblem as e:
            move_damaged(path)
            damaged.append(f"pretrain/{path.name} {e}")
            continue
        found = iteration, state
        break
    then = f"resumed after iteration {found[0]}" if found else "the pretraining starts again"
    for line in damaged:
        print(f"pretrain {run_dir}: {line}; moved to pretrain/{DAMAGED}/, {then}", file=sys.stderr)
    return found
