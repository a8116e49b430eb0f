"""`farm robust CONFIG --out DIR`: policy-space response oracles (PSRO, Lanctot et al. 2017) for the
allocation game, on the farm. docs/robust.md tells the algorithm and how it resumes.

Each iteration: every (allocator, intruder policy) pair of the two populations is played on the
same seeded episodes (the missing ones as Ray tasks; farm.studies.robust.payoffs keeps each);
the zero-sum meta-game of their mean payoff is solved by LP (farm.core.matrix_game; under the
config's floor, the allocators' mixture keeps the drift case); each side's oracle answers the
other side's meta-Nash mixture with a best response (the trained oracle: the one of its
`responses` seeds gaining most); the responses are played against the other population and
NashConv (the sum of both sides' best-response gains) is recorded; the responses join the
populations. The loop stops at `iterations`, or once NashConv is at most `threshold` when one is
set; then, on maps whose search tree fits, each iteration's allocators' mixture is valued against
the intruders' exact best response (farm.studies.robust.exact). The state is saved after each
iteration (robust.json), so a run stopped anywhere goes on from its last whole iteration; every
payoff played before is kept, and the trained oracles' trials resume as an experiment's do.
"""

from __future__ import annotations

import hashlib
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from farm.core.errors import ConfigError
from farm.core.matrix_game import solve
from farm.core.output import atomic_write_bytes, check_writable_folder
from farm.studies.robust.config import RobustConfig
from farm.studies.robust.members import Member, check_run, member_of
from farm.studies.robust.payoffs import PayoffStore, claim_folder, fill, payoff_key, read_state, write_state

__all__ = ["Iteration", "run_robust", "payoff_matrix", "STATE"]

STATE = "robust.json"


@dataclass
class Iteration:
    """One iteration's record: the populations it solved (allocators, intruders: lists of Member),
    the meta-Nash mixes (row: allocators', column: intruders', as lists of floats) and value, the
    oracles' responses (Members), their gains over the value (defenders: >= 0 when the response
    does better than the mixture; intruders: the same for the intruders) and NashConv (the sum
    of both gains, each floored at 0: a response no better than the population adds nothing);
    exact, on maps whose search tree fits: the allocators' mixture against the intruders' exact best
    response ({"value", "gain_intruders": the value's drop to it, "nash_conv": with that gain}),
    None where not valued; floor, under the config's floor: {"target", "held", "price"} (the floor,
    the allocators' mixture's payoff against its intruder member, the floor's price; the defenders'
    gain is their response's worth with that price, Solution.row_worth), else None."""

    allocators: list
    intruders: list
    row: list
    column: list
    value: float
    responses: dict
    gains: dict
    nash_conv: float
    exact: dict | None = None
    floor: dict | None = None

    def to_dict(self, root=None) -> dict:
        """Plain values for robust.json (trained members' runs under root relative to it)."""
        return {"allocators": [m.to_dict(root) for m in self.allocators],
                "intruders": [m.to_dict(root) for m in self.intruders],
                "row": self.row, "column": self.column, "value": self.value,
                "responses": {k: m.to_dict(root) for k, m in self.responses.items()}, "gains": self.gains,
                "nash_conv": self.nash_conv, **({"exact": self.exact} if self.exact is not None else {}),
                **({"floor": self.floor} if self.floor is not None else {})}

    @classmethod
    def from_dict(cls, d: dict, root=None) -> Iteration:
        """An Iteration from robust.json's values (relative runs under root, the run's folder)."""
        return cls([member_of("allocators", m, "allocators", root) for m in d["allocators"]],
                   [member_of("intruders", m, "intruders", root) for m in d["intruders"]], d["row"], d["column"],
                   d["value"], {k: member_of(k, m, k, root) for k, m in d["responses"].items()}, d["gains"],
                   d["nash_conv"], d.get("exact"), d.get("floor"))


