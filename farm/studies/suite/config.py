"""A `farm suite` config (SuiteConfig, load_suite_config); docs/suite.md shows one and says how
a suite runs."""

from __future__ import annotations

from typing import Any

from pydantic import Field, ValidationError, field_validator, model_validator

from farm.alloc.allocators import allocator_entry, allocator_names
from farm.alloc.game.config import AllocConfig
from farm.alloc.game.scenarios import SCENARIOS
from farm.core.config import StrictFile, first_line, load_yaml_model

__all__ = ["SuiteConfig", "load_suite_config", "available_policies"]


def available_policies() -> list[str]:
    """The allocators a suite may list: every registered baseline and planner, in registration order."""
    return allocator_names(("baseline", "planner"))


def _choices(names) -> str:
    return ", ".join(names) if names else "none"


def _known(names: list[str] | None, choices: list[str], what: str, hint=lambda name: "") -> list[str] | None:
    """names (None: the default) checked against choices: at least one, each a choice, none twice;
    ValueError naming the first that is not, the choices and hint(name)."""
    if names is None:
        return names
    if not names:
        raise ValueError(f"must name at least one {what} (choose from {_choices(choices)})")
    for name in names:
        if name not in choices:
            raise ValueError(f"unknown {what} {name!r} (choose from {_choices(choices)}){hint(name)}")
    _no_repeats(names)
    return names


class SuiteConfig(StrictFile):
    """A `farm suite` config (see the module doc); ConfigError or ValidationError, one line
    naming the field, the bad value and the choices, for bad input."""

    KIND = "a suite"

    # the suite's name: the leaderboard plot's title and suite.json's name
    name: str = Field("suite", min_length=1, max_length=100, pattern=r"^[A-Za-z0-9_.-]+$")
    scenarios: list[str] | None = None  # None: every scenario
    policies: list[str] | None = None  # None: every baseline and every planner
    planner_options: dict[str, dict[str, Any]] = {}  # planner -> its options (keyword arguments)
    episodes: int = Field(10, ge=1, le=100_000)  # episodes per (scenario, policy), the same for every policy
    seed: int = Field(1000, ge=0)  # episode k is seeded seed + k
    store: str | None = Field(None, min_length=1)  # None: farm.service.store.default_store_path()
    env: dict[str, Any] = {}  # AllocConfig settings replacing every scenario's
    runs: dict[str, str] = {}  # scenario -> TD3 run folder
    skip_missing_runs: bool = False  # true: a run folder without model.zip is skipped; false: an error
    # intruder policies every allocator meets (an adversary axis: the leaderboard's worst case over them);
    # None: each scenario's own intruders
    intruders: list[str] | None = None

    @field_validator("scenarios")
    @classmethod
    def _known_scenarios(cls, v):
        return _known(v, list(SCENARIOS), "scenario")

    @field_validator("policies")
    @classmethod
    def _known_policies(cls, v):
        return _known(v, available_policies(), "policy",
                      hint=lambda name: "; trained runs come from `runs`" if name in allocator_names("learned") else "")

    @field_validator("intruders")
    @classmethod
    def _known_intruders(cls, v):
        from farm.alloc.intruders import intruder_names

        return _known(v, intruder_names(("law", "heuristic")), "intruder policy")

    @model_validator(mode="after")
    def _consistent(self):
        scenarios = self.scenario_names()
        for name, path in self.runs.items():
            if name not in scenarios:
                raise ValueError(f"runs.{name}: not a scenario of this suite, got {name!r} "
                                 f"(choose from {_choices(scenarios)})")
            if not path.strip():
                raise ValueError(f"runs.{name}: an empty folder name")
        policies = self.allocator_names()
        planners = [name for name in policies if allocator_entry(name).options()]
        for name, options in self.planner_options.items():
            if name not in planners:
                raise ValueError(f"planner_options.{name}: {name!r} is not a planner of this suite "
                                 f"(choose from {_choices(planners)})")
            allowed = allocator_entry(name).options()
            for option in options:
                if option not in allowed:
                    raise ValueError(f"planner_options.{name}: unknown option {option!r} "
                                     f"(choose from {_choices(allowed)})")
        for name in scenarios:
            self.env_of(name)
        return self

    def scenario_names(self) -> list[str]:
        """The scenarios run, in order (every scenario when the config names none)."""
        return list(self.scenarios) if self.scenarios is not None else list(SCENARIOS)

    def allocator_names(self) -> list[str]:
        """The baselines and planners run, in order (all of them when the config names none)."""
        if self.policies is not None:
            return list(self.policies)
        return allocator_names(("baseline", "planner"), references=True)

    def intruder_axis(self) -> list[str | None]:
        """The intruder policies of the adversary axis, [None] without one (each scenario's own)."""
        return list(self.intruders) if self.intruders is not None else [None]

    def env_of(self, scenario: str, intruders: str | None = None) -> AllocConfig:
        """The env settings of one scenario in this suite: the scenario's, `env` replacing them, and
        the intruder policy `intruders` (None: theirs).

        ValueError (one line, `env.<field>: ...`, naming the scenario) for a setting refused.
        """
        settings = self.env if intruders is None else {**self.env, "intruders": intruders}
        try:
            return SCENARIOS[scenario].config(**settings)
        except ValidationError as e:
            raise ValueError(f"env.{first_line(e)} (in scenario {scenario})") from None


def _no_repeats(names: list[str]) -> None:
    seen = set()
    for name in names:
        if name in seen:
            raise ValueError(f"{name!r} is named twice")
        seen.add(name)


def load_suite_config(path) -> SuiteConfig:
    """Read and validate a suite YAML; ConfigError of one line naming the file and the field."""
    return load_yaml_model(path, SuiteConfig, "suite")

