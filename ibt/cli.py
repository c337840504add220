"""``python -m ibt``: the pipeline's steps without notebooks.

    python -m ibt train CartPole-v1 --algo ppo           # train + record committed experts
    python -m ibt distill CartPole-v1 ppo -o tree.joblib  # expert -> decision tree
    python -m ibt refine tree.joblib -o small.joblib --max-leaves 3  # raise its return
    python -m ibt synthesize tree.joblib -o bt.json       # decision tree -> behavior tree
    python -m ibt evaluate bt.json --task CartPole-v1     # returns of a BT, tree or expert
    python -m ibt export bt.json --format btcpp-xml -o bt.xml
    python -m ibt run-btcpp bt.xml --task CartPole-v1     # BehaviorTree.CPP ticks the BT

Your own environment: ``--env-module PKG.MODULE`` (every subcommand) imports a module that
registers gymnasium environments and, optionally, ibt tasks (``ibt.tasks.catalogue.register_task``,
for
readable feature and action names); gymnasium's ``PKG.MODULE:EnvId`` works as a task name too.
``distill`` takes any gymnasium env id with an SB3 checkpoint (``--checkpoint``); the features
are then named x0, x1, ... and tasks without a budget get a 16-leaf tree.

Exit codes: 0 done; 2 bad input (one line on stderr naming the problem and the fix, nothing
written); 130 interrupted (Ctrl-C; files are written whole or not at all).
"""

from __future__ import annotations

import argparse
import math
import os
import shlex
import sys
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

from ibt.synth.registry import SYNTHESISERS, get_synthesiser
from ibt.tasks.settings import ALGOS, DEFAULT_MAX_LEAF_NODES

if TYPE_CHECKING:  # the CLI imports the compute stack only when a command runs
    from ibt.tasks.task import Task

EXPORT_FORMATS = ("json", "dot", "svg", "png", "btcpp-xml")
EXPORT_SUFFIXES = {"json": (".json",), "dot": (".dot", ".gv"), "svg": (".svg",),
                   "png": (".png",), "btcpp-xml": (".xml",)}
TREE_FORMAT = "ibt-tree/1"
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130


class UsageError(Exception):
    """Bad input found by the command line: exit code 2 and this one-line message."""


# ------------------------------------------------------------------------- input checks
def _int_at_least(minimum: int, what: str) -> Callable[[str], int]:
    """An argparse type: an integer >= ``minimum``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be at least {minimum} ({what}), got {value}")
        return value

    return parse


def _seconds(text: str) -> float:
    """An argparse type: a finite number of seconds, 0 or more."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not math.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0 (seconds), got {text}")
    return value


POSITIVE = _int_at_least(1, "a count")
SEED = _int_at_least(0, "a seed")
LEAVES = _int_at_least(2, "a tree")


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


def check_output(path: str | Path, suffixes: Sequence[str], option: str = "-o") -> Path:
    """``path`` if a file of one of ``suffixes`` can be written there; checked before any work
    (a missing parent folder is fine: it is created when the file is written)."""
    path = Path(path)
    what = f"{option} {path}"
    if path.is_dir():
        raise UsageError(f"{what} is a folder; name a file in it, e.g. "
                         f"{option} {path / ('out' + suffixes[0])}")
    if path.suffix not in suffixes:
        raise UsageError(f"{what}: expected a {' or '.join(suffixes)} file, e.g. "
                         f"{option} {path.with_suffix(suffixes[0])}")
    _writable_folder(path.parent, what)
    if path.exists() and not os.access(path, os.W_OK):
        raise UsageError(f"{what} is read-only; choose another path")
    return path


def check_output_folder(path: str | Path, option: str) -> Path:
    """``path`` if it is, or can become, a folder we can write in."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise UsageError(f"{option} {path} is a file, not a folder; choose another path")
    _writable_folder(path, f"{option} {path}")
    return path


def check_input(path: str | Path, what: str, hint: str) -> Path:
    """``path`` if it is an existing file, else a ``UsageError`` ending with ``hint``."""
    path = Path(path)
    if path.is_dir():
        raise UsageError(f"{path} is a folder; pass the {what} itself")
    if not path.exists():
        raise UsageError(f"no {what} at {path}; {hint}")
    return path


def _again(args: argparse.Namespace, *extra: str) -> str:
    """The user's own command with ``extra`` arguments added (a hint that works)."""
    return "python -m ibt " + shlex.join([*args.argv, *extra])


