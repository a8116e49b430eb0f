"""The benchmark suite's scenarios: the one definition of each, by name.

A Scenario is a name, a one-line description and the allocation env's settings (AllocConfig
keyword arguments). SCENARIOS holds them all: the paper's five runs, with the env settings of
configs/train/paper_3x3_c1_0.yaml, paper_3x3_c1_1.5.yaml, paper_3x3_100v100.yaml,
larger_5x5.yaml and larger_8x8.yaml; harder scenarios built from the model's own levers (fewer
defenders than intruders, faster intruders, vertical drift, a wide front); and the THEATRES,
wide fronts of drifting intruders on 8 x 8 to 32 x 32 maps, an episode N steps long. Every
scenario uses `team_sizes: lattice` (the 16 sizes of farm.alloc.envs.defenders.LATTICE), so it meets at
most 16 x 16 = 256 distinct games, computed once up front (farm.alloc.game.lattice.warm_lattices):
that is why the paper's runs here differ from their training configs, which use exact team
sizes (configs/train/suite_<name>.yaml trains each scenario as defined here). Each is a
gymnasium id, its intruders' env (farm.alloc.envs.intruders) another (register_scenarios). How
the harder scenarios and the theatres were chosen: docs/results.md, "How the scenarios were chosen".
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

from farm.alloc.game.config import AllocConfig

__all__ = ["Scenario", "SCENARIOS", "PAPER_SCENARIOS", "THEATRES", "ENTRY_POINT", "VECTOR_ENTRY_POINT",
           "INTRUDER_ENTRY_POINT", "INTRUDER_VECTOR_ENTRY_POINT", "known_scenario", "gym_id", "intruder_gym_id",
           "register_scenarios"]

ENTRY_POINT = "farm.alloc.envs.defenders:SwarmAllocationEnv"  # the defenders' env of every id
VECTOR_ENTRY_POINT = "farm.alloc.envs.vector:SwarmAllocationVectorEnv"  # the batched env of every id
INTRUDER_ENTRY_POINT = "farm.alloc.envs.intruders:SwarmIntruderEnv"  # the intruders' env of every intruders' id
INTRUDER_VECTOR_ENTRY_POINT = "farm.alloc.envs.intruders:SwarmIntruderVectorEnv"  # and its batched form


@dataclass(frozen=True)
class Scenario:
    """One benchmark scenario: name, a one-line description and the env's settings.

    name: the scenario's name (letters, digits, `_`, `.`), also its gymnasium id's
    (`farm/<name>-v0`); description: one line; env: AllocConfig keyword arguments, read-only.
    """

    name: str
    description: str
    env: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self):
        object.__setattr__(self, "env", MappingProxyType(dict(self.env)))

    def config(self, **overrides) -> AllocConfig:
        """The scenario's AllocConfig, settings in `overrides` replacing its own (e.g. games=4).

        A bad or contradictory setting raises pydantic's ValidationError naming the field.
        """
        return AllocConfig(**{**self.env, **overrides})

    @property
    def gym_id(self) -> str:
        """The scenario's gymnasium id, `farm/<name>-v0`."""
        return gym_id(self.name)

    @property
    def intruder_gym_id(self) -> str:
        """The gymnasium id of the scenario played by the intruders, `farm/<name>-intruders-v0`."""
        return intruder_gym_id(self.name)


def gym_id(name: str) -> str:
    """The gymnasium id of the scenario named name: `farm/<name>-v0`."""
    return f"farm/{name}-v0"


def intruder_gym_id(name: str) -> str:
    """The gymnasium id of the intruders' env (farm.alloc.envs.intruders) of the scenario named name:
    `farm/<name>-intruders-v0`."""
    return f"farm/{name}-intruders-v0"


_LATTICE = {"team_sizes": "lattice"}
_BIG = {"max_steps": 16}  # the larger maps' episodes, as configs/train/larger_*.yaml

