"""The command line's input checks: numeric flags with bounds, input and output paths, tree
and BT files read safely; bad input is a :class:`UsageError` (exit 2, one line)."""


from __future__ import annotations

import argparse
import contextlib
import glob
import math
import os
import shlex
import tempfile
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ibt.signals import Terminated as Terminated  # re-exported: the CLI raises it

if TYPE_CHECKING:  # the CLI imports the compute stack only when a command runs
    from ibt.tasks.task import Task



EXPORT_FORMATS = ("json", "dot", "svg", "png", "btcpp-xml")
EXPORT_SUFFIXES = {"json": (".json",), "dot": (".dot", ".gv"), "svg": (".svg",),
                   "png": (".png",), "btcpp-xml": (".xml",)}
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130
EXIT_TERMINATED = 143
MAX_BT_BYTES = 64 << 20  # a BT or XML file larger than this is refused (not read)
STALE_TEMP_SECONDS = 30  # hidden temp files older than this, beside an output, are swept


class UsageError(Exception):
    """Bad input found by the command line: exit code 2 and this one-line message."""


# ------------------------------------------------------------------------- input checks
def _int_at_least(minimum: int, what: str, maximum: int = 10**6) -> Callable[[str], int]:
    """An argparse type: an integer in ``[minimum, maximum]``."""

    def parse(text: str) -> int:
        try:
            value = int(text) if len(text) <= 30 else None
        except ValueError:
            value = None
        if value is None:
            raise argparse.ArgumentTypeError(f"expected an integer ({what}), got {text!r:.40}")
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be at least {minimum} ({what}), got {value}")
        if value > maximum:
            raise argparse.ArgumentTypeError(f"must be at most {maximum:,} ({what}), got "
                                             f"{text:.40}")
        return value

    return parse


def seconds_arg(text: str) -> float:
    """An argparse type: a finite number of seconds, 0 or more."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not math.isfinite(value) or not 0 <= value <= 60:
        raise argparse.ArgumentTypeError(f"must be a number of seconds from 0 to 60, got "
                                         f"{text:.40}")
    return value


POSITIVE = _int_at_least(1, "a count")
EPISODES = _int_at_least(1, "episodes", 1_000_000)
SEED = _int_at_least(0, "a seed: 0 to 2**32 - 1", 2**32 - 1)
MAX_LEAVES = 100_000  #: a tree's leaf limit (distill --max-leaf-nodes, pipeline --leaves)
MAX_REFINE_EPISODES = 10_000_000  #: refine --episodes, pipeline --budget EPISODES
LEAVES = _int_at_least(2, "leaves of a tree", MAX_LEAVES)
LABELS = _int_at_least(1, "expert labels", 10_000_000)
ITERATIONS = _int_at_least(1, "iterations", 10_000)
TIMESTEPS = _int_at_least(1, "timesteps", 10**10)
MAX_NODES = _int_at_least(1, "BT nodes", 1_000_000)
RESTARTS = _int_at_least(1, "restarts", 64)
JOBS = _int_at_least(1, "processes", 1024)
MAX_DURATION = 7 * 24 * 3600.0  # a week: longer budgets are typing errors


def duration_arg(text: str) -> float:
    """An argparse type: a wall-clock budget such as ``90``, ``90s``, ``10m``, ``1h30m``
    (seconds, more than 0, at most a week)."""
    import re

    match = re.fullmatch(r"\s*(?:(\d+(?:\.\d+)?)h)?\s*(?:(\d+(?:\.\d+)?)m)?\s*"
                         r"(?:(\d+(?:\.\d+)?)s?)?\s*", text.lower())
    if not text.strip() or match is None or not any(match.groups()):
        raise argparse.ArgumentTypeError(f"expected a duration such as 90s, 10m or 1h30m, got "
                                         f"{text!r}")
    hours, minutes, seconds = (float(g) if g else 0.0 for g in match.groups())
    value = 3600 * hours + 60 * minutes + seconds
    if not 0 < value <= MAX_DURATION:
        raise argparse.ArgumentTypeError(f"a duration must be more than 0 and at most a week "
                                         f"(168h), got {text!r}")
    return value
REFINE_EPISODES = _int_at_least(1, "refinement episodes", MAX_REFINE_EPISODES)
PORT = _int_at_least(1, "a TCP port", 65_535)


def _writable_folder(folder: Path, what: str) -> None:
    """Fail unless ``folder`` is, or can be made inside, a folder we can write in (probed)."""
    existing = folder
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if not existing.is_dir():
        raise UsageError(f"{what}: {existing} is a file, not a folder; choose another path")
    try:
        fd, probe = tempfile.mkstemp(dir=existing, prefix=".ibt-probe-")
    except OSError as err:
        raise UsageError(f"{what}: cannot write in {existing} ({err.strerror}); choose another "
                         "path") from None
    os.close(fd)
    os.unlink(probe)


def _resolved(path: Path, what: str) -> Path:
    """``path`` with its links resolved, or a ``UsageError`` for a link loop."""
    try:
        return path.resolve(strict=False)
    except (RuntimeError, OSError):  # RuntimeError: Python 3.11's "Symlink loop from ..."
        raise UsageError(f"{what}: a loop of symbolic links; choose another path") from None


def same_path(a: str | Path, b: str | Path) -> bool:
    """Whether two paths name the same file or folder (through links; either may not exist)."""
    a, b = Path(a), Path(b)
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
        return a.resolve() == b.resolve()
    except (OSError, RuntimeError):
        return False


def check_not_input(outputs: Sequence[str | Path], *inputs: str | Path | None) -> None:
    """A ``UsageError`` when an output would write over one of the command's own inputs."""
    for out in outputs:
        for given in inputs:
            if given is not None and same_path(out, given):
                raise UsageError(f"-o {out} is the input {given}: a command never writes over "
                                 "its own input; name another output file")