# ------------------------------------------------------------------------ tree files
def save_tree_file(path: str | Path, tree: Any, task: Task | str, info: dict[str, Any]) -> Path:
    """A decision tree with what it needs to be read again: the task, the names of the features
    and actions it was fitted on, the modules that register the task's environment, run facts."""
    from ibt.files import atomic_target
    from ibt.tasks.catalogue import resolve_task
    from ibt.tasks.task import Task

    task = task if isinstance(task, Task) else resolve_task(task)
    info = dict(info)
    setup = [task.setup_module] if task.setup_module else []
    modules = list(dict.fromkeys([*info.pop("env_modules", []), *setup]))
    path = Path(path)
    with atomic_target(path) as tmp:
        import joblib

        joblib.dump({"format": TREE_FORMAT, "tree": tree, "task": task.name,
                     "gym_id": task.gym_id, "env_modules": modules,
                     "feature_names": list(task.feature_names),
                     "action_names": list(task.action_names), **info}, tmp)
    return path


def load_tree_file(path: str | Path) -> dict[str, Any]:
    """A file of :func:`save_tree_file`, checked: a fitted tree whose feature count and actions
    match the names stored beside it."""
    from sklearn.tree import DecisionTreeClassifier

    hint = (f"make one with `python -m ibt distill CartPole-v1 ppo -o "
            f"{shlex.quote(str(Path(path).with_suffix('.joblib')))}`")
    path = check_input(path, "decision-tree file", hint)
    not_ours = f"{path} is not a decision-tree file written by `python -m ibt distill`"
    try:
        import joblib

        doc = joblib.load(path)
    except Exception as err:  # joblib raises many kinds on a damaged file
        raise UsageError(f"{not_ours} ({type(err).__name__})") from None
    keys = ("tree", "task", "feature_names", "action_names")
    if not isinstance(doc, dict) or any(k not in doc for k in keys):
        raise UsageError(not_ours)
    if doc.get("format", TREE_FORMAT) != TREE_FORMAT:
        raise UsageError(f"{path} is a {doc['format']!r} file; this version reads {TREE_FORMAT}")
    tree, names, actions = doc["tree"], doc["feature_names"], doc["action_names"]
    if not isinstance(tree, DecisionTreeClassifier) or not hasattr(tree, "tree_"):
        raise UsageError(f"{not_ours} (it holds no fitted decision tree)")
    if tree.n_features_in_ != len(names) or not set(map(int, tree.classes_)) <= set(
            range(len(actions))):
        raise UsageError(f"{path} is inconsistent: its tree reads {tree.n_features_in_} features"
                         f" and predicts {sorted(map(int, tree.classes_))}, but it names "
                         f"{len(names)} features and {len(actions)} actions; distil it again")
    return doc


def _tree_task(doc: dict[str, Any], path: str | Path, args: argparse.Namespace) -> Task:
    """The task a tree file was distilled on, with the names it was fitted on."""
    from ibt.tasks.catalogue import resolve_task

    name = doc["task"]
    try:
        task = resolve_task(name)
    except LookupError:
        modules = [m for m in doc.get("env_modules", []) if m not in args.env_module]
        if modules:
            retry = _again(args, "--env-module", modules[0])
            raise UsageError(f"{path} was distilled on {name}, an environment that "
                             f"{modules[0]} registers; run `{retry}`") from None
        raise
    if (task.feature_names, task.action_names) != (tuple(doc["feature_names"]),
                                                   tuple(doc["action_names"])):
        raise UsageError(f"{path} was fitted on {name} with features "
                         f"{', '.join(doc['feature_names'])} and actions "
                         f"{', '.join(doc['action_names'])}, but {name} now names "
                         f"{', '.join(task.feature_names)} and {', '.join(task.action_names)}; "
                         "distil it again")
    return task


def _load_bt(path: str | Path):
    from ibt.bt.json_io import load_json

    bt_file = shlex.quote(str(Path(path).with_suffix(".json")))
    path = check_input(path, "behavior tree", "make one with `python -m ibt distill CartPole-v1 "
                       f"ppo -o tree.joblib` and `python -m ibt synthesize tree.joblib -o "
                       f"{bt_file}`")
    try:
        return load_json(path)
    except ValueError as err:
        raise UsageError(f"{path} is not a valid behavior tree: {err}") from None