_ALL = [
    # The paper's five runs (configs/train/<name>.yaml), on the lattice.
    Scenario("paper_3x3_c1_0", "paper fig. 6: 3x3, 100 defenders v 50 intruders, C = (1, 0)",
             {"grid_size": 3, "n_defenders": 100, "n_intruders": 50, "c_distribution": 1.0, "c_capture": 0.0,
              **_LATTICE}),
    Scenario("paper_3x3_c1_1.5", "paper fig. 7: 3x3, 100 defenders v 50 intruders, C = (1, 1.5)",
             {"grid_size": 3, "n_defenders": 100, "n_intruders": 50, "c_distribution": 1.0, "c_capture": 1.5,
              **_LATTICE}),
    Scenario("paper_3x3_100v100", "paper figs. 8-9: 3x3, 100 defenders v 100 intruders, C = (0.3, 1)",
             {"grid_size": 3, "n_defenders": 100, "n_intruders": 100, "c_distribution": 0.3, "c_capture": 1.0,
              **_LATTICE}),
    Scenario("larger_5x5", "the paper's larger map: 5x5, 100 defenders v 50 intruders, C = (1, 1.5)",
             {"grid_size": 5, **_BIG, "n_defenders": 100, "n_intruders": 50, "c_distribution": 1.0,
              "c_capture": 1.5, **_LATTICE}),
    Scenario("larger_8x8", "beyond the paper: 8x8, 800 defenders v 400 intruders, C = (1, 1.5)",
             {"grid_size": 8, **_BIG, "n_defenders": 800, "n_intruders": 400, "c_distribution": 1.0,
              "c_capture": 1.5, **_LATTICE}),
    # Harder: the model's own levers (chosen on the baselines and planners: docs/results.md).
    Scenario("outnumbered_3x3", "3x3, 4 defenders v 100 intruders: about one defender a row",
             {"grid_size": 3, "n_defenders": 4, "n_intruders": 100, "c_distribution": 1.0, "c_capture": 1.5,
              **_LATTICE}),
    Scenario("outnumbered_5x5", "5x5, 4 defenders v 200 intruders: fewer defenders than rows",
             {"grid_size": 5, **_BIG, "n_defenders": 4, "n_intruders": 200, "c_distribution": 1.0,
              "c_capture": 1.5, **_LATTICE}),
    Scenario("fast_5x5", "5x5, 12 defenders v 100 intruders twice as fast (5 s steps and windows)",
             {"grid_size": 5, **_BIG, "n_defenders": 12, "n_intruders": 100, "evader_speed": 2.0,
              "c_distribution": 1.0, "c_capture": 1.5, **_LATTICE}),
    Scenario("drift_5x5", "5x5, 20 defenders v 100 intruders drifting between rows (0.25 to each neighbour a step)",
             {"grid_size": 5, **_BIG, "n_defenders": 20, "n_intruders": 100, "vertical_drift": 0.25,
              "c_distribution": 1.0, "c_capture": 1.5, **_LATTICE}),
    Scenario("wide_front_8x8", "8x8, 6 defenders v 400 intruders: an eight-row front, fewer defenders than rows",
             {"grid_size": 8, **_BIG, "n_defenders": 6, "n_intruders": 400, "c_distribution": 1.0,
              "c_capture": 1.5, **_LATTICE}),
    # Theatres: wide fronts of drifting intruders, fewer defenders than rows, on maps of any size.
    *[Scenario(f"theatre_{n}x{n}", f"{n}x{n}, {d} defenders v {e:,} intruders drifting between rows (0.25 to each "
               "neighbour a step) on a front of " + f"{n} rows", {"grid_size": n, "max_steps": n, "n_defenders": d,
                                                                  "n_intruders": e, "vertical_drift": 0.25,
                                                                  "c_distribution": 1.0, "c_capture": 1.5, **_LATTICE})
      for n, d, e in ((8, 6, 400), (16, 10, 1600), (32, 16, 5000))],
]

SCENARIOS: dict[str, Scenario] = {s.name: s for s in _ALL}
PAPER_SCENARIOS = ("paper_3x3_c1_0", "paper_3x3_c1_1.5", "paper_3x3_100v100", "larger_5x5", "larger_8x8")
THEATRES = ("theatre_8x8", "theatre_16x16", "theatre_32x32")  # the size-free learner's maps


def known_scenario(name):
    """name, when it is a scenario's (a key of SCENARIOS); ValueError naming the choices otherwise."""
    if not isinstance(name, str) or name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r} (choose from {', '.join(SCENARIOS)})")
    return name


def register_scenarios() -> list[str]:
    """Register every scenario as the gymnasium id `farm/<name>-v0`, and its intruders' env as
    `farm/<name>-intruders-v0` (once; registering again does nothing); returns the ids, each
    scenario's two in turn.

    Each id makes farm.alloc.envs.defenders.SwarmAllocationEnv with the scenario's settings as keyword
    arguments; gymnasium.make's own keyword arguments replace them, one by one, and may add
    the env's other arguments (client, store, render_mode, estimates). Its vector entry point
    (VECTOR_ENTRY_POINT) is farm.alloc.envs.vector.SwarmAllocationVectorEnv, which
    gymnasium.make_vec(id, num_envs=B, vectorization_mode="vector_entry_point") makes with the
    same settings and keyword arguments, as RL Zoo's `env_kwargs` do. The intruders' id makes
    farm.alloc.envs.intruders.SwarmIntruderEnv (its vector entry point SwarmIntruderVectorEnv) so,
    the frozen allocator its `opponent` argument. Importing farm.alloc calls it:

        import gymnasium, farm.alloc
        env = gymnasium.make("farm/outnumbered_3x3-v0")              # the scenario as defined
        env = gymnasium.make("farm/outnumbered_3x3-v0", c_capture=0.0)  # one setting changed
        envs = gymnasium.make_vec("farm/outnumbered_3x3-v0", num_envs=16,  # 16 episodes batched
                                  vectorization_mode="vector_entry_point")
        env = gymnasium.make("farm/outnumbered_3x3-intruders-v0", opponent="stay_at_base")
    """
    import gymnasium

    ids = []
    for scenario in SCENARIOS.values():
        for env_id, entry, vector in ((scenario.gym_id, ENTRY_POINT, VECTOR_ENTRY_POINT),
                                      (scenario.intruder_gym_id, INTRUDER_ENTRY_POINT, INTRUDER_VECTOR_ENTRY_POINT)):
            if env_id not in gymnasium.registry:
                gymnasium.register(env_id, entry_point=entry, vector_entry_point=vector, kwargs=dict(scenario.env))
            ids.append(env_id)
    return ids
