"""The trained oracles of `farm robust`: each side's best response to the other side's meta-Nash
mixture, trained as the trials of one experiment an iteration (farm.studies.experiments: each
side's `responses` seeds), so that they train side by side, resume after a stop, and never train
twice."""

from __future__ import annotations

from pathlib import Path

from farm.studies.robust.config import RobustConfig
from farm.studies.robust.members import Member, mixture_options

LOOP_SET = ("env.intruders", "env.intruder_options", "pretrain.expert_options")  # set by the loop, not a config

__all__ = ["trained_responses", "iteration_experiment", "response_seeds", "distilled", "distill_experiment",
           "check_trainings"]


def iteration_experiment(config: RobustConfig, k: int, allocators: list, intruders: list, solution,
                         sides: list[str] | None = None):
    """Iteration k's experiment: a point a trained side (sides, default config.trained_sides(), in
    its order): the defenders' best response (an allocator trained in the env whose intruders are
    the intruders' mixture, with the floor's price on its drift case when there is one:
    Solution.reply_column), the intruders' (trained against the allocators' mixture);
    config.responses seeds (response_seeds)."""
    from farm.studies.experiments.config import ExperimentConfig

    defenders_training = {"env.intruders": "mixture",
                          "env.intruder_options": mixture_options(intruders, solution.reply_column()),
                          **config.training.defenders}
    intruders_training = {"side": "intruders", "opponent.name": "mixture",
                          "opponent.options": mixture_options(allocators, solution.row), **config.training.intruders}
    shared = {f"env.{name}": value for name, value in config.env.items()}
    trained = [{"allocators": defenders_training, "intruders": intruders_training}[side]
               for side in (config.trained_sides() if sides is None else sides)]
    points = [{k_: v for k_, v in point.items() if k_ not in shared} for point in trained]
    return ExperimentConfig(name=f"{config.name}-it{k}", scenario=config.scenario, overrides=shared, points=points,
                            seeds=response_seeds(config, k), episodes=3, eval_seed=config.payoffs.seed,
                            store=config.store)


def response_seeds(config: RobustConfig, k: int) -> list[int]:
    """The seeds of iteration k's responses: config.seed * 1000 + k, then + 100, + 200, ... for
    each further response (k < 100, responses <= 9: below the distillation's + 999)."""
    return [config.seed * 1000 + 100 * j + k for j in range(config.responses)]


def trained_responses(config: RobustConfig, out: Path, k: int, allocators: list, intruders: list, solution, *,
                      address: str | None = None, workers: int | None = None, show_progress: bool = True,
                      procs: int = 1) -> dict:
    """The trained sides' best responses of iteration k (iteration_experiment, run or resumed in
    out/iterations/<k>): {"allocators": the defenders' trained allocators, "intruders": the
    intruders' trained policies (none for a side whose oracle is not trained)}, each a list of
    config.responses Members (labels brK, then brK.1, brK.2, ...) whose `run` is their run folder. procs: the processes
    answering the allocators' moves in the intruders' training (run_experiment's opponent_procs:
    their planning is most of an iteration; the same responses whatever procs)."""
    from farm.alloc.training.runs import RunFolder
    from farm.studies.experiments.plan import plan
    from farm.studies.experiments.run import run_experiment
    from farm.studies.experiments.storage import ExperimentStorage

    experiment = iteration_experiment(config, k, allocators, intruders, solution)
    where = out / "iterations" / str(k)
    run_experiment(experiment, where, address=address, workers=workers, show_progress=show_progress,
                   opponent_procs=procs)
    storage = ExperimentStorage(where)
    found = {"allocators": [], "intruders": []}
    sides = config.trained_sides()
    for t in plan(experiment).trials:
        side = sides[t.point]
        run, j = storage.run_dir(t.key), len(found[side])
        name = RunFolder(run).learner() if side == "allocators" else "learned"
        found[side].append(Member(side, name, {"run": str(run)}, f"br{k}" + (f".{j}" if j else "")))
    return found


def distill_experiment(config: RobustConfig, allocators: list, intruders: list, solution):
    """The distillation's experiment: one training DAgger-started from the allocators' mixture's
    mean move (draw: mean) in the env whose intruders are the intruders' mixture (config.distill)."""
    from farm.studies.experiments.config import ExperimentConfig

    expert = {**mixture_options(allocators, solution.row), "draw": "mean"}
    point = {"env.intruders": "mixture", "env.intruder_options": mixture_options(intruders, solution.reply_column()),
             **config.distill, "pretrain.expert_options": expert}
    shared = {f"env.{name}": value for name, value in config.env.items()}
    return ExperimentConfig(name=f"{config.name}-distilled", scenario=config.scenario, overrides=shared,
                            points=[{k: v for k, v in point.items() if k not in shared}],
                            seeds=[config.seed * 1000 + 999], episodes=3, eval_seed=config.payoffs.seed,
                            store=config.store)


def check_trainings(config: RobustConfig) -> None:
    """The trained oracles' and the distillation's settings (training.defenders, training.intruders,
    distill) refused before Ray starts or a pair is played, as their experiments would refuse them
    (ConfigError, one line naming the field): each built against the starting populations' uniform
    mixtures and checked."""
    import numpy as np
    from pydantic import ValidationError

    from farm.core.config import first_line
    from farm.core.errors import ConfigError
    from farm.core.matrix_game import Solution
    from farm.studies.experiments.plan import plan

    allocators, intruders = config.population("allocators"), config.population("intruders")
    uniform = Solution(np.full(len(allocators), 1 / len(allocators)), np.full(len(intruders), 1 / len(intruders)),
                       0.0)
    own = {"training.defenders": config.training.defenders, "training.intruders": config.training.intruders,
           "distill": config.distill or {}}
    for field, settings in own.items():
        for key in settings:
            if key.split(".")[0] in ("side", "opponent", "scenario") or key in LOOP_SET:
                raise ConfigError(f"{field}: {key}: the robust loop sets it (the side, the opponent's mixture, "
                                  f"the map)", field=field)
    checks = [(f"training.{'defenders' if side == 'allocators' else 'intruders'}",
               lambda side=side: iteration_experiment(config, 0, allocators, intruders, uniform, [side]))
              for side in config.trained_sides()]
    if config.distill is not None:
        checks.append(("distill", lambda: distill_experiment(config, allocators, intruders, uniform)))
    for field, build in checks:
        try:
            plan(build(), field)
        except ValidationError as e:
            raise ConfigError(f"{field}: {first_line(e).removeprefix('points: ').removeprefix('point 0: ')}",
                              field=field) from None
        except ConfigError as e:
            raise ConfigError(str(e).split(" (point 0")[0], field=field) from None


def distilled(config: RobustConfig, out: Path, allocators: list, intruders: list, solution, *,
              address: str | None = None, workers: int | None = None, show_progress: bool = True) -> Member:
    """One network distilled from the final allocators' mixture (config.distill's training, run or
    resumed in out/distilled): DAgger from the mixture's mean move (draw: mean) in the env whose
    intruders are the final intruders' mixture, then RL there; the trained allocator as a Member."""
    from farm.alloc.training.runs import RunFolder
    from farm.studies.experiments.plan import plan
    from farm.studies.experiments.run import run_experiment
    from farm.studies.experiments.storage import ExperimentStorage

    experiment = distill_experiment(config, allocators, intruders, solution)
    where = out / "distilled"
    run_experiment(experiment, where, address=address, workers=workers, show_progress=show_progress)
    run = ExperimentStorage(where).run_dir(plan(experiment).trials[0].key)
    return Member("allocators", RunFolder(run).learner(), {"run": str(run)}, "distilled")