# --------------------------------------------------------------------------- commands
def _train(args: argparse.Namespace) -> int:
    from ibt.experts.expert import hyperparams
    from ibt.experts.training import train_missing
    from ibt.paths import DATA_DIR
    from ibt.tasks.catalogue import resolve_task

    # `train CartPole-v1 ppo` reads as `train CartPole-v1 --algo ppo`
    named_algos = [t.lower() for t in args.tasks if t.lower() in ALGOS]
    algos = list(dict.fromkeys([*(args.algo or []), *named_algos])) or list(ALGOS)
    tasks = [resolve_task(t) for t in args.tasks if t.lower() not in ALGOS]
    for task in tasks:
        for algo in algos:
            hyperparams(task, algo)  # before any training: every pair has its settings
    root = check_output_folder(args.experts_dir or DATA_DIR / "experts", "--experts-dir")
    since = None
    if args.refresh_before:
        stamp = Path(args.refresh_before)
        if not stamp.is_file():
            raise UsageError(f"--refresh-before {stamp}: no such file; create it when a "
                             f"from-scratch run starts with `touch {shlex.quote(str(stamp))}`")
        since = stamp.stat().st_mtime
    manifest = train_missing(tasks or None, algos, refresh=args.refresh, seed=args.seed,
                             timesteps=args.timesteps, refresh_before=since, root=root)
    print(manifest.to_string(index=False))
    return 0


def _random(args: argparse.Namespace) -> int:
    from ibt.experts.training import random_baselines
    from ibt.paths import DATA_DIR
    from ibt.tasks.catalogue import resolve_task

    tasks = [resolve_task(t) for t in args.tasks]
    path = check_output(args.output or DATA_DIR / "experts" / "random.csv", (".csv",))
    print(random_baselines(tasks or None, n_episodes=args.episodes, path=path)
          .to_string(index=False))
    return 0


def _distill(args: argparse.Namespace) -> int:
    from ibt.distill.loop import DistillConfig, distill
    from ibt.experts.expert import load_expert
    from ibt.tasks.catalogue import resolve_task

    task = resolve_task(args.task)
    out = check_output(args.output, (".joblib",))
    expert = load_expert(task, args.algo, args.checkpoint)
    overrides = {"n_iterations": args.iterations, "selection_episodes": args.selection_episodes}
    if args.labels is not None:
        overrides["labels_per_iteration"] = args.labels
    if args.max_leaf_nodes is not None:
        overrides["max_leaf_nodes"] = args.max_leaf_nodes
    config = DistillConfig.for_task(task, method=args.method, **overrides)
    run = distill(task, expert, config, seed=args.seed, progress=not args.quiet)
    best = run.iterations[run.best_index]
    save_tree_file(out, run.best_tree, task,
                   {"algo": args.algo, "method": args.method, "seed": args.seed,
                    "iterations": run.iterations, "best_index": run.best_index,
                    "env_modules": args.env_module})
    print(f"{task.name}/{args.algo}/{args.method}: best tree at iteration {run.best_index} "
          f"({best['leaves']} leaves of at most {config.max_leaf_nodes}, {best['nodes']} nodes, "
          f"held-out return {best['selection_mean']:.2f}); {run.expert_labels} expert labels; "
          f"written to {out}")
    return 0


def _refine(args: argparse.Namespace) -> int:
    from ibt.refine.by_return import refine, task_config

    out = check_output(args.output, (".joblib",))
    doc = load_tree_file(args.tree)
    task = _tree_task(doc, args.tree, args)
    overrides: dict[str, Any] = {"max_leaves": args.max_leaves}
    if args.episodes is not None:
        overrides["episodes"] = args.episodes
    config = task_config(task, **overrides)
    record = refine(doc["tree"], task, config, seed=args.seed, progress=not args.quiet)
    tree = record.best_tree
    info = {k: v for k, v in doc.items() if k in ("algo", "method", "seed")}
    save_tree_file(out, tree, task, {**info, "refined_from": str(args.tree),
                                     "refinement": {"stages": record.stages,
                                                    "selection_means": record.selection_means,
                                                    "best_index": record.best_index,
                                                    "config": record.config},
                                     "env_modules": args.env_module})
    before, after = record.selection_means[0], record.selection_means[record.best_index]
    print(f"{task.name}: {record.candidates[0].n_leaves} -> {record.best.n_leaves} leaves, "
          f"held-out return {before:.2f} -> {after:.2f} ({record.episodes} refinement "
          f"episodes, {record.cpu_seconds:.0f} s CPU); written to {out}")
    return 0


