"""The trained oracles of `farm robust`: each side's best response to the other side's meta-Nash
mixture, trained as the trials of one experiment an iteration (farm.studies.experiments: each
side's `responses` seeds), so that they train side by side, resume after a stop, and never train
twice."""

from __future__ import annotations

from pathlib import Path

from farm.studies.robust.config import RobustConfig
from farm.studies.robust.members import Member, mixture_options

__all__ = ["trained_responses", "iteration_experiment", "response_seeds", "distilled"]


def iteration_experiment(config: RobustConfig, k: int, allocators: list, intruders: list, solution):
    """Iteration k's experiment: a point a trained side (config.trained_sides(), in its order): the
    defenders' best response (an allocator trained in the env whose intruders are the intruders'
    mixture, with the floor's price on its drift case when there is one: Solution.reply_column),
    the intruders' (trained against the allocators' mixture); config.responses seeds
    (response_seeds)."""
    from farm.studies.experiments.config import ExperimentConfig

    defenders_training = {"env.intruders": "mixture",
                          "env.intruder_options": mixture_options(intruders, solution.reply_column()),
                          **config.training.defenders}
    intruders_training = {"side": "intruders", "opponent.name": "mixture",
                          "opponent.options": mixture_options(allocators, solution.row), **config.training.intruders}
    shared = {f"env.{name}": value for name, value in config.env.items()}
    trained = [{"allocators": defenders_training, "intruders": intruders_training}[side]
               for side in config.trained_sides()]
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


def distilled(config: RobustConfig, out: Path, allocators: list, intruders: list, solution, *,
              address: str | None = None, workers: int | None = None, show_progress: bool = True) -> Member:
    """One network distilled from the final allocators' mixture (config.distill's training, run or
    resumed in out/distilled): DAgger from the mixture's mean move (draw: mean) in the env whose
    intruders are the final intruders' mixture, then RL there; the trained allocator as a Member."""
    from farm.alloc.training.runs import RunFolder
    from farm.studies.experiments.config import ExperimentConfig
    from farm.studies.experiments.plan import plan
    from farm.studies.experiments.run import run_experiment
    from farm.studies.experiments.storage import ExperimentStorage

    expert = {**mixture_options(allocators, solution.row), "draw": "mean"}
    point = {"env.intruders": "mixture", "env.intruder_options": mixture_options(intruders, solution.reply_column()),
             **config.distill, "pretrain.expert_options": expert}
    shared = {f"env.{name}": value for name, value in config.env.items()}
    experiment = ExperimentConfig(name=f"{config.name}-distilled", scenario=config.scenario, overrides=shared,
                                  points=[{k: v for k, v in point.items() if k not in shared}],
                                  seeds=[config.seed * 1000 + 999], episodes=3, eval_seed=config.payoffs.seed,
                                  store=config.store)
    where = out / "distilled"
    run_experiment(experiment, where, address=address, workers=workers, show_progress=show_progress)
    run = ExperimentStorage(where).run_dir(plan(experiment).trials[0].key)
    return Member("allocators", RunFolder(run).learner(), {"run": str(run)}, "distilled")
