"""``python -m ibt``: the command line (:mod:`ibt.cli.main`; checks in :mod:`ibt.cli.checks`,
subcommands in :mod:`ibt.cli.commands` (those that build experts, trees and BTs),
:mod:`ibt.cli.bt_commands` (those that use them) and :mod:`ibt.cli.pipeline_command`).

:func:`main` first checks that it runs in the project's environment: ``--help`` needs nothing
beyond the standard library, but every command needs the compute stack, and a Python outside
``.venv`` would otherwise die with a ``ModuleNotFoundError`` traceback half-way into a command.
"""

from __future__ import annotations

import importlib.util
import sys

from ibt.cli.checks import EXIT_BAD_INPUT, UsageError, sweep_temp_files
from ibt.cli.main import build_parser
from ibt.cli.main import main as run

__all__ = ["UsageError", "build_parser", "main", "missing_library", "sweep_temp_files"]

#: what every command imports (``make setup`` installs them into ``.venv`` from environment.lock)
REQUIRED = ("numpy", "pandas", "gymnasium", "sklearn", "torch", "stable_baselines3")


def missing_library(names: tuple[str, ...] = REQUIRED) -> str | None:
    """The first of ``names`` this Python cannot import (found without importing it), or None."""
    for name in names:
        if importlib.util.find_spec(name) is None:
            return name
    return None


def outside_venv_message(library: str) -> str:
    """One line: which library this Python lacks, and how to get the project's Python."""
    return (f"error: {sys.executable} has no {library!r}, so it is not the project's Python: "
            "run `make setup` once, then `source .venv/bin/activate` (or call "
            "`.venv/bin/python -m ibt ...`)")


def main(argv: list[str] | None = None) -> int:
    """:func:`ibt.cli.main.main`, or exit code 2 with one line when this Python is not the
    project's (help texts are shown everywhere)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    wants_help = not argv or any(a in ("-h", "--help") for a in argv)
    library = None if wants_help else missing_library()
    if library is None:
        try:
            return run(argv)
        except ModuleNotFoundError as err:  # a library beyond REQUIRED
            if not err.name or err.name.partition(".")[0] == "ibt":
                raise  # our own module missing: a bug, not the environment
            library = err.name.partition(".")[0]
    print(outside_venv_message(library), file=sys.stderr)
    return EXIT_BAD_INPUT
