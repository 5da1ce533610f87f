"""``optitact experiment NAME``: a study of :mod:`optitact.studies`, its key figures beside the published ones.

By default a short table on stdout (the study's key figures, ours beside the
published ones); ``--json`` prints the whole result as one JSON object on
stdout instead, and ``--out FILE.json`` saves it (both can be given).
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

from optitact.cli._args import out_file, plot_parent, seed_parent

__all__ = ["add_parsers", "format_value", "summary_table"]

#: Widest cell of the table; longer text is cut with an ellipsis.
CELL = 48


def add_parsers(sub) -> None:
    """Add ``experiment`` to the subcommands; its names come from the studies registry."""
    from optitact import studies

    exp = sub.add_parser(
        "experiment", parents=[seed_parent(), plot_parent("save the study's figure as PNG")],
        help="reproduce a published experiment (other tactile sensors, the robotic finger, the noise sweep)",
        description="Run one study of optitact.studies and print a short table of its key figures "
                    "beside the published ones; --json prints the whole result (every figure and "
                    "series, seed, size, timing) as one JSON object instead, --out saves it. Quick "
                    "size by default (seconds); --full runs the published sizes. Studies: "
                    + ", ".join(studies.names()) + ".")
    exp.add_argument("name", choices=studies.names(), help="which study")
    exp.add_argument("--full", action="store_true", help="full size (minutes) instead of a quick run")
    exp.add_argument("--json", action="store_true",
                     help="print the whole result as one JSON object on stdout instead of the table")
    exp.add_argument("--out", type=out_file(".json"), default=None, metavar="RESULT.json",
                     help="also save the whole result as JSON (written atomically)")
    exp.set_defaults(run=run_experiment)


def format_value(value) -> str:
    """One table cell: numbers to 4 significant digits, short lists inline, None as ``-``.

    Examples
    --------
    >>> [format_value(v) for v in (None, 0.912345, [1, 2.5], True, "near 1", list(range(9)))]
    ['-', '0.9123', '[1, 2.5]', 'yes', 'near 1', '[0, 1, 2, 3, 4, 5, ... (9 values)]']
    """
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        return f"{value:.4g}" if math.isfinite(value) else str(value)
    if isinstance(value, (list, tuple)):
        items = [format_value(v) for v in value[:6]]
        more = f", ... ({len(value)} values)" if len(value) > 6 else ""
        text = "[" + ", ".join(items) + more + "]"
    elif isinstance(value, dict):
        text = "{" + ", ".join(f"{k}: {format_value(v)}" for k, v in value.items()) + "}"
    else:
        text = str(value)
    return text if len(text) <= CELL else text[:CELL - 3] + "..."


def summary_table(result: dict) -> str:
    """The text ``optitact experiment`` prints: a header line, the key figures, the paper's reference."""
    from optitact import studies

    name = result["study"]
    rows = [("", "ours", "published")]
    rows += [(label, format_value(ours), format_value(pub))
             for label, ours, pub in studies.key_figures(name, result)]
    widths = [max(len(r[i]) for r in rows) for i in range(3)]
    lines = [f"{name} ({result['size']} size, seed {result['seed']}, {result['seconds']:.1f} s): "
             f"{studies.get(name).summary}"]
    for k, row in enumerate(rows):
        lines.append("  " + "  ".join(cell.ljust(w) for cell, w in zip(row, widths, strict=True)).rstrip())
        if k == 0:
            lines.append("  " + "  ".join("-" * w for w in widths))
    reference = (result.get("published") or {}).get("reference")
    if reference:
        lines.append(f"published: {reference}")
    return "\n".join(lines)


def run_experiment(args) -> int:
    """Run the study, optionally save its figure and JSON; print the table (or the JSON)."""
    from optitact import studies

    if args.plot is not None:  # before minutes of work, not after
        from optitact._optional import require

        require("matplotlib.figure", purpose="--plot")
    result = studies.run(args.name, seed=args.seed, size="full" if args.full else "quick", progress=True)
    if args.plot is not None:
        path = studies.save_plot(args.name, result, args.plot)
        print(f"optitact: wrote {path}", file=sys.stderr)
        result = {**result, "plot": str(Path(path))}
    if args.out is not None:
        from optitact.io.files import atomic_write_text

        atomic_write_text(args.out, json.dumps(result) + "\n")
        print(f"optitact: wrote the whole result to {args.out}", file=sys.stderr)
    if args.json:
        print(json.dumps(result))
    else:
        print(summary_table(result))
    return 0
