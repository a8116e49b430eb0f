"""`farm claims RUNS_DIR`: the paper's claims (a)-(c), measured on evaluated runs; on an
experiment folder (its experiment.json), over its seeds."""

from __future__ import annotations

from pathlib import Path

from farm.core.errors import CliError

CLAIM_RUNS = ("paper_3x3_c1_0", "paper_3x3_c1_1.5")  # the default --c0 and --c15 run folders


def register(subparsers) -> None:
    """Add `farm claims` and its flags to the `farm` parser's subcommands."""
    cl = subparsers.add_parser("claims", help="the paper's claims (a)-(c), measured on evaluated runs, or over an "
                                              "experiment's seeds")
    cl.add_argument("runs_dir", help="folder of run folders (e.g. results/runs), or an experiment folder "
                                     "(e.g. results/experiments/paper)")
    cl.add_argument("--c0", help=f"the C_capture = 0 run's folder name (default {CLAIM_RUNS[0]}, as make experiments "
                                 f"names it)")
    cl.add_argument("--c15", help=f"the C_capture = 1.5 run's folder name (default {CLAIM_RUNS[1]})")
    cl.add_argument("--points", type=int, nargs=2, metavar=("C0", "C15"),
                    help="an experiment folder's points of C_capture 0 and 1.5 (default: found from the trials' "
                         "configs)")
    cl.set_defaults(func=run)


def run(args) -> int:
    """Print each claim with its measure and verdict and write claims.csv into RUNS_DIR."""
    from farm.studies.claims import check_claim_runs, claims, write_claims
    from farm.studies.experiments import is_experiment

    runs = Path(args.runs_dir)
    if not runs.is_dir():
        raise CliError(f"{runs}: not a folder of training runs")
    if is_experiment(runs):
        for flag, value in (("--c0", args.c0), ("--c15", args.c15)):
            if value is not None:
                raise CliError(f"{flag}: names a run of a folder of runs; {runs} is an experiment folder "
                               f"(--points names its points)")
        return _over_seeds(runs, args.points)
    if args.points is not None:
        raise CliError(f"--points: names points of an experiment folder; {runs} holds no experiment.json")
    c0, c15 = args.c0 or CLAIM_RUNS[0], args.c15 or CLAIM_RUNS[1]
    note = check_claim_runs(runs, c0, c15, named=(args.c0 is not None, args.c15 is not None))
    if note is not None:
        print(note)
    rows = claims(runs, c0, c15)
    if not rows:
        raise CliError(f"{runs}: no evaluated runs (run farm train, then farm eval, for each config)")
    for r in rows:
        print(f"{r['claim']}\n  measured: {r['measured']}\n  verdict:  {r['verdict']}")
    print(f"wrote {write_claims(runs, rows)}")
    return 0


def _over_seeds(folder: Path, points) -> int:
    """The claims over an experiment's seeds; writes claims.csv and claims_seeds.csv into folder."""
    from farm.studies.claims import claims_over_seeds, write_claims_over_seeds

    found = claims_over_seeds(folder, None if points is None else tuple(points))
    print(found.note)
    if not found.rows:
        raise CliError(f"{folder}: no finished trial with its evaluations yet (farm experiments writes them)")
    for r in found.rows:
        print(f"{r['claim']}\n  measured: {r['measured']}\n  verdict:  {r['verdict']}\n  rule:     {r['rule']}")
    print("wrote " + ", ".join(map(str, write_claims_over_seeds(folder, found))))
    return 0
