"""Command-line interface: ``optitact demo``, ``render``, ``process``, ``register``, ``calibrate``, ``bench``...

Messages, warnings (one ``optitact: warning: ...`` line each) and progress
bars go to stderr; ``bench`` prints one JSON object on stdout, ``experiment``
a table of key figures (``--json``: the JSON object), the others the path
they wrote. Bad input (optitact's own :class:`~optitact.errors.InputError`
and :class:`~optitact.errors.ShapeError`, a missing extra, an unreadable or
unwritable file) is a one-line ``optitact: error: ...`` and exit code 2; any
other exception is a bug and shows its traceback.

One module per command group: :mod:`~optitact.cli.demo` (demo, render,
overlay), :mod:`~optitact.cli.process`, :mod:`~optitact.cli.register`,
:mod:`~optitact.cli.calibrate`, :mod:`~optitact.cli.bench`, :mod:`~optitact.cli.experiment`; shared options
are argparse parent parsers (:mod:`~optitact.cli._args`).
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import sys
import warnings

from optitact import __version__
from optitact.errors import OptitactError, OptitactWarning

__all__ = ["main", "parser", "USER_ERRORS", "BLAS_THREADS_SET"]

#: Exceptions that mean bad input rather than a bug: a one-line message and exit code 2.
#: OptitactError covers InputError, ShapeError, MissingExtraError and RenderError (Mitsuba set-up).
USER_ERRORS = (OptitactError, OSError, json.JSONDecodeError)


#: The module (of this package) that adds each command, in the order ``--help`` lists them.
COMMANDS = {"demo": "demo", "render": "demo", "process": "process", "register": "register",
            "calibrate": "calibrate", "bench": "bench", "experiment": "experiment"}


def parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``optitact`` argument parser (with ``command``: only the module that adds that command).

    A command's run imports what it needs: ``optitact process`` imports neither the renderer's,
    the calibration sets' nor the benchmarks' modules.
    """
    p = argparse.ArgumentParser(
        prog="optitact",
        description="Optical three-axis tactile sensing: render synthetic frames of the dome "
                    "sensor, process frames into forces.")
    p.add_argument("--version", action="version", version=f"optitact {__version__}")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND", help="what to do")
    names = dict.fromkeys(COMMANDS.values()) if command is None else [COMMANDS[command]]
    for name in names:
        importlib.import_module(f"{__name__}.{name}").add_parsers(sub)
    return p


def __getattr__(name: str):
    if name == "overlay":  # re-exported from the demo command's module
        from optitact.cli.demo import overlay

        return overlay
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _one_line(message, category, filename, lineno, file=None, line=None) -> None:
    """Print a warning as one ``optitact: warning: ...`` line on stderr, above any progress bar.

    A bar is tqdm's, so without tqdm imported there is none to keep clear of: the line is
    printed as it is, and tqdm (17 ms to import) is not loaded for it.
    """
    text = f"optitact: warning: {message}"
    tqdm = sys.modules.get("tqdm")
    if tqdm is None:
        print(text, file=sys.stderr)
    else:
        tqdm.tqdm.write(text, file=sys.stderr)


#: :func:`main` set ``OPENBLAS_NUM_THREADS=1`` itself (NumPy was not loaded yet and the user had not set it).
BLAS_THREADS_SET = False


def _one_blas_thread() -> None:
    """Run OpenBLAS on one thread when the command line is the program (before NumPy loads it).

    optitact parallelises over frames itself; OpenBLAS's own worker threads only busy-wait
    (about 0.1 s of CPU at every start) on matrices this small. A user's setting is kept, and a
    process that loaded NumPy before calling :func:`main` keeps its threads.
    """
    global BLAS_THREADS_SET
    if "numpy" not in sys.modules and "OPENBLAS_NUM_THREADS" not in os.environ:
        os.environ["OPENBLAS_NUM_THREADS"] = "1"
        BLAS_THREADS_SET = True


def main(argv: list[str] | None = None) -> int:
    """Run the ``optitact`` command; returns the exit code."""
    _one_blas_thread()
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parser(argv[0] if argv and argv[0] in COMMANDS else None).parse_args(argv)
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _one_line
            warnings.simplefilter("always", OptitactWarning)  # the user is told, whatever the filters say
            return args.run(args)
    except USER_ERRORS as exc:
        print(f"optitact: error: {exc}", file=sys.stderr)
        return 2