def digest(config: RobustConfig) -> str:
    """The digest of everything in the config that decides the results (iterations and threshold
    only bound the loop, and exact only values its iterations, so they may change when a run is
    resumed)."""
    values = config.model_dump(mode="json", exclude={"iterations", "threshold", "store", "exact"})
    if values["responses"] == 1:  # at its default the digest is that of a config without the field
        del values["responses"]
    if config.oracle_of("intruders") == config.oracle:  # the intruders' oracle the defenders': as if unset
        del values["intruders_oracle"]
    if values["floor"] is None:
        del values["floor"]
    return hashlib.sha256(json.dumps(values, sort_keys=True).encode()).hexdigest()[:16]


def payoff_matrix(store: PayoffStore, config: RobustConfig, allocators: list, intruders: list) -> np.ndarray:
    """(len(allocators), len(intruders)) float64: each pair's mean payoff (the config's measure) from
    the store, every pair played already."""
    env, p = config.alloc_config(), config.payoffs
    M = np.empty((len(allocators), len(intruders)))
    for i, a in enumerate(allocators):
        for j, b in enumerate(intruders):
            values = store.get(payoff_key(env, a, b, p.episodes, p.seed, store.root))
            if values is None:
                raise RuntimeError(f"payoff of {a.shown()} v {b.shown()} missing")
            M[i, j] = float(np.mean(values[p.measure]))
    return M


def _load_state(out: Path, config: RobustConfig) -> list[Iteration]:
    path = out / STATE
    saved = read_state(path, "robust")
    if saved is None:
        return []
    if saved.get("digest") != digest(config):
        raise ConfigError(f"out: {out} holds a robust run of another config; choose another folder", field="out")
    iterations = [Iteration.from_dict(d, out) for d in saved["iterations"]]
    for k, it in enumerate(iterations):  # every trained member's run, before it is played or trained against
        for m in it.allocators + it.intruders + list(it.responses.values()):
            if "run" in m.options:
                check_run(m.options["run"], m.side, f"{path}: iteration {k}: {m.shown()}")
    return iterations


def _save_state(out: Path, config: RobustConfig, iterations: list[Iteration]) -> None:
    state = {"name": config.name, "digest": digest(config), "iterations": [it.to_dict(out) for it in iterations]}
    write_state(out / STATE, "robust", state)


def _library_response(side: str, config: RobustConfig, store, client, population: list, opponents: list,
                      solution, workers: int) -> Member:
    """The library oracle: the candidate or member of side doing best against the other side's
    mixture of the solution (the defenders' worth with the floor's price: Solution.row_worth)."""
    env, p = config.alloc_config(), config.payoffs
    options = population + [c for c in config.candidates(side) if c not in population]
    pairs = [(c, o) if side == "allocators" else (o, c) for c in options for o in opponents]
    fill(store, env, pairs, p.episodes, p.seed, client, workers)
    M = payoff_matrix(store, config, options, opponents) if side == "allocators" else \
        payoff_matrix(store, config, opponents, options).T
    if side == "allocators":
        return options[int(np.argmax(solution.row_worth(M)))]
    return options[int(np.argmin(M @ solution.row))]