def check_output(path: str | Path, suffixes: Sequence[str], option: str = "-o",
                 inputs: Sequence[str | Path] = ()) -> Path:
    """``path`` if a file of one of ``suffixes`` can be written there; checked before any work
    (a missing parent folder is fine: it is created when the file is written). A link is
    refused (writing would replace the link, not its target), and so is one of ``inputs``."""
    path = Path(path)
    what = f"{option} {path}"
    _resolved(path, what)
    if path.is_symlink():
        raise UsageError(f"{what} is a symbolic link (to {os.readlink(path)}); a command "
                         "replaces no link: name the file itself or another path")
    check_not_input([path], *inputs)
    if path.is_dir():
        raise UsageError(f"{what} is a folder; name a file in it, e.g. "
                         f"{option} {path / ('out' + suffixes[0])}")
    if path.suffix not in suffixes:
        raise UsageError(f"{what}: expected a {' or '.join(suffixes)} file, e.g. "
                         f"{option} {path.with_suffix(suffixes[0])}")
    _writable_folder(path.parent, what)
    if path.exists() and (not os.access(path, os.W_OK) or _mode_read_only(path)):
        raise UsageError(f"{what} is read-only; choose another path")
    sweep_temp_files(path)
    return path


def sweep_temp_files(path: Path, age: float = STALE_TEMP_SECONDS) -> list[Path]:
    """Remove the hidden temporary files a killed run left beside ``path`` (those of
    :func:`ibt.files.atomic_target`, ``.<name>.XXXXXXXX<suffix>``, and write probes) that were
    last written more than ``age`` seconds ago; returns them."""
    import re
    import time

    removed: list[Path] = []
    # the names tempfile.mkstemp makes (8 characters of its alphabet): a user's file of a like
    # name (".bt.json.backup") is not one of ours and stays
    ours = re.compile(rf"\.{re.escape(path.name)}\.[a-z0-9_]{{8}}{re.escape(path.suffix)}"
                      r"|\.ibt-probe-[a-z0-9_]{8}")
    try:
        candidates = [*path.parent.glob(f".{glob_escape(path.name)}.*"),
                      *path.parent.glob(".ibt-probe-*")]
    except OSError:
        return removed
    for temp in candidates:
        if not ours.fullmatch(temp.name):
            continue
        try:
            if temp.is_file() and not temp.is_symlink() \
                    and time.time() - temp.stat().st_mtime > age:
                temp.unlink()
                removed.append(temp)
        except OSError:
            continue
    return removed