def _synthesize(args: argparse.Namespace) -> int:
    from ibt.bt.json_io import save_json
    from ibt.synth.imitation import NotEquivalentError, imitation_bt

    out = check_output(args.output, (".json",))
    doc = load_tree_file(args.tree)
    task = _tree_task(doc, args.tree, args)
    try:
        if args.method == "imitation-bt":  # the paper's construction takes its options
            result = imitation_bt(doc["tree"], task, default_strategy=args.default_strategy,
                                  dont_cares=args.dont_cares)
        else:
            result = get_synthesiser(args.method)(doc["tree"], task)
    except NotEquivalentError as err:  # a bug of ours, not bad input: nothing is written
        raise RuntimeError(f"the synthesised BT failed its verification ({err}); please "
                           "report it with the tree file") from None
    result.bt.validate()  # every state reaches an action, so the file will load again
    save_json(result.bt, out)
    print(f"{args.method}: {result.bt.node_count} nodes, verified equivalent to the tree; "
          f"written to {out}")
    return 0


def _matching_tasks(bt: Any) -> list[str]:
    from ibt.tasks.catalogue import TASKS

    return [t.name for t in TASKS.values()
            if (t.feature_names, t.action_names) == (bt.feature_names, bt.action_names)]


def _load_policy(path: Path, args: argparse.Namespace):
    from ibt.evaluate.policies import BTPolicy, TreePolicy
    from ibt.tasks.catalogue import resolve_task

    if path.suffix == ".json":
        bt = _load_bt(path)
        if args.task is None:
            known = _matching_tasks(bt)
            if len(known) == 1:
                raise UsageError(f"a BT file does not name its task; its names are "
                                 f"{known[0]}'s: run `{_again(args, '--task', known[0])}`")
            raise UsageError("a BT file does not name its task; pass --task with the "
                             "environment it was made for")
        task = resolve_task(args.task)
        if (bt.feature_names, bt.action_names) != (task.feature_names, task.action_names):
            known = _matching_tasks(bt)
            fix = (f"run `{_again(args, '--task', known[0])}`" if len(known) == 1
                   else "pass the task the BT was made for")
            raise UsageError(f"{path} reads {', '.join(bt.feature_names)} and acts "
                             f"{', '.join(bt.action_names)}, but {task.name} has "
                             f"{', '.join(task.feature_names)} and "
                             f"{', '.join(task.action_names)}; {fix}")
        return task, BTPolicy(task, bt)
    if path.suffix != ".joblib" and not path.exists():
        raise UsageError(f"{path}: expected a BT (.json), a decision-tree file (.joblib) or an "
                         f"expert ({', '.join(ALGOS)})")
    doc = load_tree_file(path)
    task = _tree_task(doc, path, args)
    if args.task is not None and resolve_task(args.task).name != task.name:
        raise UsageError(f"{path} was distilled on {task.name}, not {args.task}; drop --task "
                         f"or pass --task {task.name}")
    return task, TreePolicy(task, doc["tree"])


def _evaluate(args: argparse.Namespace) -> int:
    from ibt.evaluate.rollouts import episode_metrics, final_seeds, rollout
    from ibt.experts.expert import load_expert
    from ibt.tasks.catalogue import resolve_task

    if args.policy in ALGOS:
        if args.task is None:
            raise UsageError(f"evaluating an expert needs --task, e.g. "
                             f"`{_again(args, '--task', 'CartPole-v1')}`")
        task = resolve_task(args.task)
        policy: Any = load_expert(task, args.policy, args.checkpoint)
    else:
        if args.checkpoint is not None:
            raise UsageError(f"--checkpoint is for experts ({', '.join(ALGOS)}), not for "
                             f"{args.policy}; drop it")
        task, policy = _load_policy(Path(args.policy), args)
    result = rollout(task, policy.act, final_seeds(args.episodes))
    extra = "".join(f", {k} {v:.3f}" for k, v in episode_metrics(task, result).items())
    print(f"{task.name}: mean return {result.mean:.3f} +- {result.std:.3f} over "
          f"{len(result.returns)} episodes{extra}")
    return 0


