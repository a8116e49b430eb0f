"""A `farm robust` config (RobustConfig, load_robust_config): the meta-game's map, its two starting
populations, how payoffs are played, the oracles and the loop's budget; docs/robust.md shows one."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, field_validator, model_validator

from farm.core.checks import whole
from farm.core.config import Strict, StrictFile, load_yaml_model

__all__ = ["RobustConfig", "load_robust_config", "PayoffParams", "LibraryParams", "TrainingParams", "FloorParams"]


class PayoffParams(Strict):
    """How a pair's payoff is played: episodes seeded seed .. seed + episodes - 1, and the measure
    the meta-game is zero-sum in (eliminated mass or the defenders' return)."""

    episodes: int = Field(20, ge=1, le=10_000)  # episodes a pair plays
    seed: int = Field(2000, ge=0)  # the pairs' episodes are seeded seed .. seed + episodes - 1
    measure: Literal["eliminated", "return"] = "eliminated"  # the defenders' payoff: eliminated mass or return


class LibraryParams(Strict):
    """The library oracle's candidates (double oracle over a fixed set): each side's best response
    is its candidate, or member, doing best against the other side's meta-Nash mixture."""

    allocators: list[Any] = []  # candidate allocators: names or {name, options, label}
    intruders: list[Any] = []  # candidate intruder policies: names or {name, options, label}


class FloorParams(Strict):
    """A floor under the allocators' mixture in the drift case: against the intruder member
    `intruders` it keeps at least the payoff of the allocator member `allocator` there, less margin.
    The meta-solver then maximises the worst case under that constraint, and the defenders' oracle
    answers the intruders' mixture with the floor's price on the drift case
    (farm.core.matrix_game)."""

    allocator: str = "receding_horizon"  # the reference: a starting allocator, as tables show it
    intruders: str = "drift"  # the intruder member the floor holds against: a starting one, as tables show it
    margin: float = Field(0.05, ge=0, le=1)  # how far below the reference's payoff the floor is


class TrainingParams(Strict):
    """The trained oracles: dotted TrainConfig settings of each side's best response (the loop sets
    the scenario, the seed, the side, the opponent mixture and the name)."""

    # dotted TrainConfig settings of the defenders' best response (DAgger from a planner, PPO, the level repair)
    defenders: dict[str, Any] = {
        "algo": "ppo", "ppo.n_timesteps": 20000, "ppo.n_steps": 256, "ppo.batch_size": 256, "n_envs": 8,
        "pretrain": {"expert": "receding_horizon", "iterations": 2, "episodes": 32, "expert_share": 0.5},
        "repair": "levels", "keep": "best", "eval.freq": 5000}
    # dotted TrainConfig settings of the intruders' best response (side: intruders)
    intruders: dict[str, Any] = {"algo": "ppo", "ppo.n_timesteps": 20000, "ppo.n_steps": 256, "ppo.batch_size": 256,
                                 "n_envs": 8, "eval.freq": 5000}


class RobustConfig(StrictFile):
    """A `farm robust` config (see the module doc); one line naming the field for bad input."""

    KIND = "a robust"

    name: str = Field(min_length=1, max_length=80, pattern=r"^[A-Za-z0-9_.-]+$")  # the run's name
    scenario: str  # a suite scenario: the map, its teams and reward
    env: dict[str, Any] = {}  # AllocConfig settings over the scenario's (information: follower or simultaneous)
    seed: int = Field(0, ge=0)  # seeds the oracles' trainings
    # the allocators' starting population: names or {name, options, label}
    allocators: list[Any] = ["intercept", "mmr", "receding_horizon", "transport", "spread_evenly"]
    # the intruders' starting population: names or {name, options, label}
    intruders: list[Any] = ["drift", "fewest_ahead", "least_defended", "split_away"]
    iterations: int = Field(4, ge=0, le=100)  # oracle iterations at most
    threshold: float | None = Field(None, ge=0)  # stop once NashConv is at most this; None: run every iteration
    payoffs: PayoffParams = PayoffParams()  # how a pair's payoff is played
    # the defenders' oracle (and the intruders' unless intruders_oracle says otherwise): trained best responses,
    # or the best of a fixed library
    oracle: Literal["trained", "library"] = "trained"
    # the intruders' best response: the same oracle as the defenders' (oracle), trained, the best of the library,
    # or `search` intruders planning against the allocators' mixture (its support as their model;
    # farm.alloc.intruders.searching), on maps whose search tree fits
    intruders_oracle: Literal["oracle", "trained", "library", "search"] = "oracle"
    # trained oracles: seeds of each side's best response trained an iteration, the one gaining most kept
    responses: int = Field(1, ge=1, le=9)
    # each iteration's allocators' mixture valued against the intruders' exact best response, on maps whose
    # search tree fits (auto), or never; it bounds the trained intruders' gain (farm.studies.robust.exact)
    exact: Literal["auto", "never"] = "auto"
    library: LibraryParams = LibraryParams()  # the library oracle's candidates
    # the allocators' mixture held to the reference allocator's payoff against one intruder member (drift), less a
    # margin; None: no floor (the plain meta-Nash)
    floor: FloorParams | None = None
    training: TrainingParams = TrainingParams()  # the trained oracles' settings
    # one network distilled from the final allocators' mixture: dotted TrainConfig settings of a training
    # DAgger-started from the mixture's mean move against the final intruders' mixture; None: none
    distill: dict[str, Any] | None = {
        "algo": "ppo", "ppo.n_timesteps": 20000, "ppo.n_steps": 256, "ppo.batch_size": 256, "n_envs": 8,
        "pretrain": {"expert": "mixture", "iterations": 3, "episodes": 32, "expert_share": 0.5},
        "repair": "levels", "keep": "best", "eval.freq": 5000}
    store: str | None = Field(None, min_length=1)  # the capture-time store; None: default_store_path()

    @field_validator("scenario")
    @classmethod
    def _known_scenario(cls, v):
        from farm.alloc.game.scenarios import known_scenario

        return known_scenario(v)

    @model_validator(mode="after")
    def _members(self):
        from farm.studies.robust.members import check_member, member_of

        env = self.alloc_config()  # the env settings: one line naming the field
        for side in ("allocators", "intruders"):
            values = getattr(self, side)
            if not values:
                raise ValueError(f"{side}: the population needs one member at least")
            for field, v in [(f"{side}[{i}]", v) for i, v in enumerate(values)] + \
                    [(f"library.{side}[{i}]", v) for i, v in enumerate(getattr(self.library, side))]:
                check_member(member_of(side, v, field), env, field)
        if self.floor is not None:
            for side, name in (("allocators", self.floor.allocator), ("intruders", self.floor.intruders)):
                shown = [m.shown() for m in self.population(side)]
                if name not in shown:
                    raise ValueError(f"floor: {name!r} is not one of the starting {side} ({', '.join(shown)})")
        if self.intruders_oracle == "search":
            from farm.studies.robust.exact import deterministic, searchable

            drawing = [m.shown() for m in self.population("allocators") + self.candidates("allocators")
                       if not deterministic(m)]
            if drawing:
                raise ValueError(f"intruders_oracle: search models deterministic allocators; {drawing[0]} draws its "
                                 f"moves (list its members instead)")
            if not searchable(self.alloc_config(), self.payoffs.episodes, self.payoffs.seed):
                raise ValueError(f"intruders_oracle: search: the search tree of {self.scenario} does not fit the "
                                 f"search's budget (use the oracle's intruders)")
        return self

    def oracle_of(self, side: str) -> str:
        """The oracle of a side (allocators or intruders): trained, library or search."""
        if side == "allocators" or self.intruders_oracle == "oracle":
            return self.oracle
        return self.intruders_oracle

    def trained_sides(self) -> list[str]:
        """The sides whose best responses are trained, allocators first."""
        return [side for side in ("allocators", "intruders") if self.oracle_of(side) == "trained"]

    def floor_of(self, M, allocators: list, intruders: list) -> tuple[int, float] | None:
        """The meta-solver's floor over the payoff matrix M: (len(allocators), len(intruders)) float64
        of these populations: (the floor's intruder column, the reference's payoff there less the
        margin), or None without a floor."""
        if self.floor is None:
            return None
        i = [a.shown() for a in allocators].index(self.floor.allocator)
        j = [b.shown() for b in intruders].index(self.floor.intruders)
        return j, float(M[i, j]) - self.floor.margin

    def alloc_config(self):
        """The map's AllocConfig: the scenario's settings with `env` over them."""
        from farm.alloc.game.scenarios import SCENARIOS

        return SCENARIOS[self.scenario].config(**self.env)

    def with_seed(self, seed: int) -> RobustConfig:
        """This config with the loop's seed set to seed and _s<seed> added to its name (the runs of
        one config over seeds side by side); ConfigError naming seed unless a whole number >= 0."""
        whole("seed", seed)
        return self.model_copy(update={"seed": seed, "name": f"{self.name}_s{seed}"})

    def population(self, side: str) -> list:
        """The starting members of a side (farm.studies.robust.members.Member)."""
        from farm.studies.robust.members import member_of

        return [member_of(side, v, side) for v in getattr(self, side)]

    def candidates(self, side: str) -> list:
        """The library oracle's candidates of a side."""
        from farm.studies.robust.members import member_of

        return [member_of(side, v, f"library.{side}") for v in getattr(self.library, side)]


def load_robust_config(path) -> RobustConfig:
    """Read and validate a robust YAML; ConfigError of one line naming the file and the field."""
    return load_yaml_model(path, RobustConfig, "robust")
