"""Trained stable-baselines3 models: an algorithm's class by name, and a run folder's model loaded
on the CPU and checked (load_model), for the learned allocators and the learned intruders alike."""

from __future__ import annotations

from pathlib import Path

from farm.core.errors import ConfigError, ModelError

__all__ = ["ALGORITHMS", "algorithm_class", "load_model"]

ALGORITHMS = ("td3", "ppo", "sac")  # the registry's learned allocators, one per SB3 algorithm


def algorithm_class(algo: str):
    """stable-baselines3's class of an algorithm name (td3, ppo, sac)."""
    import stable_baselines3

    if algo not in ALGORITHMS:
        raise ConfigError(f"algo: must be one of {', '.join(ALGORITHMS)}, got {algo!r}", field="algo")
    return getattr(stable_baselines3, algo.upper())


def load_model(run_dir, algorithm: str = "td3"):
    """The trained model of a run folder (its model.zip), on the CPU.

    ConfigError without a model.zip; ModelError (one line naming the file) for a file
    stable-baselines3 cannot load (truncated, damaged, not a model of `algorithm`) or whose
    parameters are not all finite."""
    import torch

    run_dir = Path(run_dir)
    path = run_dir / "model.zip"
    if not path.exists():
        raise ConfigError(f"{run_dir}: no trained model (model.zip); run `farm train CONFIG --out {run_dir}`")
    cls = algorithm_class(algorithm)
    try:
        model = cls.load(path, device="cpu")
    except Exception as e:  # any failure to read it: the file is not a model this can evaluate
        problem = (str(e).strip().splitlines() or [""])[0]
        raise ModelError(f"{path}: not a loadable stable-baselines3 {algorithm.upper()} model ({type(e).__name__}"
                         f"{': ' + problem if problem else ''})") from None
    with torch.no_grad():
        for name, p in model.policy.named_parameters():
            if not bool(torch.isfinite(p).all()):
                raise ModelError(f"{path}: the policy's {name} is not finite (a run that diverged); "
                                 f"train it again")
    return model
