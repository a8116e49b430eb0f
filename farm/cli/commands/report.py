"""`farm report RESULTS_DIR`: one self-contained HTML page of a results folder."""

from __future__ import annotations


def register(subparsers) -> None:
    """Add `farm report` and its flags to the `farm` parser's subcommands."""
    r = subparsers.add_parser("report", help="one self-contained HTML page of everything in a results folder")
    r.add_argument("results_dir")
    r.add_argument("-o", "--output", help="where the HTML goes (default RESULTS_DIR/report.html)")
    r.set_defaults(func=run)


def run(args) -> int:
    """Write the page and print its path."""
    from farm.report import write_report

    path = write_report(args.results_dir, args.output)
    print(f"report: {path.resolve()}")
    return 0
