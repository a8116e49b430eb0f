"""A `farm train` config: TrainConfig and its sections (the learner's: TD3Params, PPOParams or
SACParams under `algo`; PretrainParams, OpponentParams, EvalParams, ServiceParams, TrackingParams), read with
load_train_config;
every default in one place (docs/training.md shows a config)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, ClassVar, Literal

from pydantic import Field, field_validator, model_serializer, model_validator

from farm.alloc.envs.intruders import DEFAULT_OPPONENT, REWARDS
from farm.alloc.game.config import AllocConfig
from farm.alloc.game.scenarios import SCENARIOS, known_scenario
from farm.core.checks import flag, is_finite_number, is_whole, whole
from farm.core.config import ConfigError, Strict, load_yaml_model
from farm.core.tracking import TrackingParams

__all__ = ["ALGOS", "SIDES", "TD3Params", "PPOParams", "SACParams", "PretrainParams", "OpponentParams", "EvalParams",
           "ServiceParams", "TrainConfig", "load_train_config", "store_of", "POLICY_KWARGS", "check_trainable",
           "check_allocators", "check_pretrain_memory", "pretrain_bytes"]

ALGOS = ("td3", "ppo", "sac")  # stable-baselines3's algorithms a config may name (`algo`)
SIDES = ("defenders", "intruders")  # the side a run trains (`side`)

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
# CellPolicy's (farm.alloc.networks.cell_policy, PPO only): its sizes and ActorCriticPolicy's plain values
CELL_POLICY_KWARGS = ("channels", "layers", "positions", "lateral", "balance", "log_std_init", "ortho_init",
                      "optimizer_kwargs")
ACTIVATIONS = ("relu", "tanh", "elu", "leaky_relu", "gelu")  # torch.nn's ReLU, Tanh, ELU, LeakyReLU, GELU


def _check_net_arch(sizes) -> None:
    """ValueError unless sizes, policy_kwargs' net_arch, is None, a list of layer sizes (whole
    numbers >= 1), or a mapping of pi, qf and vf to such lists."""
    layers = ([] if sizes is None else sizes.values() if isinstance(sizes, dict) and set(sizes) <= {"pi", "qf", "vf"}
              else [sizes])
    for layer in layers:
        if not isinstance(layer, list) or not all(is_whole(x, numpy=False) and x >= 1 for x in layer):
            raise ValueError(f"net_arch: must be a list of layer sizes >= 1 (or {{pi: [...], qf: [...]}}, vf for ppo), "
                             f"got {sizes!r}")


def _check_adam(adam) -> None:
    """ValueError unless adam, policy_kwargs' optimizer_kwargs, is a mapping of Adam's betas (two
    numbers in [0, 1)), eps and weight_decay (numbers >= 0) and amsgrad (true or false)."""
    if not isinstance(adam, dict) or not set(adam) <= {"betas", "eps", "weight_decay", "amsgrad"}:
        raise ValueError(f"optimizer_kwargs: must be a mapping of Adam's betas, eps, weight_decay or amsgrad, "
                         f"got {adam!r}")
    betas = adam.get("betas", (0.9, 0.999))
    if not (isinstance(betas, (list, tuple)) and len(betas) == 2
            and all(is_finite_number(b) and 0 <= b < 1 for b in betas)):
        raise ValueError(f"optimizer_kwargs.betas: must be two numbers in [0, 1), got {betas!r}")
    for name in ("eps", "weight_decay"):
        if name in adam and not (is_finite_number(adam[name]) and adam[name] >= 0):
            raise ValueError(f"optimizer_kwargs.{name}: must be a number >= 0, got {adam[name]!r}")
    flag("optimizer_kwargs.amsgrad", adam.get("amsgrad", False), error=ValueError)


def _check_policy_kwargs(v: dict, algo: str, policy: str = "MlpPolicy") -> dict:
    """policy_kwargs of algo's SB3 policy as a config may set them (POLICY_KWARGS; CellPolicy's:
    CELL_POLICY_KWARGS), checked."""
    allowed = CELL_POLICY_KWARGS if policy == "CellPolicy" else POLICY_KWARGS[algo]
    unknown = sorted(set(v) - set(allowed))
    if unknown:
        what = "CellPolicy" if policy == "CellPolicy" else f"{algo.upper()} policy"
        raise ValueError(f"{unknown[0]}: not a {what} argument a config can set (choose from {', '.join(allowed)})")
    for name in ("channels", "layers"):
        if name in v and not (is_whole(v[name], numpy=False) and 1 <= v[name] <= 512):
            raise ValueError(f"{name}: must be a whole number from 1 to 512, got {v[name]!r}")
    for name in ("positions", "lateral", "balance", "share_features_extractor", "normalize_images", "ortho_init",
                 "full_std", "use_expln", "squash_output"):
        if name in v:
            flag(name, v[name], error=ValueError)
    _check_net_arch(v.get("net_arch"))
    if "n_critics" in v:
        whole("n_critics", v["n_critics"], 1, error=ValueError)
    _check_adam(v.get("optimizer_kwargs") or {})
    if "activation_fn" in v and v["activation_fn"] not in ACTIVATIONS:
        raise ValueError(f"activation_fn: must be one of {', '.join(ACTIVATIONS)}, got {v['activation_fn']!r}")
    for name in ("log_std_init", "clip_mean"):
        if name in v and not is_finite_number(v[name]):
            raise ValueError(f"{name}: must be a number, got {v[name]!r}")
    return v


class _Params(Strict):
    """What every algorithm's section has: its length, and the policy_kwargs of its SB3 policy
    (checked for ALGO's policy, _check_policy_kwargs)."""

    ALGO: ClassVar[str] = ""

    n_timesteps: int = Field(30_000, ge=1)  # env steps to train for (SB3's total_timesteps)
    policy: Literal["MlpPolicy"] = "MlpPolicy"  # the SB3 policy class

    @field_validator("policy_kwargs", check_fields=False)
    @classmethod
    def _policy_kwargs(cls, v, info):
        return _check_policy_kwargs(v, cls.ALGO, info.data.get("policy", "MlpPolicy"))


class _OffPolicyParams(_Params):
    """The settings TD3 and SAC share (stable-baselines3's OffPolicyAlgorithm's)."""

    learning_rate: float = Field(1e-3, gt=0)  # Adam's learning rate
    buffer_size: int = Field(200_000, ge=1)  # the replay buffer's capacity (transitions)
    learning_starts: int = Field(1000, ge=0)  # steps of random actions collected before the first update
    batch_size: int = Field(256, ge=1)  # transitions per minibatch of a gradient step
    tau: float = Field(0.005, gt=0, le=1)  # soft (Polyak) update coefficient of the target networks
    gamma: float = Field(0.95, ge=0, le=1)  # discount factor
    train_freq: int = Field(1, ge=1)  # env steps between model updates
    gradient_steps: int = Field(1, ge=-1)  # gradient steps per update; -1: as many as the steps collected

    @field_validator("gradient_steps")
    @classmethod
    def _some_gradient_steps(cls, v):
        if v == 0:
            raise ValueError("must be -1 (as many as the rollout's steps) or >= 1; 0 never updates the model")
        return v

    @model_validator(mode="after")
    def _can_train(self):
        # SB3 samples a minibatch from the buffer: a buffer that cannot hold two distinct
        # transitions, or a minibatch larger than it, repeats transitions in every update.
        if self.buffer_size < 2:
            raise ValueError(f"buffer_size: a replay buffer of {self.buffer_size} transition cannot hold a "
                             f"minibatch of distinct transitions (at least 2)")
        if self.batch_size > self.buffer_size:
            raise ValueError(f"batch_size: minibatches of {self.batch_size} transitions from a buffer of "
                             f"{self.buffer_size} (buffer_size) repeat transitions; at most buffer_size")
        return self


class TD3Params(_OffPolicyParams):
    """stable-baselines3 TD3's hyperparameters, RL-Zoo style."""

    ALGO: ClassVar[str] = "td3"

    policy_delay: int = Field(2, ge=1)  # critic updates per actor (and target) update
    noise_type: Literal["normal", "none"] = "normal"  # exploration noise added to actions: Gaussian, or none
    noise_std: float = Field(0.2, ge=0)  # standard deviation of the Gaussian action noise
    policy_kwargs: dict[str, Any] = {"net_arch": [400, 300]}  # SB3 policy arguments: POLICY_KWARGS["td3"]


class PPOParams(_Params):
    """stable-baselines3 PPO's hyperparameters, RL-Zoo style (SB3's defaults, but gamma and the
    rollout's length, which suit episodes of 12 to 16 steps)."""

    ALGO: ClassVar[str] = "ppo"

    n_timesteps: int = Field(100_000, ge=1)
    policy: Literal["MlpPolicy", "CellPolicy"] = "MlpPolicy"  # CellPolicy: farm.alloc.networks.cell_policy
    learning_rate: float = Field(3e-4, gt=0)  # Adam's learning rate
    n_steps: int = Field(256, ge=1)  # per env: a rollout is n_steps x n_envs steps
    batch_size: int = Field(64, ge=2)  # minibatch size
    n_epochs: int = Field(10, ge=1)  # passes over each rollout
    gamma: float = Field(0.99, ge=0, le=1)  # discount factor
    gae_lambda: float = Field(0.95, ge=0, le=1)  # lambda of the generalised advantage estimate
    clip_range: float = Field(0.2, gt=0)  # the probability ratio is clipped to 1 +- clip_range
    ent_coef: float = Field(0.0, ge=0)  # weight of the entropy bonus in the loss
    vf_coef: float = Field(0.5, ge=0)  # weight of the value function's loss
    max_grad_norm: float = Field(0.5, gt=0)  # gradients are clipped to this norm
    target_kl: float | None = Field(None, gt=0)  # an update stops past KL 1.5 x target_kl; None: no limit
    normalize_advantage: bool = True  # normalise the advantages of each minibatch
    policy_kwargs: dict[str, Any] = {}  # SB3 policy arguments: POLICY_KWARGS["ppo"] (CellPolicy: CELL_POLICY_KWARGS)


class SACParams(_OffPolicyParams):
    """stable-baselines3 SAC's hyperparameters, RL-Zoo style (SB3's defaults, but gamma, the
    buffer and the warm-up, as TD3's here)."""

    ALGO: ClassVar[str] = "sac"

    learning_rate: float = Field(3e-4, gt=0)
    ent_coef: float | Literal["auto"] = "auto"  # a number: fixed; auto: learned, starting at 1
    target_entropy: float | Literal["auto"] = "auto"  # the learned ent_coef's entropy target; auto: -(action size)
    policy_kwargs: dict[str, Any] = {"net_arch": [400, 300]}  # SB3 policy arguments: POLICY_KWARGS["sac"]

    @field_validator("ent_coef")
    @classmethod
    def _positive_ent_coef(cls, v):
        if v != "auto" and v < 0:
            raise ValueError(f"must be 'auto' or a number >= 0, got {v!r}")
        return v


class MapParams(Strict):
    """One map of a pretraining curriculum (pretrain.maps): a suite scenario, its env settings
    replaced by `env`'s (AllocConfig fields), as a training config's `scenario` and `env`."""

    scenario: str  # a suite scenario's name (farm.alloc.game.scenarios.SCENARIOS)
    env: dict[str, Any] = {}  # AllocConfig settings replacing the scenario's

    @field_validator("scenario")
    @classmethod
    def _known(cls, v):
        return known_scenario(v)

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
    """Planner-guided pretraining (DAgger; farm.alloc.training.dagger.loop): before RL, the learner's
    actor is fitted to an expert's actions on the states visited by a mixture of the expert and
    the learner, then RL fine-tunes from there.

    expert: an allocator of the registry (farm.alloc.allocators: any planner or baseline) and
    expert_options its options; iterations: DAgger iterations; episodes: episodes played per
    iteration; expert_share: the share of steps the expert drives in each iteration (one number
    per iteration, or one number p for the schedule 1, p, p^2, ...: the first iteration is the
    expert's alone); epochs, batch_size, learning_rate: the fit of each iteration (mean squared
    error to the expert's actions, Adam) over the states labelled so far; episodes_per_task:
    the episodes of one labelling task (on Ray: one task per batch of episodes); maps: suite
    scenarios whose episodes are labelled too, each iteration's `episodes` on each, and fitted
    with the run's own (a curriculum of maps, for a policy whose weights fit any map:
    ppo.policy CellPolicy)."""

    expert: str = "receding_horizon"  # the expert: a registered baseline, planner or mixture (farm.alloc.allocators)
    expert_options: dict[str, Any] = {}  # the expert's options
    iterations: int = Field(4, ge=1, le=1000)  # DAgger iterations
    episodes: int = Field(16, ge=1)  # episodes played per iteration (on each map)
    expert_share: float | list[float] = 0.5  # expert's share of steps: one per iteration, or p for 1, p, p^2, ...
    loss: Literal["flows", "actions"] = "flows"  # flows: density-weighted move cross-entropy; actions: MSE
    epochs: int = Field(30, ge=1)  # epochs of each iteration's fit over the labels so far
    batch_size: int = Field(128, ge=1)  # minibatch size of the fit
    learning_rate: float = Field(1e-3, gt=0)  # Adam's learning rate of the fit
    episodes_per_task: int = Field(4, ge=1)  # episodes of one labelling task (a Ray task on the farm)
    maps: list[MapParams] = []  # suite scenarios labelled too, a curriculum (ppo.policy CellPolicy only)

    @field_validator("maps", mode="before")
    @classmethod
    def _names_are_maps(cls, v):
        return [{"scenario": m} if isinstance(m, str) else m for m in v] if isinstance(v, list) else v

    @field_validator("expert")
    @classmethod
    def _known_expert(cls, v):
        from farm.alloc.allocators import allocator_names

        choices = allocator_names(("baseline", "planner", "mixture"))
        if v not in choices:
            raise ValueError(f"unknown expert {v!r} (choose from the baselines, the planners and mixture: "
                             f"{', '.join(choices)})")
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


class OpponentParams(Strict):
    """The game a `side: intruders` run trains the intruders in (farm.alloc.envs.intruders): the frozen
    allocator they play against, an allocator of the registry (farm.alloc.allocators: a baseline, a
    planner, or a learned one, e.g. `name: ppo` with `options: {run: FOLDER}`), and their reward."""

    name: str = DEFAULT_OPPONENT  # the frozen allocator (farm.alloc.allocators' registry)
    options: dict[str, Any] = {}  # its options (a learned allocator's run folder: run)
    # the intruders' action: shares (each cell's shares of its routes) or pure (one route a cell)
    actions: Literal["shares", "pure"] = "shares"
    reward: Literal[REWARDS] = "eliminated"  # eliminated: minus the mass eliminated; zero_sum: minus the defenders'

    @field_validator("name")
    @classmethod
    def _known_allocator(cls, v):
        from farm.alloc.allocators import allocator_names

        if v not in allocator_names():
            raise ValueError(f"unknown allocator {v!r} (choose from {', '.join(allocator_names())})")
        return v


class EvalParams(Strict):
    """The periodic evaluation during training (SB3's EvalCallback)."""

    freq: int = Field(2000, ge=1)  # env steps (all envs) between periodic evaluations
    episodes: int = Field(10, ge=1)  # episodes of each periodic evaluation (and of the pretrained model's)


class ServiceParams(Strict):
    """Where training's capture-time statistics come from (farm.service.lookup.open_client)."""

    mode: Literal["ray", "local"] = "ray"  # ray: the service actor on a Ray cluster; local: in-process lookup
    store: str | None = Field(None, min_length=1)  # None: farm.service.store.default_store_path()
    address: str | None = None  # the Ray cluster to join; None: $RAY_ADDRESS, else a local Ray
    warm_lattice: bool = True  # compute the lattice pairs of every map (team_sizes lattice) first
    # During training (its steps and its periodic evaluations), a first visit's outcome comes
    # from an interpolation while the exact value is computed in the background (farm eval
    # afterwards is exact). true: the service's interpolation of what it has computed by then
    # (which visits, and from what, depends on timing); lattice: every pair off the lattice is
    # interpolated from its lattice anchors, computed exactly (reproducible: CaptureTimeClient.
    # lattice_estimates).
    estimates: bool | Literal["lattice"] = False


class TrainConfig(Strict):
    """A `farm train` config (see the module doc)."""

    # the run's name: the default run folder results/runs/NAME, and MLflow's run and experiment
    name: str = Field(min_length=1, max_length=100, pattern=r"^[A-Za-z0-9_.-]+$")
    seed: int = Field(0, ge=0)  # seeds the learner, the envs' episodes and the evaluations
    scenario: str | None = None  # SCENARIOS' name: its env settings are the base of `env`
    env: AllocConfig = AllocConfig()  # the allocation env's settings (over the scenario's)
    algo: Literal["td3", "ppo", "sac"] = "td3"  # stable-baselines3's algorithm; its section holds its settings
    td3: TD3Params = TD3Params()  # TD3's settings (algo td3)
    ppo: PPOParams = PPOParams()  # PPO's settings (algo ppo)
    sac: SACParams = SACParams()  # SAC's settings (algo sac)
    n_envs: int = Field(1, ge=1, le=1024)  # episodes stepped at once (> 1: the batched vector env)
    pretrain: PretrainParams | None = None  # planner-guided pretraining before RL; None: none
    keep: Literal["final", "best"] = "final"  # model.zip: the final model, or the best of the periodic evaluations
    # the side trained: the defenders (an allocator), or the intruders (their routing, farm.alloc.envs.intruders)
    # against the frozen allocator of `opponent`; side and opponent are written out only when set
    side: Literal[SIDES] = "defenders"
    opponent: OpponentParams = OpponentParams()  # side intruders: the allocator they play and their reward
    # how the trained allocator acts, in the periodic evaluations and after: its network's action (none),
    # or that action moved onto the game levels it almost plays (levels: farm.alloc.allocators.repair)
    repair: Literal["none", "levels"] = "none"
    eval: EvalParams = EvalParams()  # the periodic evaluation during training
    checkpoint_freq: int = Field(5000, ge=1)  # env steps between checkpoints (what --resume goes on from)
    log_interval: int = Field(100, ge=1)  # episodes between TensorBoard rollout records
    threads: int | None = Field(1, ge=1, le=1024)  # torch threads while training; None: torch's choice
    service: ServiceParams = ServiceParams()  # where the capture-time statistics come from
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
        if self.algo in ("td3", "sac") and self.learner.buffer_size // self.n_envs < 1:
            raise ValueError(f"{self.algo}.buffer_size: {self.learner.buffer_size} transitions over n_envs = "
                             f"{self.n_envs} envs leave none for each (SB3 splits the buffer between them)")
        if self.algo == "ppo" and self.ppo.n_steps * self.n_envs < 2:
            raise ValueError(f"ppo.n_steps: a rollout of n_steps x n_envs = {self.ppo.n_steps * self.n_envs} "
                             f"step; PPO needs at least 2")
        return self

    @model_validator(mode="after")
    def _side(self):
        """What the intruders' side refuses: the allocator's pretraining, repair and CellPolicy, and
        intruders of the env's own; an opponent is the intruders' side's alone."""
        if self.side == "defenders":
            if self.opponent != OpponentParams():
                raise ValueError("opponent: the frozen allocator is for side: intruders (the defenders' intruders "
                                 "are env.intruders)")
            return self
        if self.pretrain is not None:
            raise ValueError("pretrain: planner-guided pretraining imitates an allocator; side: intruders has none")
        if self.repair != "none":
            raise ValueError("repair: the level repair moves an allocator's action; side: intruders has none")
        if self.algo == "ppo" and self.ppo.policy == "CellPolicy":
            raise ValueError("ppo.policy: CellPolicy scores the defenders' moves; side: intruders takes MlpPolicy")
        if self.env.intruders != "drift":
            raise ValueError(f"env.intruders: side: intruders trains the intruders' routing; leave env.intruders at "
                             f"drift, got {self.env.intruders!r}")
        return self

    @model_serializer(mode="wrap")
    def _without_default_side(self, handler):
        """The config as written (config.yaml, an experiment's trials): side and opponent only on the
        intruders' side (a defenders' run is written as before they existed)."""
        data = handler(self)
        if self.side == "defenders":
            data.pop("side", None)
            data.pop("opponent", None)
        return data

    @property
    def learner(self) -> TD3Params | PPOParams | SACParams:
        """The chosen algorithm's section."""
        return getattr(self, self.algo)

    @property
    def replay_buffer(self) -> bool:
        """Whether the algorithm learns from a replay buffer (TD3, SAC), which its checkpoints hold; PPO has none."""
        return self.algo != "ppo"

    def envs(self) -> list[AllocConfig]:
        """Every map the run plays: its env, then its pretraining curriculum's (pretrain.maps,
        the run's service games and seed), whose lattices are warmed before training."""
        maps = self.pretrain.maps if self.pretrain is not None else []
        return [self.env, *(m.config(games=self.env.games, seed=self.env.seed) for m in maps)]

    def with_timesteps(self, n: int) -> TrainConfig:
        """This config with the learner's n_timesteps set to n."""
        return self.model_copy(update={self.algo: self.learner.model_copy(update={"n_timesteps": n})})

    def resumes(self, before: TrainConfig) -> bool:
        """Whether a run trained with before may go on under this config: equal but for the
        length of training, the threads and the tracking."""
        def comparable(c: TrainConfig) -> dict:
            return c.with_timesteps(0).model_copy(update={"threads": None, "tracking": None}).model_dump()

        return comparable(before) == comparable(self)

    @field_validator("scenario")
    @classmethod
    def _known_scenario(cls, v):
        return v if v is None else known_scenario(v)


def check_trainable(config: TrainConfig) -> None:
    """ConfigError (one line naming the field) when an off-policy learner's run would never update
    its model (SB3 updates only once more than learning_starts steps are collected, and such a
    run would still write a model.zip as if trained), when its allocators refuse their options
    (check_allocators), or when its pretraining's labels would not fit in memory
    (check_pretrain_memory). Asked of a config a user trains (its file, an experiment's trials,
    `farm train`); not of a run's own record (its config.yaml, which a run trained in parts may
    hold). train() asks check_allocators and check_pretrain_memory of the API's TrainConfig."""
    starts = getattr(config.learner, "learning_starts", None)
    if starts is not None and starts >= config.learner.n_timesteps:
        field = f"{config.algo}.learning_starts"
        raise ConfigError(f"{field}: {starts} steps of random actions before the first update, but "
                          f"{config.algo}.n_timesteps is {config.learner.n_timesteps}: "
                          "the model would never be updated",
                          field=field)
    check_allocators(config)
    check_pretrain_memory(config)
    if config.env.intruders == "search":  # the search's tree on the run's map, before anything is written
        from farm.alloc.intruders.searching import check_searchable

        check_searchable(config.env, config.env.intruder_options.get("objective", "eliminated"))


def check_allocators(config: TrainConfig) -> None:
    """ConfigError (one line naming pretrain.expert_options or opponent.options) when the
    pretraining's expert refuses its options on a map the run plays (config.envs()), or the
    intruders' opponent on the run's map: each is built by its own checks, as the run will
    build it (farm.alloc.allocators.check_options), before anything is written."""
    from farm.alloc.game.registry import ALLOCATORS

    if config.pretrain is not None:
        for env in config.envs():
            ALLOCATORS.check_options(config.pretrain.expert, config.pretrain.expert_options, env,
                                     "pretrain.expert_options")
    if config.side == "intruders":
        ALLOCATORS.check_options(config.opponent.name, config.opponent.options, config.env, "opponent.options")


LABEL_COPIES = 4  # copies of the labels a pretraining holds at most: the data set, its concatenation, its file's two


def pretrain_bytes(config: TrainConfig) -> int:
    """What a pretraining's labels hold in memory at most, in bytes: every iteration's episodes of
    every map at max_steps states each (an observation and the next, a label and an action,
    float32; a reward and a return, float64; two flags), LABEL_COPIES times; 0 without `pretrain:`."""
    from farm.alloc.game.dynamics import n_actions

    p = config.pretrain
    if p is None:
        return 0
    per_map = [env.max_steps * (16 * env.grid_size ** 2 + 8 * n_actions(env.grid_size) + 18) for env in config.envs()]
    return LABEL_COPIES * p.iterations * p.episodes * sum(per_map)


def check_pretrain_memory(config: TrainConfig) -> None:
    """ConfigError (one line naming pretrain.episodes) when the pretraining's labels
    (pretrain_bytes) would need more than half of this machine's memory, before any episode."""
    from farm.games.sizes import memory_limit

    needed, limit = pretrain_bytes(config), memory_limit()
    if needed > limit:
        p = config.pretrain
        raise ConfigError(f"pretrain.episodes: {p.iterations} iterations of {p.episodes:,} episodes on "
                          f"{len(config.envs())} map(s) label up to {needed / 2**30:,.1f} GiB, more than half of "
                          f"this machine's memory ({limit / 2**30:,.1f} GiB); label fewer episodes",
                          field="pretrain.episodes")


def load_train_config(path, *, trainable: bool = True) -> TrainConfig:
    """Read and validate a training YAML; raises ConfigError with one line. trainable: also
    check_trainable (False for a run folder's own config.yaml)."""
    config = load_yaml_model(path, TrainConfig, "training")
    if trainable:
        try:
            check_trainable(config)
        except ConfigError as e:
            raise ConfigError(f"{path}: {e}") from None
    return config



def store_of(config: TrainConfig) -> Path:
    """The capture-time store a run uses: its config's, else the default store."""
    from farm.service.store import default_store_path

    return Path(config.service.store or default_store_path())
