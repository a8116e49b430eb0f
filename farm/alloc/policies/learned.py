"""Learned allocators: a trained stable-baselines3 model of a run folder, loaded on the CPU
and checked (load_model), acting through its policy's predict()."""

from __future__ import annotations

from pathlib import Path

from farm.core.errors import ConfigError, ModelError

__all__ = ["load_model", "td3"]


def load_model(run_dir, algorithm: str = "td3"):
    """The trained model of a run folder (its model.zip), on the CPU.

    ConfigError without a model.zip; ModelError (one line naming the file) for a file
    stable-baselines3 cannot load (truncated, damaged, not a model of `algorithm`) or whose
    parameters are not all finite."""
    import stable_baselines3
    import torch

    run_dir = Path(run_dir)
    path = run_dir / "model.zip"
    if not path.exists():
        raise ConfigError(f"{run_dir}: no trained model (model.zip); run `farm train CONFIG --out {run_dir}`")
    try:
        model = getattr(stable_baselines3, algorithm.upper()).load(path, device="cpu")
    except Exception as e:  # any failure to read it: the file is not a model this can evaluate
        problem = (str(e).strip().splitlines() or [""])[0]
        raise ModelError(f"{path}: not a loadable stable-baselines3 model ({type(e).__name__}"
                         f"{': ' + problem if problem else ''})") from None
    with torch.no_grad():
        for name, p in model.policy.named_parameters():
            if not bool(torch.isfinite(p).all()):
                raise ModelError(f"{path}: the policy's {name} is not finite (a run that diverged); "
                                 f"train it again")
    return model


def td3(config, client=None, *, policy=None, run: str | None = None):
    """A trained TD3 allocator: policy (a loaded SB3 policy, model.policy) as it is, or the
    model of the run folder `run` (load_model)."""
    if policy is None:
        if run is None:
            raise ConfigError("td3: needs a trained model: the run folder (run=...) or its policy (policy=...)")
        policy = load_model(run, "td3").policy
    return policy
