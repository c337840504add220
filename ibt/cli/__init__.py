"""``python -m ibt``: the command line (:mod:`ibt.cli.main`; checks in :mod:`ibt.cli.checks`,
subcommands in :mod:`ibt.cli.commands`)."""

from ibt.cli.checks import UsageError, sweep_temp_files
from ibt.cli.main import build_parser, main

__all__ = ["UsageError", "build_parser", "main", "sweep_temp_files"]