def glob_escape(name: str) -> str:
    """``name`` with glob's special characters taken literally."""
    return glob.escape(name)


def _mode_read_only(path: Path) -> bool:
    """No write bit in the mode (root may write anyway, but the user said not to)."""
    import stat

    return not path.stat().st_mode & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH)


def _folder_path(path: Path, what: str) -> Path:
    """``path`` checked as a folder to be: no link loop, no dangling link, not a file, nor under
    one."""
    _resolved(path, what)
    if path.is_symlink() and not path.exists():
        raise UsageError(f"{what} is a symbolic link to {os.readlink(path)}, which does not "
                         "exist; choose another path")
    if path.exists() and not path.is_dir():
        raise UsageError(f"{what} is a file, not a folder; choose another path")
    return path


def check_output_folder(path: str | Path, option: str) -> Path:
    """``path`` if it is, or can become, a folder we can write in."""
    path = Path(path)
    _folder_path(path, f"{option} {path}")
    _writable_folder(path, f"{option} {path}")
    return path


def check_cache_folder(path: str | Path, option: str) -> Path:
    """``path`` if it is, or can become, a cache folder: no link loop, not a file, readable
    when it exists. A read-only cache is fine (hits are read, misses computed, not stored)."""
    path = Path(path)
    what = f"{option} {path}"
    _folder_path(path, what)
    if path.is_dir():
        try:
            next(os.scandir(path), None)
        except OSError as err:
            raise UsageError(f"{what}: cannot read it ({err.strerror}); choose another "
                             "folder") from None
    else:
        existing = path.parent
        while not existing.exists() and existing != existing.parent:
            existing = existing.parent
        if not existing.is_dir():
            raise UsageError(f"{what}: {existing} is a file, not a folder; choose another path")
    return path


@contextlib.contextmanager
def one_line_warnings() -> Iterator[None]:
    """While active, a warning prints as one line on stderr (``warning: MESSAGE``), without
    the file, line and source line Python adds: a user reads what happened, not our code."""
    import sys
    import warnings

    def show(message: Warning | str, category: type[Warning], *args: Any, **kwargs: Any
             ) -> None:
        print(f"warning: {' '.join(str(message).split())}", file=sys.stderr)

    with warnings.catch_warnings():
        warnings.showwarning = show
        yield


def check_input(path: str | Path, what: str, hint: str) -> Path:
    """``path`` if it is an existing regular file, else a ``UsageError`` ending with ``hint``
    (a device or a named pipe is refused: reading it would not end)."""
    path = Path(path)
    if path.is_dir():
        raise UsageError(f"{path} is a folder; pass the {what} itself")
    if not path.exists():
        raise UsageError(f"no {what} at {path}; {hint}")
    if not path.is_file():
        raise UsageError(f"{path} is not a regular file (a device, pipe or socket); pass the "
                         f"{what} itself")
    return path


def read_input(path: str | Path, what: str, hint: str, limit: int = MAX_BT_BYTES) -> bytes:
    """The bytes of an input file, checked by :func:`check_input` and at most ``limit``."""
    from ibt.distill.tree_file import read_regular_file

    path = check_input(path, what, hint)
    try:
        return read_regular_file(path, limit, what)
    except ValueError as err:
        raise UsageError(str(err)) from None


# ------------------------------------------------------------------------------ agents
CALLABLE = "callable"  #: the algorithm name of an agent given as MODULE:FUNCTION
AGENT_HELP = ("with algo callable: a function from one observation to an action (MODULE a .py "
              "file or an importable module); it is code: pass only agents you trust")


