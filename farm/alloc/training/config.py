"""A `farm train` config: TrainConfig and its sections (the learner's: TD3Params, PPOParams or
SACParams under `algo`; PretrainParams, EvalParams, ServiceParams, TrackingParams), read with load_train_config;
every default in one place (docs/training.md shows a config)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, ClassVar, Literal

from pydantic import Field, field_validator, model_validator

from workers.errors import is_number

from farm.alloc.config import AllocConfig
from farm.alloc.scenarios import SCENARIOS
from farm.core.config import Strict, load_yaml_model
from farm.core.tracking import TrackingParams

__all__ = ["ALGOS", "TD3Params", "PPOParams", "SACParams", "PretrainParams", "EvalParams", "ServiceParams",
           "TrainConfig", "load_train_config", "store_of", "POLICY_KWARGS"]

ALGOS = ("td3", "ppo", "sac")  # stable-baselines3's algorithms a config may name (`algo`)

# What policy_kwargs may set from a config, by algorithm: the SB3 policy's arguments that are plain
# values (activation_fn by name: ACTIVATIONS).
POLICY_KWARGS = {
    "td3": ("net_arch", "n_critics", "share_features_extractor", "normalize_images", "optimizer_kwargs",
            "activation_fn"),
    "sac": ("net_arch", "n_critics", "share_features_extractor", "normalize_images", "optimizer_kwargs",
            "activation_fn", "log_std_init", "use_expln", "clip_mean"),
    "ppo": ("net_arch", "share_features_extractor", "normalize_images", "optimizer_kwargs", "activation_fn",
            "log_std_init", "ortho_init", "full_std", "use_expln", "squash_output"),
}
# CellPolicy's (farm.alloc.training.cell_policy, PPO only): its sizes and ActorCriticPolicy's plain values
CELL_POLICY_KWARGS = ("channels", "layers", "positions", "log_std_init", "ortho_init", "optimizer_kwargs")
ACTIVATIONS = ("relu", "tanh", "elu", "leaky_relu", "gelu")  # torch.nn's ReLU, Tanh, ELU, LeakyReLU, GELU


def _whole(x) -> bool:
    return is_number(x) and isinstance(x, int)


def _number(x) -> bool:
    return is_number(x) and math.isfinite(x)


def _check_policy_kwargs(v: dict, algo: str, policy: str = "MlpPolicy") -> dict:
    """policy_kwargs of algo's SB3 policy as a config may set them (POLICY_KWARGS; CellPolicy's:
    CELL_POLICY_KWARGS), checked."""
    allowed = CELL_POLICY_KWARGS if policy == "CellPolicy" else POLICY_KWARGS[algo]
    unknown = sorted(set(v) - set(allowed))
    if unknown:
        what = "CellPolicy" if policy == "CellPolicy" else f"{algo.upper()} policy"
        raise ValueError(f"{unknown[0]}: not a {what} argument a config can set (choose from {', '.join(allowed)})")
    for name in ("channels", "layers"):
        if name in v and not (_whole(v[name]) and 1 <= v[name] <= 512):
            raise ValueError(f"{name}: must be a whole number from 1 to 512, got {v[name]!r}")
    for name in ("positions", "share_features_extractor", "normalize_images", "ortho_init", "full_std", "use_expln",
                 "squash_output"):
        if name in v and not isinstance(v[name], bool):
            raise ValueError(f"{name}: must be true or false, got {v[name]!r}")
    sizes = v.get("net_arch")
    layers = ([] if sizes is None else sizes.values() if isinstance(sizes, dict) and set(sizes) <= {"pi", "qf", "vf"}
              else [sizes])
    for layer in layers:
        if not isinstance(layer, list) or not all(_whole(x) and x >= 1 for x in layer):
            raise ValueError(f"net_arch: must be a list of layer sizes >= 1 (or {{pi: [...], qf: [...]}}, vf for ppo), "
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
    if "activation_fn" in v and v["activation_fn"] not in ACTIVATIONS:
        raise ValueError(f"activation_fn: must be one of {', '.join(ACTIVATIONS)}, got {v['activation_fn']!r}")
    for name in ("log_std_init", "clip_mean"):
        if name in v and not _number(v[name]):
            raise ValueError(f"{name}: must be a number, got {v[name]!r}")
    return v


class _Params(Strict):
    """What every algorithm's section has: its length, and the policy_kwargs of its SB3 policy
    (checked for ALGO's policy, _check_policy_kwargs)."""

    ALGO: ClassVar[str] = ""

    n_timesteps: int = Field(30_000, ge=1)
    policy: Literal["MlpPolicy"] = "MlpPolicy"

    @field_validator("policy_kwargs", check_fields=False)
    @classmethod
    def _policy_kwargs(cls, v, info):
        return _check_policy_kwargs(v, cls.ALGO, info.data.get("policy", "MlpPolicy"))


class _OffPolicyParams(_Params):
    """The settings TD3 and SAC share (stable-baselines3's OffPolicyAlgorithm's)."""

    learning_rate: float = Field(1e-3, gt=0)
    buffer_size: int = Field(200_000, ge=1)
    learning_starts: int = Field(1000, ge=0)
    batch_size: int = Field(256, ge=1)
    tau: float = Field(0.005, gt=0, le=1)
    gamma: float = Field(0.95, ge=0, le=1)
    train_freq: int = Field(1, ge=1)
    gradient_steps: int = Field(1, ge=-1)

    @field_validator("gradient_steps")
    @classmethod
    def _some_gradient_steps(cls, v):
        if v == 0:
            raise ValueError("must be -1 (as many as the rollout's steps) or >= 1; 0 never updates the model")
        return v


class TD3Params(_OffPolicyParams):
    """stable-baselines3 TD3's hyperparameters, RL-Zoo style."""

    ALGO: ClassVar[str] = "td3"

    policy_delay: int = Field(2, ge=1)
    noise_type: Literal["normal", "none"] = "normal"
    noise_std: float = Field(0.2, ge=0)
    policy_kwargs: dict[str, Any] = {"net_arch": [400, 300]}


class PPOParams(_Params):
    """stable-baselines3 PPO's hyperparameters, RL-Zoo style (SB3's defaults, but gamma and the
    rollout's length, which suit episodes of 12 to 16 steps)."""

    ALGO: ClassVar[str] = "ppo"

    n_timesteps: int = Field(100_000, ge=1)
    policy: Literal["MlpPolicy", "CellPolicy"] = "MlpPolicy"  # CellPolicy: farm.alloc.training.cell_policy
    learning_rate: float = Field(3e-4, gt=0)
    n_steps: int = Field(256, ge=1)  # per env: a rollout is n_steps x n_envs steps
    batch_size: int = Field(64, ge=2)
    n_epochs: int = Field(10, ge=1)
    gamma: float = Field(0.99, ge=0, le=1)
    gae_lambda: float = Field(0.95, ge=0, le=1)
    clip_range: float = Field(0.2, gt=0)
    ent_coef: float = Field(0.0, ge=0)
    vf_coef: float = Field(0.5, ge=0)
    max_grad_norm: float = Field(0.5, gt=0)
    target_kl: float | None = Field(None, gt=0)
    normalize_advantage: bool = True
    policy_kwargs: dict[str, Any] = {}


class SACParams(_OffPolicyParams):
    """stable-baselines3 SAC's hyperparameters, RL-Zoo style (SB3's defaults, but gamma, the
    buffer and the warm-up, as TD3's here)."""

    ALGO: ClassVar[str] = "sac"

    learning_rate: float = Field(3e-4, gt=0)
    ent_coef: float | Literal["auto"] = "auto"  # a number: fixed; auto: learned, starting at 1
    target_entropy: float | Literal["auto"] = "auto"
    policy_kwargs: dict[str, Any] = {"net_arch": [400, 300]}

    @field_validator("ent_coef")
    @classmethod
    def _positive_ent_coef(cls, v):
        if v != "auto" and v < 0:
            raise ValueError(f"must be 'auto' or a number >= 0, got {v!r}")
        return v


class MapParams(Strict):
    """One map of a pretraining curriculum (pretrain.maps): a suite scenario, its env settings
    replaced by `env`'s (AllocConfig fields), as a training config's `scenario` and `env`."""

    scenario: str
    env: dict[str, Any] = {}

    @field_validator("scenario")
    @classmethod
    def _known(cls, v):
        if v not in SCENARIOS:
            raise ValueError(f"unknown scenario {v!r} (choose from {', '.join(SCENARIOS)})")
        return v

    @model_validator(mode="after")
    def _settings(self):
        try:
            self.config()
        except ValueError as e:  # pydantic's ValidationError: the first problem, in one line
            first = e.errors()[0] if hasattr(e, "errors") else {"loc": (), "msg": str(e)}
            where = ".".join(str(x) for x in first["loc"])
            raise ValueError(f"env: {where + ': ' if where else ''}{first['msg']}") from None
        return self

    def config(self, **service) -> AllocConfig:
        """The map's AllocConfig, service settings (games, seed) in `service` replacing the scenario's."""
        return SCENARIOS[self.scenario].config(**{**self.env, **service})


class PretrainParams(Strict):
    """Planner-guided pretraining (DAgger; farm.alloc.training.pretrain): before RL, the learner's
    actor is fitted to an expert's actions on the states visited by a mixture of the expert and
    the learner, then RL fine-tunes from there.

    expert: an allocator of the registry (farm.alloc.policies: any planner or baseline) and
    expert_options its options; iterations: DAgger iterations; episodes: episodes played per
    iteration; expert_share: the share of steps the expert drives in each iteration (one number
    per iteration, or one number p for the schedule 1, p, p^2, ...: the first iteration is the
    expert's alone); epochs, batch_size, learning_rate: the fit of each iteration (mean squared
    error to the expert's actions, Adam) over the states labelled so far; episodes_per_task:
    the episodes of one labelling task (on Ray: one task per batch of episodes); maps: suite
    scenarios whose episodes are labelled too, each iteration's `episodes` on each, and fitted
    with the run's own (a curriculum of maps, for a policy whose weights fit any map:
    ppo.policy CellPolicy)."""

    expert: str = "receding_horizon"
    expert_options: dict[str, Any] = {}
    iterations: int = Field(4, ge=1, le=1000)
    episodes: int = Field(16, ge=1)
    expert_share: float | list[float] = 0.5
    loss: Literal["flows", "actions"] = "flows"
    epochs: int = Field(30, ge=1)
    batch_size: int = Field(128, ge=1)
    learning_rate: float = Field(1e-3, gt=0)
    episodes_per_task: int = Field(4, ge=1)
    maps: list[MapParams] = []

    @field_validator("maps", mode="before")
    @classmethod
    def _names_are_maps(cls, v):
        return [{"scenario": m} if isinstance(m, str) else m for m in v] if isinstance(v, list) else v

    @field_validator("expert")
    @classmethod
    def _known_expert(cls, v):
        from farm.alloc.policies import policy_names

        choices = policy_names(("baseline", "planner"))
        if v not in choices:
            raise ValueError(f"unknown expert {v!r} (choose from the baselines and planners: {', '.join(choices)})")
        return v

    @field_validator("expert_share")
    @classmethod
    def _shares(cls, v):
        shares = v if isinstance(v, list) else [v]
        if not shares or not all(0 <= x <= 1 for x in shares):
            raise ValueError(f"must be a number in [0, 1] or a list of them, one per iteration, got {v!r}")
        return v

    @model_validator(mode="after")
    def _schedule_length(self):
        if isinstance(self.expert_share, list) and len(self.expert_share) != self.iterations:
            raise ValueError(f"expert_share: {len(self.expert_share)} shares for {self.iterations} iterations")
        return self

    def schedule(self) -> list[float]:
        """The share of steps the expert drives, per iteration."""
        if isinstance(self.expert_share, list):
            return list(self.expert_share)
        return [self.expert_share ** i for i in range(self.iterations)]


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
    algo: Literal["td3", "ppo", "sac"] = "td3"  # stable-baselines3's algorithm; its section holds its settings
    td3: TD3Params = TD3Params()
    ppo: PPOParams = PPOParams()
    sac: SACParams = SACParams()
    n_envs: int = Field(1, ge=1, le=1024)  # episodes stepped at once (> 1: the batched vector env)
    pretrain: PretrainParams | None = None
    keep: Literal["final", "best"] = "final"  # model.zip: the final model, or the best of the periodic evaluations
    eval: EvalParams = EvalParams()
    checkpoint_freq: int = Field(5000, ge=1)
    log_interval: int = Field(100, ge=1)  # episodes between TensorBoard rollout records
    threads: int | None = Field(1, ge=1, le=1024)  # torch threads while training; None: torch's choice
    service: ServiceParams = ServiceParams()
    tracking: TrackingParams = TrackingParams()  # MLflow, when set (farm.core.tracking); no part of the run's identity

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

    @model_validator(mode="after")
    def _sections_of_algo(self):
        # Another algorithm's section is ignored when algo is named (an experiment may grid over
        # algo with settings for each); without algo it is a forgotten `algo:`.
        for other in ALGOS:
            if other != self.algo and other in self.model_fields_set and "algo" not in self.model_fields_set:
                raise ValueError(f"{other}: settings of {other}, but algo is {self.algo} by default "
                                 f"(set algo: {other})")
        if self.pretrain is not None and self.pretrain.maps and not (self.algo == "ppo"
                                                                    and self.ppo.policy == "CellPolicy"):
            raise ValueError("pretrain.maps: a curriculum of maps needs a policy whose weights fit any map "
                             "(algo: ppo with ppo.policy: CellPolicy)")
        if self.algo == "ppo" and self.ppo.n_steps * self.n_envs < 2:
            raise ValueError(f"ppo.n_steps: a rollout of n_steps x n_envs = {self.ppo.n_steps * self.n_envs} "
                             f"step; PPO needs at least 2")
        return self

    @property
    def learner(self) -> TD3Params | PPOParams | SACParams:
        """The chosen algorithm's section."""
        return getattr(self, self.algo)

    def envs(self) -> list[AllocConfig]:
        """Every map the run plays: its env, then its pretraining curriculum's (pretrain.maps,
        the run's service games and seed), whose lattices are warmed before training."""
        maps = self.pretrain.maps if self.pretrain is not None else []
        return [self.env, *(m.config(games=self.env.games, seed=self.env.seed) for m in maps)]

    def with_timesteps(self, n: int) -> "TrainConfig":
        """This config with the learner's n_timesteps set to n."""
        return self.model_copy(update={self.algo: self.learner.model_copy(update={"n_timesteps": n})})

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