def _export(args: argparse.Namespace) -> int:
    from ibt.bt.json_io import save_json
    from ibt.export.drawing import require_dot, to_graphviz
    from ibt.export.pictures import save_drawing
    from ibt.files import atomic_write_text

    out = check_output(args.output, EXPORT_SUFFIXES[args.format])
    if args.format in ("svg", "png"):
        require_dot()
    bt = _load_bt(args.bt)
    if args.format == "json":
        save_json(bt, out)
    elif args.format == "btcpp-xml":
        from ibt.export.btcpp import to_btcpp_xml

        atomic_write_text(out, to_btcpp_xml(bt, flavour=args.flavour))
    elif args.format == "dot":
        atomic_write_text(out, to_graphviz(bt).source)
    else:
        save_drawing(to_graphviz(bt), out.with_suffix(""), formats=(args.format,))
    print(f"written {out}")
    return 0


def _run_btcpp(args: argparse.Namespace) -> int:
    from ibt.export.engine import run_btcpp
    from ibt.tasks.catalogue import resolve_task

    xml = check_input(args.xml, "BehaviorTree.CPP XML", "write one with `python -m ibt export "
                      "BT.json --format btcpp-xml -o BT.xml`")
    run = run_btcpp(xml, resolve_task(args.task), args.episodes, args.groot_port,
                    args.step_delay)
    print(run.summary())
    if not run.ok:
        print("error: BehaviorTree.CPP and the Python BT disagree (a bug: please report it)",
              file=sys.stderr)
    return 0 if run.ok else 1