def run_robust(config: RobustConfig, out, *, address: str | None = None, workers: int | None = None,
               show_progress: bool = True) -> tuple[list[Iteration], dict]:
    """Run or resume the loop into out (a local folder); returns (the iterations, info: the pairs
    played this time, the seconds). ConfigError (one line) for bad input before Ray starts."""
    import time

    from farm.alloc.game.lattice import lattice_groups, warm_lattices
    from farm.runtime import check_workers, starts_local_ray, tasks_in_flight
    from farm.service.client import open_client
    from farm.service.store import default_store_path

    from farm.studies.robust.oracles import check_trainings

    check_workers(workers)
    out = check_writable_folder(out, "out")
    check_trainings(config)
    iterations = _load_state(out, config)
    claim_folder(out, "robust")
    store = PayoffStore(out / "payoffs")
    env, p = config.alloc_config(), config.payoffs
    info = {"pairs_played": 0, "iterations_before": len(iterations), "exact_searched": 0}
    t0 = time.perf_counter()
    with open_client(env.game_settings(), mode="ray", store=Path(config.store or default_store_path()),
                     address=address, num_cpus=max(2, workers or 2) if starts_local_ray(address) else None) as client:
        import ray

        warm_lattices(client, lattice_groups([env]), show_progress)
        n = tasks_in_flight(workers, int(ray.cluster_resources().get("CPU", 1)), address)
        allocators = iterations[-1].allocators + _new(iterations[-1], "allocators") if iterations \
            else config.population("allocators")
        intruders = iterations[-1].intruders + _new(iterations[-1], "intruders") if iterations \
            else config.population("intruders")
        if iterations:  # a kept pair whose file was damaged is played again before anything reads it
            info["pairs_played"] += fill(store, env, [(a, b) for a in allocators for b in intruders], p.episodes,
                                         p.seed, client, n)
        while len(iterations) < config.iterations and not _converged(config, iterations):
            info["pairs_played"] += fill(store, env, [(a, b) for a in allocators for b in intruders], p.episodes,
                                         p.seed, client, n)
            M = payoff_matrix(store, config, allocators, intruders)
            solution = solve(M, config.floor_of(M, allocators, intruders))
            k = len(iterations)
            responses, candidates = {}, {}
            if config.trained_sides():
                from farm.studies.robust.oracles import trained_responses

                found = trained_responses(config, out, k, allocators, intruders, solution, address=address,
                                          workers=workers, show_progress=show_progress,
                                          procs=max(1, n // config.responses))
                responses, candidates = _best_responses(config, store, client, n, found, allocators, intruders,
                                                        solution, info)
            if config.oracle_of("allocators") == "library":
                responses["allocators"] = _library_response("allocators", config, store, client, allocators,
                                                            intruders, solution, n)
            if config.oracle_of("intruders") == "library":
                responses["intruders"] = _library_response("intruders", config, store, client, intruders,
                                                           allocators, solution, n)
            elif config.oracle_of("intruders") == "search":
                responses["intruders"] = searching_response(config, k, allocators, solution.row)
            ra, ri = responses["allocators"], responses["intruders"]
            pairs = [(ra, b) for b in intruders] + [(a, ri) for a in allocators] + [(ra, ri)]
            info["pairs_played"] += fill(store, env, pairs, p.episodes, p.seed, client, n)
            gain_d = float(solution.row_worth(payoff_matrix(store, config, [ra], intruders))[0]) - solution.value
            gain_i = solution.value - float(solution.row @ payoff_matrix(store, config, allocators, [ri])[:, 0])
            gains = {"defenders": gain_d, "intruders": gain_i, **candidates}
            it = Iteration(list(allocators), list(intruders), solution.row.tolist(), solution.column.tolist(),
                           solution.value, responses, gains, max(0.0, gain_d) + max(0.0, gain_i),
                           floor=_floor_record(M, solution))
            iterations.append(it)
            _save_state(out, config, iterations)
            if show_progress:
                print(f"robust {config.name}: iteration {k}: value {solution.value:.4f}, NashConv {it.nash_conv:.4f}",
                      file=sys.stderr)
            allocators, intruders = allocators + _new(it, "allocators"), intruders + _new(it, "intruders")
        if config.exact == "auto" and any(it.exact is None for it in iterations):
            _exact_measures(config, store, iterations, client, n, info)
            _save_state(out, config, iterations)
            if show_progress and iterations[-1].exact is not None:
                print(f"robust {config.name}: NashConv with the intruders' exact best response by iteration: "
                      + ", ".join(f"{it.exact['nash_conv']:.4f}" for it in iterations), file=sys.stderr)
        distilled = None
        if iterations and config.distill is not None:
            from farm.studies.robust.oracles import distilled as distil

            allocators, intruders = final_populations(iterations)
            M = payoff_matrix(store, config, allocators, intruders)
            final = solve(M, config.floor_of(M, allocators, intruders))
            distilled = distil(config, out, allocators, intruders, final, address=address, workers=workers,
                               show_progress=show_progress)
            info["pairs_played"] += fill(store, env, [(distilled, b) for b in intruders], p.episodes, p.seed,
                                         client, n)
        info["files"] = write_results(out, config, store, iterations, distilled) if iterations else []
    info["seconds"] = time.perf_counter() - t0
    return iterations, info


def _floor_record(M: np.ndarray, solution) -> dict | None:
    """An iteration's floor: {"target": the floor, "held": the allocators' mixture's payoff against
    its column, "price": the floor's price}, or None without one."""
    if solution.floor is None:
        return None
    j, f = solution.floor
    return {"target": f, "held": float(solution.row @ M[:, j]), "price": solution.price}


def _best_responses(config: RobustConfig, store, client, n: int, found: dict, allocators: list, intruders: list,
                    solution, info: dict) -> tuple[dict, dict]:
    """Each side's response gaining most over the meta-game's value among its trained seeds (found:
    lists of Members), their candidates' pairs played first: ({side: the kept Member}, {
    "defenders_candidates", "intruders_candidates": every seed's gain} or {} for one seed a side)."""
    if config.responses == 1:
        return {side: found[side][0] for side in ("allocators", "intruders") if found[side]}, {}
    env, p = config.alloc_config(), config.payoffs
    pairs = [(a, b) for a in found["allocators"] for b in intruders] + \
            [(a, b) for a in allocators for b in found["intruders"]]
    info["pairs_played"] += fill(store, env, pairs, p.episodes, p.seed, client, n)
    kept, candidates = {}, {}
    if found["allocators"]:
        gain_d = solution.row_worth(payoff_matrix(store, config, found["allocators"], intruders)) - solution.value
        kept["allocators"] = found["allocators"][int(np.argmax(gain_d))]
        candidates["defenders_candidates"] = gain_d.tolist()
    if found["intruders"]:
        gain_i = solution.value - solution.row @ payoff_matrix(store, config, allocators, found["intruders"])
        kept["intruders"] = found["intruders"][int(np.argmax(gain_i))]
        candidates["intruders_candidates"] = gain_i.tolist()
    return kept, candidates


def searching_response(config: RobustConfig, k: int, allocators: list, row) -> Member:
    """The intruders' response of iteration k under `intruders_oracle: search`: search intruders whose
    model is the allocators' mixture row (its support and weights), minimising the payoffs' measure."""
    support = [(a, float(w)) for a, w in zip(allocators, row) if w > 0]
    options = {"allocators": [a.spec() for a, _ in support], "weights": [w for _, w in support],
               "objective": config.payoffs.measure}
    return Member("intruders", "search", options, f"br{k}")


def _exact_measures(config: RobustConfig, store: PayoffStore, iterations: list[Iteration], client, n: int,
                    info: dict) -> None:
    """Each iteration lacking it gets its allocators' mixture valued against the intruders' exact
    best response (Iteration.exact), on maps whose search tree fits; every member of a mixture's
    support searched once (farm.studies.robust.exact). An iteration whose support holds an
    allocator that draws its moves (a population member that is itself a drawn mixture) is left
    unvalued: the search answers deterministic allocators only."""
    from farm.studies.robust.exact import deterministic, exact_values, fill_exact, searchable

    env, p = config.alloc_config(), config.payoffs
    todo = [it for it in iterations if it.exact is None
            and all(deterministic(a) for a, w in zip(it.allocators, it.row) if w > 0)]
    if not searchable(env, p.episodes, p.seed):
        return
    support = {json.dumps(a.key(), sort_keys=True): a for it in todo for a, w in zip(it.allocators, it.row) if w > 0}
    info["exact_searched"] += fill_exact(store, env, list(support.values()), p.episodes, p.seed, p.measure,
                                         client, n)
    for it in todo:
        members = [a for a, w in zip(it.allocators, it.row) if w > 0]
        weights = np.array([w for w in it.row if w > 0])
        value = float(weights @ exact_values(store, env, members, p.episodes, p.seed, p.measure))
        gain = it.value - value
        it.exact = {"value": value, "gain_intruders": gain,
                    "nash_conv": max(0.0, it.gains["defenders"]) + max(0.0, gain)}


def final_populations(iterations: list[Iteration]) -> tuple[list, list]:
    """The populations after the last iteration: its own and its responses."""
    last = iterations[-1]
    return last.allocators + _new(last, "allocators"), last.intruders + _new(last, "intruders")


def write_results(out: Path, config: RobustConfig, store: PayoffStore, iterations: list[Iteration],
                  distilled: Member | None = None) -> list[Path]:
    """The loop's files: nash_conv.csv (each iteration's value, both gains and NashConv), payoffs.csv
    (the final populations' payoff matrix, allocators by row, the distilled network's row last),
    mixture.yaml (the final meta-Nash mixtures: the robust allocator as the registry's `mixture`
    with its options, the intruders' as theirs, and the distilled network as its registry name
    and run) and nash_conv.png; returns the paths."""
    import pandas as pd
    import yaml

    from farm.studies.robust.members import mixture_options

    allocators, intruders = final_populations(iterations)
    M = payoff_matrix(store, config, allocators, intruders)
    final = solve(M, config.floor_of(M, allocators, intruders))
    rows = [{"iteration": k, "value": it.value, "gain_defenders": it.gains["defenders"],
             "gain_intruders": it.gains["intruders"], "nash_conv": it.nash_conv, "allocators": len(it.allocators),
             "intruders": len(it.intruders),
             **({f"exact_{name}": v for name, v in it.exact.items()} if it.exact is not None else {}),
             **({f"floor_{name}": v for name, v in it.floor.items()} if it.floor is not None else {})}
            for k, it in enumerate(iterations)]
    files = [out / "nash_conv.csv", out / "payoffs.csv", out / "mixture.yaml", out / "nash_conv.png"]
    pd.DataFrame(rows).to_csv(files[0], index=False)
    shown = pd.DataFrame(M, index=[a.shown() for a in allocators], columns=[b.shown() for b in intruders])
    if distilled is not None:
        shown.loc[distilled.shown()] = payoff_matrix(store, config, [distilled], intruders)[0]
    shown.to_csv(files[1])
    mixture = {"value": float(final.value), "measure": config.payoffs.measure,
               "allocator": {"name": "mixture", "options": mixture_options(allocators, final.row)},
               "intruders": {"name": "mixture", "options": mixture_options(intruders, final.column)},
               "weights": {"allocators": {a.shown(): float(w) for a, w in zip(allocators, final.row)},
                           "intruders": {b.shown(): float(w) for b, w in zip(intruders, final.column)}}}
    if final.floor is not None:
        mixture["floor"] = _floor_record(M, final)
    if distilled is not None:
        mixture["distilled"] = {"name": distilled.name, "options": distilled.options}
    atomic_write_bytes(files[2], yaml.safe_dump(mixture, sort_keys=False).encode())
    _plot_nash_conv(rows, files[3], config.name)
    return files


def _plot_nash_conv(rows: list[dict], path: Path, name: str) -> None:
    """NashConv and the meta-game's value by iteration, as a PNG (an Agg figure of its own)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 3.5))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    k = [r["iteration"] for r in rows]
    ax.plot(k, [r["nash_conv"] for r in rows], "o-", label="NashConv")
    if any("exact_nash_conv" in r for r in rows):
        ax.plot(k, [r.get("exact_nash_conv", np.nan) for r in rows], "^:", label="NashConv, intruders' exact")
    ax.plot(k, [r["value"] for r in rows], "s--", label="meta-game value")
    ax.set_xlabel("iteration")
    ax.set_title(f"{name}: NashConv by iteration")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def _converged(config: RobustConfig, iterations: list[Iteration]) -> bool:
    """Whether the last iteration's NashConv is at most the config's threshold (never without one)."""
    return config.threshold is not None and bool(iterations) and iterations[-1].nash_conv <= config.threshold


def _new(it: Iteration, side: str) -> list:
    """The iteration's response of side as a new member ([] when a member is that strategy already:
    the same name and options, whatever its label)."""
    response = it.responses[side]
    return [] if response.key() in [m.key() for m in getattr(it, side)] else [response]
