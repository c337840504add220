"""``python -m ibt``: the pipeline's steps without notebooks.

    python -m ibt train CartPole-v1 --algo ppo           # train + record committed experts
    python -m ibt distill CartPole-v1 ppo -o tree.json    # expert -> decision tree
    python -m ibt refine tree.json -o small.json --max-leaves 3  # raise its return
    python -m ibt synthesize tree.json -o bt.json         # decision tree -> behavior tree
    python -m ibt evaluate bt.json --task CartPole-v1     # returns of a BT, tree or expert
    python -m ibt export bt.json --format btcpp-xml -o bt.xml
    python -m ibt run-btcpp bt.xml --task CartPole-v1     # BehaviorTree.CPP ticks the BT
    python -m ibt pipeline CartPole-v1 ppo -o out/        # all of it: a recommended BT + report

Your own environment: ``--env-module PKG.MODULE`` (every subcommand) imports a module that
registers gymnasium environments and, optionally, ibt tasks with readable feature and action
names (``ibt.tasks.catalogue.register_task``); gymnasium's ``PKG.MODULE:EnvId`` works as a task
name too.
``distill`` takes any gymnasium env id with an SB3 checkpoint (``--checkpoint``) or, as
``pipeline``, an agent ``callable --agent MODULE:FUNCTION``; the features are then named x0,
x1, ... and tasks without a budget get a 16-leaf tree.

Files: decision trees (``ibt-tree``) and BTs are JSON and reading them never runs code; a tree
file of earlier versions (``.joblib``, a pickle) is converted once, if you trust its source, by
``python -m ibt convert-tree old.joblib -o tree.json --trust-pickle``. An SB3 checkpoint
(``--checkpoint``) IS code (its zip holds pickles): load only checkpoints from a trusted source;
they are checked against the task (spaces, normalisation sidecar ``<ckpt>.obs_norm.json``).

Exit codes: 0 done; 2 bad input (one line on stderr naming the problem and the fix, nothing
written); 130 interrupted (Ctrl-C), 143 terminated (SIGTERM): files are written whole or not at
all, and temporary files left by a killed run are swept by the next run that writes there.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from typing import TYPE_CHECKING, Any, NoReturn

from ibt.synth.registry import SYNTHESISERS
from ibt.tasks.settings import ALGOS, BOX_MAX_LEAF_NODES, DEFAULT_MAX_LEAF_NODES

if TYPE_CHECKING:  # the CLI imports the compute stack only when a command runs
    pass

from ibt.cli.bt_commands import evaluate_command, export_command, run_btcpp_command
from ibt.cli.checks import (
    CALLABLE,
    EPISODE_STEPS,
    EPISODES,
    EXIT_BAD_INPUT,
    EXIT_INTERRUPTED,
    EXIT_TERMINATED,
    EXPORT_FORMATS,
    ITERATIONS,
    JOBS,
    LABELS,
    LEAVES,
    MAX_NODES,
    PORT,
    REFINE_EPISODES,
    RESTARTS,
    SEED,
    TIMESTEPS,
    Terminated,
    UsageError,
    add_agent_options,
    duration_arg,
    seconds_arg,
)
from ibt.cli.commands import (
    convert_tree_command,
    distill_command,
    random_command,
    refine_command,
    synthesize_command,
    train_command,
)
from ibt.cli.pipeline_command import budget_arg, keep_arg, leaf_limits_arg, pipeline_command

TRUST_HELP = ("read a pickled (.joblib) tree file of earlier versions: it runs the code it "
              "holds, so only for files from a trusted source (better: convert-tree it once)")

class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors that name the help command."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message}; see `{self.prog} --help`\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="python -m ibt", description=__doc__,
                     formatter_class=argparse.RawDescriptionHelpFormatter)
    common = _Parser(add_help=False)
    common.add_argument("--env-module", action="append", default=[], metavar="MODULE",
                        help="import MODULE first: it registers your gymnasium environments "
                        "(and, optionally, ibt tasks with readable names); repeatable")
    sub = parser.add_subparsers(dest="command", required=True)

    def command(name: str, **kwargs: Any) -> argparse.ArgumentParser:
        return sub.add_parser(name, parents=[common], **kwargs)

    train = command("train", help="train, evaluate and record experts "
                    "(missing ones only unless --refresh)")
    train.add_argument("tasks", nargs="*", metavar="TASK",
                       help="task names (default: all); an algorithm name here counts as --algo")
    train.add_argument("--algo", action="append", choices=ALGOS, help="repeatable; default all")
    train.add_argument("--refresh", action="store_true", help="retrain existing experts")
    train.add_argument("--refresh-before", metavar="FILE",
                       help="retrain experts older than FILE (a resumable --refresh)")
    train.add_argument("--seed", type=SEED, default=0)
    train.add_argument("--timesteps", type=TIMESTEPS, default=None, help="override the table")
    train.add_argument("--experts-dir", metavar="DIR",
                       help="where checkpoints and manifest.csv go (default: data/experts)")
    train.set_defaults(func=train_command)

    rnd = command("random-baselines", help="write data/experts/random.csv")
    rnd.add_argument("tasks", nargs="*", metavar="TASK")
    rnd.add_argument("--episodes", type=EPISODES, default=100)
    rnd.add_argument("-o", "--output", help="CSV to write (default: data/experts/random.csv)")
    rnd.set_defaults(func=random_command)

    dist = command("distill", help="distil an expert into a decision tree")
    dist.add_argument("task", help="a registered task, any gymnasium env id, or MODULE:EnvId")
    dist.add_argument("algo", choices=(*ALGOS, CALLABLE),
                      help="the agent's algorithm (an SB3 checkpoint), or callable with --agent")
    dist.add_argument("-o", "--output", required=True, help="decision-tree file (.json)")
    add_agent_options(dist, "SB3 checkpoint (default: the committed expert); a checkpoint is "
                      "code (pickles): use only ones from a trusted source")
    dist.add_argument("--method", default="imitation-bt",
                      choices=("bc", "dagger", "viper", "imitation-bt", "imitation-bt+rel"))
    dist.add_argument("--seed", type=SEED, default=0)
    dist.add_argument("--iterations", type=ITERATIONS, default=None,
                      help="default 50; on a Box task (continuous actions) its budget's, or 20")
    dist.add_argument("--selection-episodes", type=EPISODES, default=20)
    dist.add_argument("--labels", type=LABELS, default=None,
                      help="at least this many new expert labels per iteration: whole episodes "
                      "are collected until that many steps have been taken, so an iteration "
                      "adds a little more (default: the task's budget)")
    dist.add_argument("--max-leaf-nodes", type=LEAVES, default=None,
                      help="leaf limit of the tree (default: the task's budget in its "
                      f"catalogue entry, Task.budget; {DEFAULT_MAX_LEAF_NODES} for other "
                      f"tasks, {BOX_MAX_LEAF_NODES} for other tasks with continuous actions, "
                      "whose leaves are then merged into named commands)")
    dist.add_argument("--quiet", action="store_true", help="no progress bar")
    dist.set_defaults(func=distill_command)

    ref = command("refine", help="raise a decision tree's return by refinement (thresholds "
                  "by CMA-ES, leaf actions, pruning), optionally to a leaf limit")
    ref.add_argument("tree", help="decision-tree file (.json) from `distill` (or `refine`)")
    ref.add_argument("-o", "--output", required=True, help="refined decision-tree file (.json)")
    ref.add_argument("--max-leaves", type=LEAVES, default=None,
                     help="prune to at most this many leaves (default: no forced pruning)")
    ref.add_argument("--episodes", type=REFINE_EPISODES, default=None,
                     help="refinement budget in episodes (default: the task's, "
                     "its catalogue entry, Task.refine; 20,000 for other tasks)")
    ref.add_argument("--seed", type=SEED, default=0)
    ref.add_argument("--quiet", action="store_true", help="no progress bar")
    ref.add_argument("--trust-pickle", action="store_true", help=TRUST_HELP)
    ref.set_defaults(func=refine_command)

    syn = command("synthesize", help="turn a decision tree into a verified BT (JSON)")
    syn.add_argument("tree", help="decision-tree file (.json) from `distill`")
    syn.add_argument("-o", "--output", required=True, help="BT JSON file")
    syn.add_argument("--method", default="imitation-bt", choices=tuple(SYNTHESISERS),
                     help="a registered synthesiser (ibt.synth.registry); default imitation-bt")
    syn.add_argument("--default-strategy", default="max_complexity",
                     choices=("max_complexity", "most_frequent", "smallest_tree"))
    syn.add_argument("--dont-cares", action="store_true",
                     help="give Espresso the impossible threshold combinations as don't-cares")
    syn.add_argument("--trust-pickle", action="store_true", help=TRUST_HELP)
    syn.set_defaults(func=synthesize_command)

    ev = command("evaluate", help="returns of a BT (.json), a decision tree (.json) or an "
                 f"expert ({'/'.join(ALGOS)}) on the fixed evaluation episodes")
    ev.add_argument("policy", help=f"BT JSON, decision-tree file, or {'|'.join(ALGOS)}")
    ev.add_argument("--task", help="task (required for BT files and experts)")
    ev.add_argument("--checkpoint", help="SB3 checkpoint for an expert; a checkpoint is code "
                    "(pickles): use only ones from a trusted source")
    ev.add_argument("--episodes", type=EPISODES, default=100)
    ev.add_argument("--trust-pickle", action="store_true", help=TRUST_HELP)
    ev.set_defaults(func=evaluate_command)

    conv = command("convert-tree", help="convert a decision-tree file of earlier versions "
                   "(.joblib, a pickle) into the JSON format")
    conv.add_argument("tree", help="the .joblib file (it runs code when read: trusted only)")
    conv.add_argument("-o", "--output", required=True, help="decision-tree file (.json)")
    conv.add_argument("--trust-pickle", action="store_true",
                      help="required: you trust the file's source (unpickling runs its code)")
    conv.set_defaults(func=convert_tree_command)

    ex = command("export", help="write a BT as json, dot, svg, png or BehaviorTree.CPP v4 XML")
    ex.add_argument("bt", help="BT JSON file")
    ex.add_argument("--format", required=True, choices=EXPORT_FORMATS)
    ex.add_argument("-o", "--output", required=True,
                    help="file to write, with the format's suffix (.json, .dot, .svg, .png, .xml)")
    ex.add_argument("--flavour", default="portable", choices=("portable", "check-feature"),
                    help="btcpp-xml only: 'portable' (default) runs in stock BehaviorTree.CPP "
                    "with ScriptConditions on blackboard keys; 'check-feature' needs a custom "
                    "C++ CheckFeature condition node")
    ex.set_defaults(func=export_command)

    rb = command("run-btcpp", help="roll a BehaviorTree.CPP XML out with the engine "
                 "(behaviortreepy) ticking, beside the Python BT on the same seeds")
    rb.add_argument("xml", help="XML from `export --format btcpp-xml` (portable flavour)")
    rb.add_argument("--task", required=True, help="the task whose BT the XML is")
    rb.add_argument("--episodes", type=EPISODES, default=10)
    rb.add_argument("--groot-port", type=PORT, default=None, metavar="PORT",
                    help="publish the tree to Groot2 on this port while it runs "
                    "(behaviortreepy's Groot2Publisher; connect Groot2 to it)")
    rb.add_argument("--step-delay", type=seconds_arg, default=0.0, metavar="SECONDS",
                    help="sleep between steps, to watch a run in Groot2")
    rb.set_defaults(func=run_btcpp_command)

    pl = command("pipeline", help="from an agent to a recommended BT, anytime: distil and refine "
                 "at increasing leaf limits, search structure where the target is not kept, "
                 "synthesise every verified BT, evaluate on held-out episodes, and write bt.json, "
                 "bt.xml, bt.png, bt.svg, faithful_bt.json, faithful_bt.xml, front.png, "
                 "episode.gif and report.md")
    pl.add_argument("task", help="a registered task, any gymnasium env id, or MODULE:EnvId")
    pl.add_argument("algo", choices=(*ALGOS, CALLABLE),
                    help="the agent's algorithm (an SB3 checkpoint), or callable with --agent")
    pl.add_argument("-o", "--output", required=True, metavar="DIR",
                    help="folder to write: new, empty, or one the pipeline wrote before (its "
                    "marker .ibt-pipeline.json lists its files); see --force")
    add_agent_options(pl, "SB3 checkpoint (default: the committed expert)")
    pl.add_argument("--keep", type=keep_arg, default=0.95,
                    help="target share of the agent's random-normalised return (default 0.95)")
    clock = pl.add_mutually_exclusive_group()
    clock.add_argument("--time", type=duration_arg, default="10m", metavar="DURATION",
                    help="wall-clock budget such as 90s, 10m, 1h30m; the best BT found by then "
                    "is recommended (default 10m); a step under way may finish within a tenth of "
                    "the budget (at least 1m) past it, else it is cut, and a first search sure "
                    "to be cut is not started; time left over polishes again the searched BT "
                    "nearest the target; a rerun with more time resumes from the cache")
    clock.add_argument("--plan", metavar="PLAN.JSON",
                       help="replay the steps a run took, its plan.json (no --time: every "
                       "planned step runs and nothing else), for the same BT on any machine; "
                       "give the options of the run that made it (the report's Reproduce "
                       "section prints the command)")
    pl.add_argument("--max-nodes", type=MAX_NODES, default=None, metavar="N",
                    help="recommend only BTs of at most N nodes")
    pl.add_argument("--restarts", type=RESTARTS, default=3, metavar="K",
                    help="seeds of each structure search, chosen among on held-out episodes "
                    "(default 3); the ladder's last search spends time left over on up to 4K")
    pl.add_argument("--jobs", type=JOBS, default=None, metavar="N",
                    help="processes for the work run side by side: distillations, "
                    "refinements and a search's restarts, each with its progress on a line under "
                    "the pipeline's (default: the machine's cores; a Dask cluster when "
                    "IBT_DASK_SCHEDULER holds its address)")
    pl.add_argument("--budget", type=budget_arg, default="1x",
                    help="smoke (seconds), a scale of every step's episode budget such as 2x, "
                    "or refinement episodes per tree such as 40000 (default 1x)")
    pl.add_argument("--leaves", type=leaf_limits_arg, default=(4, 8, 16, 32), metavar="L,L,...",
                    help="leaf limits (default 4,8,16,32): distilled smallest first, searched "
                         "by bisection")
    pl.add_argument("--episodes", type=EPISODES, default=None,
                    help="held-out episodes per evaluation (default: 100; 5 with --budget smoke)")
    pl.add_argument("--seed", type=SEED, default=0)
    pl.add_argument("--cache-dir", metavar="DIR", help="cache of every step (default: DIR/cache)")
    pl.add_argument("--force", action="store_true",
                    help="write into a folder holding files the pipeline did not write: its "
                    "output names are replaced (said first), other files left alone; "
                    "read-only files are never replaced")
    pl.add_argument("--quiet", action="store_true", help="no progress bars")
    pl.set_defaults(func=pipeline_command)
    for rolls_out in (rnd, dist, ref, ev, rb, pl):
        rolls_out.add_argument("--max-episode-steps", type=EPISODE_STEPS, default=None,
                               metavar="N", help="cut every episode at N steps (default: the "
                               "environment's own limit, or 1,000 steps where it sets none)")
    return parser


def _one_line(err: BaseException) -> str:
    if isinstance(err, KeyError) and err.args:
        text = str(err.args[0])
    elif isinstance(err, OSError) and err.filename is not None:
        text = f"{err.filename}: {err.strerror or err}"
    else:
        text = str(err)
    return " ".join(text.split())


def _import_env_module(module: str) -> None:
    """``--env-module``: imported; its ``sys.exit`` is bad input too, not an exit of ours."""
    from ibt.tasks.catalogue import import_env_module

    try:
        import_env_module(module)
    except SystemExit as stop:
        raise UsageError(f"the environment module {module!r} called sys.exit({stop.code!r}) "
                         "while imported; a module given to --env-module must only register "
                         "environments") from None


#: the code of Python's import machinery, as frames name it
_IMPORT_MACHINERY = "<frozen importlib._bootstrap"
#: seconds before a SIGTERM that arrived inside an import is delivered again
REDELIVERY_S = 0.05


def _importing(frame: Any) -> bool:
    """Whether ``frame`` runs inside an import (one of its callers is the import machinery)."""
    while frame is not None:
        if frame.f_code.co_filename.startswith(_IMPORT_MACHINERY):
            return True
        frame = frame.f_back
    return False


def _terminate(signum: int, frame: Any) -> None:
    """SIGTERM's handler: raise :class:`Terminated` where the process is, except inside an
    import, where the exception can cross a C extension's initialisation (torch's, through
    pybind11), which aborts the process (exit -6, no message) instead of unwinding: there the
    signal is sent again shortly, to be raised once the import is done."""
    import os
    import threading

    if _importing(frame):
        timer = threading.Timer(REDELIVERY_S, os.kill, (os.getpid(), signum))
        timer.daemon = True
        timer.start()
        return
    raise Terminated


@contextlib.contextmanager
def _sigterm_unwinds() -> Any:
    """While active (main thread only), SIGTERM raises :class:`Terminated` where the process is:
    ``finally`` blocks run, so temporary files are removed as on Ctrl-C."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _terminate)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def main(argv: list[str] | None = None) -> int:
    """Run one subcommand: 0 when done, 2 on bad input (one line on stderr, nothing written),
    130 when interrupted (Ctrl-C), 143 when terminated (SIGTERM)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        with _sigterm_unwinds():
            return _main(argv)
    except KeyboardInterrupt:
        print("interrupted: stopped before the next write (files are written whole or not at "
              "all)", file=sys.stderr)
        return EXIT_INTERRUPTED
    except Terminated:
        print("terminated (SIGTERM): stopped before the next write (files are written whole or "
              "not at all)", file=sys.stderr)
        return EXIT_TERMINATED


def _main(argv: list[str]) -> int:
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as stop:  # --help (0) or a usage error, already printed as one line (2)
        return stop.code if isinstance(stop.code, int) else EXIT_BAD_INPUT
    args.argv = argv
    try:
        for module in args.env_module:
            _import_env_module(module)
        return int(args.func(args))
    except (UsageError, KeyError, ValueError, LookupError, RuntimeError, OSError) as err:
        print(f"error: {_one_line(err)}", file=sys.stderr)
        return EXIT_BAD_INPUT