def add_agent_options(parser: argparse.ArgumentParser, checkpoint_help: str) -> None:
    """``--checkpoint`` and ``--agent``: an agent's options, alike in every command that takes
    one (the positional ``algo``, ``callable`` included, is the command's own)."""
    parser.add_argument("--checkpoint", help=checkpoint_help)
    parser.add_argument("--agent", metavar="MODULE:FUNCTION", help=AGENT_HELP)


def callable_spec(args: argparse.Namespace) -> str | None:
    """The agent's ``MODULE:FUNCTION`` where ``algo`` is ``callable`` (which takes ``--agent``
    and no ``--checkpoint``), None for an SB3 agent (``--checkpoint``, no ``--agent``); a
    ``UsageError`` for any other mix. The one reading of the agent options."""
    if args.algo == CALLABLE:
        if args.agent is None or args.checkpoint is not None:
            raise UsageError("algo callable takes --agent MODULE:FUNCTION (and no --checkpoint)")
        return str(args.agent)
    if args.agent is not None:
        raise UsageError(f"--agent is for algo callable; a {args.algo} agent is an SB3 "
                         "checkpoint: pass it with --checkpoint")
    return None


def rerun_command(args: argparse.Namespace, *extra: str) -> str:
    """The user's own command with ``extra`` arguments added (a hint that works)."""
    return "python -m ibt " + shlex.join([*args.argv, *extra])


# ---------------------------------------------------------------------- environments
EPISODE_STEPS = _int_at_least(1, "steps of an episode", 10**7)


def task_for(args: argparse.Namespace, name: str) -> Task:
    """The task a command line names, ready to roll out: resolved, a user's task checked
    against its environment (``TaskMismatch``, one line), and its episodes cut at
    ``--max-episode-steps`` or, where neither it nor its environment sets a limit, at the
    default cut, said once on stderr."""
    import sys

    from ibt.tasks.catalogue import check_user_task, resolve_task, with_episode_cap

    task = resolve_task(name)
    check_user_task(task)
    check_action_start(task)
    task, notice = with_episode_cap(task, getattr(args, "max_episode_steps", None))
    said = args.__dict__.setdefault("notices_said", set())
    if notice is not None and notice not in said:
        said.add(notice)
        print(notice, file=sys.stderr)
    return task


def check_action_start(task: Task) -> None:
    """:class:`UsageError` where a user's discrete environment numbers its actions from
    ``start != 0`` (``Discrete(n, start=k)``): ibt's actions are ``0..n-1``, and an action
    sent outside the space would blame the environment for ibt's mistake."""
    from ibt.tasks.catalogue import BUILTIN_BY_NAME

    if task.continuous or BUILTIN_BY_NAME.get(task.name) is task:
        return
    try:
        env = task.make_env()
    except Exception:  # check_user_task has named a failing constructor already
        return
    try:
        start = int(getattr(env.action_space, "start", 0))
        n = int(getattr(env.action_space, "n", 0))
    finally:
        env.close()
    if start != 0:
        raise UsageError(f"the environment {task.gym_id} numbers its actions from {start} "
                         f"(Discrete({n}, start={start})); ibt numbers a task's actions 0 to "
                         f"{n - 1}: register it with Discrete({n}) (start 0), or wrap it in a "
                         "gymnasium.ActionWrapper that adds the offset")


# ------------------------------------------------------------------------ tree files
def load_tree_file(path: str | Path, args: argparse.Namespace | None = None) -> dict[str, Any]:
    """A tree file of :mod:`ibt.distill.tree_file`, checked; a pickle only with --trust-pickle."""
    from ibt.distill.tree_file import TREE_SUFFIX
    from ibt.distill.tree_file import load_tree_file as load

    hint = (f"make one with `python -m ibt distill CartPole-v1 ppo -o "
            f"{shlex.quote(str(Path(path).with_suffix(TREE_SUFFIX)))}`")
    path = check_input(path, "decision-tree file", hint)
    return load(path, trust_pickle=bool(getattr(args, "trust_pickle", False)))


