"""A `farm train` config: TrainConfig and its sections (TD3Params, EvalParams, ServiceParams),
read with load_train_config; every default in one place (docs/training.md shows a config)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Literal

from pydantic import Field, field_validator, model_validator

from workers.errors import is_number

from farm.alloc.config import AllocConfig
from farm.alloc.scenarios import SCENARIOS
from farm.core.config import Strict, load_yaml_model

__all__ = ["TD3Params", "EvalParams", "ServiceParams", "TrainConfig", "load_train_config", "store_of", "POLICY_KWARGS"]

# What policy_kwargs may set from a config (SB3's TD3Policy arguments that are plain values).
POLICY_KWARGS = ("net_arch", "n_critics", "share_features_extractor", "normalize_images", "optimizer_kwargs")


def _whole(x) -> bool:
    return is_number(x) and isinstance(x, int)


def _number(x) -> bool:
    return is_number(x) and math.isfinite(x)


class TD3Params(Strict):
    """stable-baselines3 TD3's hyperparameters, RL-Zoo style."""

    n_timesteps: int = Field(30_000, ge=1)
    policy: Literal["MlpPolicy"] = "MlpPolicy"
    learning_rate: float = Field(1e-3, gt=0)
    buffer_size: int = Field(200_000, ge=1)
    learning_starts: int = Field(1000, ge=0)
    batch_size: int = Field(256, ge=1)
    tau: float = Field(0.005, gt=0, le=1)
    gamma: float = Field(0.95, ge=0, le=1)
    train_freq: int = Field(1, ge=1)
    gradient_steps: int = Field(1, ge=-1)
    policy_delay: int = Field(2, ge=1)
    noise_type: Literal["normal", "none"] = "normal"
    noise_std: float = Field(0.2, ge=0)
    policy_kwargs: dict[str, Any] = {"net_arch": [400, 300]}

    @field_validator("gradient_steps")
    @classmethod
    def _some_gradient_steps(cls, v):
        if v == 0:
            raise ValueError("must be -1 (as many as the rollout's steps) or >= 1; 0 never updates the model")
        return v

    @field_validator("policy_kwargs")
    @classmethod
    def _policy_kwargs(cls, v):
        unknown = sorted(set(v) - set(POLICY_KWARGS))
        if unknown:
            raise ValueError(f"{unknown[0]}: not a TD3 policy argument a config can set "
                             f"(choose from {', '.join(POLICY_KWARGS)})")
        for name in ("share_features_extractor", "normalize_images"):
            if name in v and not isinstance(v[name], bool):
                raise ValueError(f"{name}: must be true or false, got {v[name]!r}")
        sizes = v.get("net_arch")
        layers = ([] if sizes is None else sizes.values() if isinstance(sizes, dict) and set(sizes) <= {"pi", "qf"}
                  else [sizes])
        for layer in layers:
            if not isinstance(layer, list) or not all(_whole(x) and x >= 1 for x in layer):
                raise ValueError(f"net_arch: must be a list of layer sizes >= 1 (or {{pi: [...], qf: [...]}}), "
                                 f"got {sizes!r}")
        if "n_critics" in v and not (_whole(v["n_critics"]) and v["n_critics"] >= 1):
            raise ValueError(f"n_critics: must be a whole number >= 1, got {v['n_critics']!r}")
        adam = v.get("optimizer_kwargs") or {}
        if not isinstance(adam, dict) or not set(adam) <= {"betas", "eps", "weight_decay", "amsgrad"}:
            raise ValueError(f"optimizer_kwargs: must be a mapping of Adam's betas, eps, weight_decay or amsgrad, "
                             f"got {adam!r}")
        betas = adam.get("betas", (0.9, 0.999))
        if not (isinstance(betas, (list, tuple)) and len(betas) == 2 and all(_number(b) and 0 <= b < 1 for b in betas)):
            raise ValueError(f"optimizer_kwargs.betas: must be two numbers in [0, 1), got {betas!r}")
        for name in ("eps", "weight_decay"):
            if name in adam and not (_number(adam[name]) and adam[name] >= 0):
                raise ValueError(f"optimizer_kwargs.{name}: must be a number >= 0, got {adam[name]!r}")
        if not isinstance(adam.get("amsgrad", False), bool):
            raise ValueError(f"optimizer_kwargs.amsgrad: must be true or false, got {adam['amsgrad']!r}")
        return v


class EvalParams(Strict):
    """The periodic evaluation during training (SB3's EvalCallback)."""

    freq: int = Field(2000, ge=1)
    episodes: int = Field(10, ge=1)


class ServiceParams(Strict):
    """Where training's capture-time statistics come from (farm.service.lookup.open_client)."""

    mode: Literal["ray", "local"] = "ray"
    store: str | None = None  # None: farm.service.store.default_store_path()
    address: str | None = None
    warm_lattice: bool = True
    # During training (its steps and its periodic evaluations), a first visit's outcome comes
    # from an interpolation while the exact value is computed in the background (farm eval
    # afterwards is exact). true: the service's interpolation of what it has computed by then
    # (which visits, and from what, depends on timing); lattice: every pair off the lattice is
    # interpolated from its lattice anchors, computed exactly (reproducible: CaptureTimeClient.
    # lattice_estimates).
    estimates: bool | Literal["lattice"] = False


class TrainConfig(Strict):
    """A `farm train` config (see the module doc)."""

    name: str = Field(min_length=1, max_length=100, pattern=r"^[A-Za-z0-9_.-]+$")
    seed: int = Field(0, ge=0)
    scenario: str | None = None  # SCENARIOS' name: its env settings are the base of `env`
    env: AllocConfig = AllocConfig()
    td3: TD3Params = TD3Params()
    eval: EvalParams = EvalParams()
    checkpoint_freq: int = Field(5000, ge=1)
    log_interval: int = Field(100, ge=1)  # episodes between TensorBoard rollout records
    threads: int | None = Field(1, ge=1, le=1024)  # torch threads while training; None: torch's choice
    service: ServiceParams = ServiceParams()

    @model_validator(mode="before")
    @classmethod
    def _scenario_env(cls, data):
        """A named scenario's env settings are the base; `env:` (a mapping) overrides them.
        An unknown name is left to the field's own check, an env given as an AllocConfig is
        taken whole."""
        if isinstance(data, dict) and isinstance(data.get("scenario"), str) and data["scenario"] in SCENARIOS:
            env = data.get("env")
            if env is None or isinstance(env, dict):
                data = {**data, "env": {**SCENARIOS[data["scenario"]].env, **(env or {})}}
        return data

    @field_validator("scenario")
    @classmethod
    def _known_scenario(cls, v):
        if v is not None and v not in SCENARIOS:
            raise ValueError(f"unknown scenario {v!r} (choose from {', '.join(SCENARIOS)})")
        return v


def load_train_config(path) -> TrainConfig:
    """Read and validate a training YAML; raises ConfigError with one line."""
    return load_yaml_model(path, TrainConfig, "training")



def store_of(config: TrainConfig) -> Path:
    """The capture-time store a run uses: its config's, else the default store."""
    from farm.service.store import default_store_path

    return Path(config.service.store or default_store_path())
