"""Learned allocators: a trained stable-baselines3 model of a run folder (TD3, PPO or SAC, the
run's `algo`), loaded on the CPU and checked (load_model), acting through its policy's predict()."""

from __future__ import annotations

from pathlib import Path

from farm.alloc.allocators.repair import check_repair, repaired
from farm.alloc.networks.trained import ALGORITHMS, algorithm_class, load_model
from farm.core.errors import ConfigError

__all__ = ["ALGORITHMS", "algorithm_class", "load_model", "learned", "td3", "ppo", "sac"]

def _run_repair(run) -> str:
    """The `repair` of a run folder's config.yaml (none for a config without it, or a run without one)."""
    import yaml

    path = Path(run) / "config.yaml" if run is not None else None  # farm.alloc.training.runs.CONFIG, a layer above
    values = yaml.safe_load(path.read_text()) if path is not None and path.exists() else None
    value = values.get("repair", "none") if isinstance(values, dict) else "none"
    return check_repair(value, "repair")


def learned(algo: str, policy=None, run: str | None = None, config=None, repair: str | None = None):
    """A trained allocator of algorithm algo: policy (a loaded SB3 policy, model.policy), or the
    model of the run folder `run` (load_model), for the map of config (an AllocConfig; None: the
    model's own). A CellPolicy acts on a map of any size and teams (cell_policy.resized); a policy
    whose size is its map's is refused on another map size (ConfigError, one line).
    repair: `none` or `levels` (farm.alloc.allocators.repair); None: the run's config's (none
    without a run); config None gives the bare network."""
    if policy is None:
        if run is None:
            raise ConfigError(f"{algo}: needs a trained model: the run folder (run=...) or its policy (policy=...)")
        policy = load_model(run, algo).policy
    if config is None:  # the bare network, as it was trained
        if repair not in (None, "none"):
            raise ConfigError(f"repair: {repair!r} needs the map's config (config=...)", field="repair")
        return policy
    repair = check_repair(repair, "repair") if repair is not None else _run_repair(run)
    return repaired(_on_map(policy, config), config, repair)


def _on_map(policy, config):
    """policy acting on config's map (a CellPolicy moved there; another policy checked to fit)."""
    if type(policy).__name__ == "CellPolicy":
        from farm.alloc.networks.cell_policy import resized

        return resized(policy, config)
    trained = int(round((policy.observation_space.shape[0] / 2) ** 0.5))
    if trained != config.grid_size:
        n = config.grid_size
        raise ConfigError(f"scenario: the model was trained on a {trained}x{trained} map and its "
                          f"{type(policy).__name__}'s size is its map's, so it cannot act on a {n}x{n} map "
                          f"(train it with ppo.policy: CellPolicy, whose weights fit any map)", field="scenario")
    return policy


def td3(config, client=None, *, policy=None, run: str | None = None, repair: str | None = None):
    """A trained TD3 allocator (learned)."""
    return learned("td3", policy, run, config, repair)


def ppo(config, client=None, *, policy=None, run: str | None = None, repair: str | None = None):
    """A trained PPO allocator (learned)."""
    return learned("ppo", policy, run, config, repair)


def sac(config, client=None, *, policy=None, run: str | None = None, repair: str | None = None):
    """A trained SAC allocator (learned)."""
    return learned("sac", policy, run, config, repair)