def tree_file_task(doc: dict[str, Any], path: str | Path, args: argparse.Namespace) -> Task:
    """The task a tree file was distilled on, with the names it was fitted on.

    A name of the form ``MODULE:EnvId`` in the file imports nothing: only ``--env-module`` on
    the command line imports (a file must not choose the code that runs)."""
    name = doc["task"]
    module, colon, bare = name.rpartition(":")
    if colon and module not in args.env_module:
        retry = rerun_command(args, "--env-module", module)
        raise UsageError(f"{path} was distilled on {bare}, which the module {module} registers; "
                         f"a tree file imports nothing: if you trust that module, run "
                         f"`{retry}`")
    try:
        task = task_for(args, bare)
    except LookupError:
        modules = [m for m in doc.get("env_modules", []) if m not in args.env_module]
        if modules:
            retry = rerun_command(args, "--env-module", modules[0])
            raise UsageError(f"{path} was distilled on {name}, an environment that "
                             f"{modules[0]} registers; run `{retry}`") from None
        raise
    if task.continuous:  # a command tree: its actions are the file's commands
        return _command_task(doc, path, task)
    if (task.feature_names, task.action_names) != (tuple(doc["feature_names"]),
                                                   tuple(doc["action_names"])):
        raise UsageError(f"{path} was fitted on {name} with features "
                         f"{', '.join(doc['feature_names'])} and actions "
                         f"{', '.join(doc['action_names'])}, but {name} now names "
                         f"{', '.join(task.feature_names)} and {', '.join(task.action_names)}; "
                         "distil it again")
    return task


def _command_task(doc: dict[str, Any], path: str | Path, task: Task) -> Task:
    """The discrete view (actions = the file's commands) of a Box task's command tree, checked:
    the task's features and action dimensions, every command finite and inside the Box."""
    from ibt.bt.model import Commands
    from ibt.synth.commands import command_task

    try:
        commands = Commands.from_dict(doc.get("commands"), len(doc["action_names"]))
        if (task.feature_names, task.action_names) != (tuple(doc["feature_names"]),
                                                       commands.dimensions):
            raise ValueError(f"it reads {', '.join(doc['feature_names'])} and commands "
                             f"{', '.join(commands.dimensions)}, but {task.name} has "
                             f"{', '.join(task.feature_names)} and "
                             f"{', '.join(task.action_names)}")
        task.check_action(commands.array())
    except ValueError as err:
        raise UsageError(f"{path} is not a command tree of {task.name}: {err}; distil it "
                         "again") from None
    return command_task(task, tuple(doc["action_names"]))


def bt_file_hint(path: str | Path) -> str:
    """The fix to name when a BT file is missing or bad: the commands that make one."""
    bt_file = shlex.quote(str(Path(path).with_suffix(".json")))
    return ("make one with `python -m ibt distill CartPole-v1 ppo -o tree.json` and "
            f"`python -m ibt synthesize tree.json -o {bt_file}`")


def read_json_input(path: str | Path, what: str, hint: str) -> Any:
    """A JSON input file: regular, bounded, strict (no duplicate keys)."""
    from ibt.distill.tree_file import parse_json

    data = read_input(path, what, hint)
    try:
        return parse_json(data, path, what)
    except ValueError as err:
        raise UsageError(str(err)) from None


def load_bt_file(path: str | Path, doc: Any = None):
    """A BT file (or its parsed ``doc``) as a BehaviorTree; bad input is a UsageError."""
    from ibt.bt.model import BehaviorTree

    if doc is None:
        doc = read_json_input(path, "behavior tree", bt_file_hint(path))
    try:
        return BehaviorTree.from_dict(doc)
    except RecursionError:
        raise UsageError(f"{path} is nested too deeply to be a behavior tree") from None
    except ValueError as err:
        raise UsageError(f"{path} is not a valid behavior tree: {err}") from None


# --------------------------------------------------------------------------- commands