# ----------------------------------------------------------------------------- parser
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
    train.add_argument("--timesteps", type=POSITIVE, default=None, help="override the table")
    train.add_argument("--experts-dir", metavar="DIR",
                       help="where checkpoints and manifest.csv go (default: data/experts)")
    train.set_defaults(func=_train)

    rnd = command("random-baselines", help="write data/experts/random.csv")
    rnd.add_argument("tasks", nargs="*", metavar="TASK")
    rnd.add_argument("--episodes", type=POSITIVE, default=100)
    rnd.add_argument("-o", "--output", help="CSV to write (default: data/experts/random.csv)")
    rnd.set_defaults(func=_random)

    dist = command("distill", help="distil an expert into a decision tree")
    dist.add_argument("task", help="a registered task, any gymnasium env id, or MODULE:EnvId")
    dist.add_argument("algo", choices=ALGOS)
    dist.add_argument("-o", "--output", required=True, help="decision-tree file (.joblib)")
    dist.add_argument("--checkpoint", help="SB3 checkpoint (default: the committed expert)")
    dist.add_argument("--method", default="imitation-bt",
                      choices=("bc", "dagger", "viper", "imitation-bt"))
    dist.add_argument("--seed", type=SEED, default=0)
    dist.add_argument("--iterations", type=POSITIVE, default=50)
    dist.add_argument("--selection-episodes", type=POSITIVE, default=20)
    dist.add_argument("--labels", type=POSITIVE, default=None,
                      help="expert labels per iteration (default: the task's budget)")
    dist.add_argument("--max-leaf-nodes", type=LEAVES, default=None,
                      help="leaf limit of the tree (default: the task's budget in "
                      f"ibt.distill.loop.TASK_BUDGETS; {DEFAULT_MAX_LEAF_NODES} for other tasks)")
    dist.add_argument("--quiet", action="store_true", help="no progress bar")
    dist.set_defaults(func=_distill)

    ref = command("refine", help="raise a decision tree's return by refinement (thresholds "
                  "by CMA-ES, leaf actions, pruning), optionally to a leaf limit")
    ref.add_argument("tree", help="decision-tree file from `distill` (or `refine`)")
    ref.add_argument("-o", "--output", required=True, help="refined decision-tree file (.joblib)")
    ref.add_argument("--max-leaves", type=POSITIVE, default=None,
                     help="prune to at most this many leaves (default: no forced pruning)")
    ref.add_argument("--episodes", type=POSITIVE, default=None,
                     help="refinement budget in episodes (default: the task's, "
                     "ibt.refine.by_return.REFINE_BUDGETS; 20,000 for other tasks)")
    ref.add_argument("--seed", type=SEED, default=0)
    ref.add_argument("--quiet", action="store_true", help="no progress bar")
    ref.set_defaults(func=_refine)

    syn = command("synthesize", help="turn a decision tree into a verified BT (JSON)")
    syn.add_argument("tree", help="decision-tree file from `distill`")
    syn.add_argument("-o", "--output", required=True, help="BT JSON file")
    syn.add_argument("--method", default="imitation-bt", choices=tuple(SYNTHESISERS),
                     help="a registered synthesiser (ibt.synth.registry); default imitation-bt")
    syn.add_argument("--default-strategy", default="max_complexity",
                     choices=("max_complexity", "most_frequent", "smallest_tree"))
    syn.add_argument("--dont-cares", action="store_true",
                     help="give Espresso the impossible threshold combinations as don't-cares")
    syn.set_defaults(func=_synthesize)

    ev = command("evaluate", help="returns of a BT (.json), a tree (.joblib) or an "
                 "expert (dqn/ppo/a2c) on the fixed evaluation episodes")
    ev.add_argument("policy", help="BT JSON, decision-tree file, or dqn|ppo|a2c")
    ev.add_argument("--task", help="task (required for BT files and experts)")
    ev.add_argument("--checkpoint", help="SB3 checkpoint for an expert")
    ev.add_argument("--episodes", type=POSITIVE, default=100)
    ev.set_defaults(func=_evaluate)

    ex = command("export", help="write a BT as json, dot, svg, png or BehaviorTree.CPP v4 XML")
    ex.add_argument("bt", help="BT JSON file")
    ex.add_argument("--format", required=True, choices=EXPORT_FORMATS)
    ex.add_argument("-o", "--output", required=True,
                    help="file to write, with the format's suffix (.json, .dot, .svg, .png, .xml)")
    ex.add_argument("--flavour", default="portable", choices=("portable", "check-feature"),
                    help="btcpp-xml only: 'portable' (default) runs in stock BehaviorTree.CPP "
                    "with ScriptConditions on blackboard keys; 'check-feature' needs a custom "
                    "C++ CheckFeature condition node")
    ex.set_defaults(func=_export)

    rb = command("run-btcpp", help="roll a BehaviorTree.CPP XML out with the engine "
                 "(behaviortreepy) ticking, beside the Python BT on the same seeds")
    rb.add_argument("xml", help="XML from `export --format btcpp-xml` (portable flavour)")
    rb.add_argument("--task", required=True, help="the task whose BT the XML is")
    rb.add_argument("--episodes", type=POSITIVE, default=10)
    rb.add_argument("--groot-port", type=POSITIVE, default=None, metavar="PORT",
                    help="publish the tree to Groot2 on this port while it runs "
                    "(behaviortreepy's Groot2Publisher; connect Groot2 to it)")
    rb.add_argument("--step-delay", type=_seconds, default=0.0, metavar="SECONDS",
                    help="sleep between steps, to watch a run in Groot2")
    rb.set_defaults(func=_run_btcpp)
    return parser


def _one_line(err: BaseException) -> str:
    if isinstance(err, KeyError) and err.args:
        text = str(err.args[0])
    elif isinstance(err, OSError) and err.filename is not None:
        text = f"{err.filename}: {err.strerror or err}"
    else:
        text = str(err)
    return " ".join(text.split())


def main(argv: list[str] | None = None) -> int:
    """Run one subcommand: 0 when done, 2 on bad input (one line on stderr, nothing written),
    130 when interrupted (Ctrl-C)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as stop:  # --help (0) or a usage error, already printed as one line (2)
        return stop.code if isinstance(stop.code, int) else EXIT_BAD_INPUT
    args.argv = argv
    try:
        from ibt.tasks.catalogue import import_env_module

        for module in args.env_module:
            import_env_module(module)
        return int(args.func(args))
    except KeyboardInterrupt:
        print("interrupted: stopped before the next write (files are written whole or not at "
              "all)", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (UsageError, KeyError, ValueError, LookupError, RuntimeError, OSError) as err:
        print(f"error: {_one_line(err)}", file=sys.stderr)
        return EXIT_BAD_INPUT
