"""``optitact experiment NAME``: a study of :mod:`optitact.studies`, its figures as one JSON object."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from ._args import plot_parent, seed_parent

__all__ = ["add_parsers"]


def add_parsers(sub) -> None:
    """Add ``experiment`` to the subcommands; its names come from the studies registry."""
    from optitact import studies

    exp = sub.add_parser(
        "experiment", parents=[seed_parent(), plot_parent("save the study's figure as PNG")],
        help="reproduce a published experiment (other tactile sensors, the robotic finger, the noise sweep)",
        description="Run one study of optitact.studies and print its result as one JSON object "
                    "(the study's figures next to the published ones, seed, size, timing). Quick "
                    "size by default (seconds); --full runs the published sizes. Studies: "
                    + ", ".join(studies.names()) + ".")
    exp.add_argument("name", choices=studies.names(), help="which study")
    exp.add_argument("--full", action="store_true", help="full size (minutes) instead of a quick run")
    exp.set_defaults(run=run_experiment)


def run_experiment(args) -> int:
    """Run the study, optionally save its figure, print its result as JSON."""
    from optitact import studies

    result = studies.run(args.name, seed=args.seed, size="full" if args.full else "quick", progress=True)
    if args.plot is not None:
        path = studies.save_plot(args.name, result, args.plot)
        print(f"optitact: wrote {path}", file=sys.stderr)
        result = {**result, "plot": str(Path(path))}
    print(json.dumps(result))
    return 0
