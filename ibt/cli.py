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
registers gymnasium environments and, optionally, ibt tasks (``ibt.tasks.catalogue.register_task``,
for
readable feature and action names); gymnasium's ``PKG.MODULE:EnvId`` works as a task name too.
``distill`` takes any gymnasium env id with an SB3 checkpoint (``--checkpoint``); the features
are then named x0, x1, ... and tasks without a budget get a 16-leaf tree.

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
import glob
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
EXIT_BAD_INPUT = 2
EXIT_INTERRUPTED = 130
EXIT_TERMINATED = 143
MAX_BT_BYTES = 64 << 20  # a BT or XML file larger than this is refused (not read)
STALE_TEMP_SECONDS = 30  # hidden temp files older than this, beside an output, are swept


class UsageError(Exception):
    """Bad input found by the command line: exit code 2 and this one-line message."""


class Terminated(BaseException):
    """SIGTERM, raised where the process is, so that it unwinds like Ctrl-C (exit 143)."""


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


def _seconds(text: str) -> float:
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
LEAVES = _int_at_least(2, "leaves of a tree", 100_000)
LABELS = _int_at_least(1, "expert labels", 10_000_000)
ITERATIONS = _int_at_least(1, "iterations", 10_000)
TIMESTEPS = _int_at_least(1, "timesteps", 10**10)
REFINE_EPISODES = _int_at_least(1, "refinement episodes", 10_000_000)
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
    sweep_temp_files(path)
    return path


def sweep_temp_files(path: Path, age: float = STALE_TEMP_SECONDS) -> list[Path]:
    """Remove the hidden temporary files a killed run left beside ``path`` (those of
    :func:`ibt.files.atomic_target`, ``.<name>.XXXXXXXX<suffix>``, and write probes) that were
    last written more than ``age`` seconds ago; returns them."""
    import time

    removed: list[Path] = []
    try:
        candidates = [*path.parent.glob(f".{glob_escape(path.name)}.*"),
                      *path.parent.glob(".ibt-probe-*")]
    except OSError:
        return removed
    for temp in candidates:
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


def check_output_folder(path: str | Path, option: str) -> Path:
    """``path`` if it is, or can become, a folder we can write in."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise UsageError(f"{option} {path} is a file, not a folder; choose another path")
    _writable_folder(path, f"{option} {path}")
    return path


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


def _again(args: argparse.Namespace, *extra: str) -> str:
    """The user's own command with ``extra`` arguments added (a hint that works)."""
    return "python -m ibt " + shlex.join([*args.argv, *extra])


# ------------------------------------------------------------------------ tree files
def load_tree_file(path: str | Path, args: argparse.Namespace | None = None) -> dict[str, Any]:
    """A tree file of :mod:`ibt.distill.tree_file`, checked; a pickle only with --trust-pickle."""
    from ibt.distill.tree_file import TREE_SUFFIX
    from ibt.distill.tree_file import load_tree_file as load

    hint = (f"make one with `python -m ibt distill CartPole-v1 ppo -o "
            f"{shlex.quote(str(Path(path).with_suffix(TREE_SUFFIX)))}`")
    path = check_input(path, "decision-tree file", hint)
    return load(path, trust_pickle=bool(getattr(args, "trust_pickle", False)))


def _tree_task(doc: dict[str, Any], path: str | Path, args: argparse.Namespace) -> Task:
    """The task a tree file was distilled on, with the names it was fitted on.

    A name of the form ``MODULE:EnvId`` in the file imports nothing: only ``--env-module`` on
    the command line imports (a file must not choose the code that runs)."""
    from ibt.tasks.catalogue import resolve_task

    name = doc["task"]
    module, colon, bare = name.rpartition(":")
    if colon and module not in args.env_module:
        retry = _again(args, "--env-module", module)
        raise UsageError(f"{path} was distilled on {bare}, which the module {module} registers; "
                         f"a tree file imports nothing: if you trust that module, run "
                         f"`{retry}`")
    try:
        task = resolve_task(bare)
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


def _bt_hint(path: str | Path) -> str:
    bt_file = shlex.quote(str(Path(path).with_suffix(".json")))
    return ("make one with `python -m ibt distill CartPole-v1 ppo -o tree.json` and "
            f"`python -m ibt synthesize tree.json -o {bt_file}`")


def _read_json(path: str | Path, what: str, hint: str) -> Any:
    """A JSON input file: regular, bounded, strict (no duplicate keys)."""
    from ibt.distill.tree_file import parse_json

    data = read_input(path, what, hint)
    try:
        return parse_json(data, path, what)
    except ValueError as err:
        raise UsageError(str(err)) from None


def _load_bt(path: str | Path, doc: Any = None):
    from ibt.bt.model import BehaviorTree

    if doc is None:
        doc = _read_json(path, "behavior tree", _bt_hint(path))
    try:
        return BehaviorTree.from_dict(doc)
    except RecursionError:
        raise UsageError(f"{path} is nested too deeply to be a behavior tree") from None
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
    from ibt.experts.expert import expert_path
    from ibt.tasks.catalogue import TASKS

    asked = [(t, a) for t in (tasks or list(TASKS.values())) for a in algos]

    def mtime(t: Task, a: str) -> int | None:
        path = expert_path(t, a, root)
        return path.stat().st_mtime_ns if path.exists() else None

    before = {(t.name, a): mtime(t, a) for t, a in asked}
    manifest = train_missing(tasks or None, algos, refresh=args.refresh, seed=args.seed,
                             timesteps=args.timesteps, refresh_before=since, root=root)
    skipped = [f"{t.name}/{a}" for t, a in asked
               if before[(t.name, a)] is not None and before[(t.name, a)] == mtime(t, a)]
    if skipped:
        print(f"skipped {len(skipped)} expert(s) already recorded in {root} (--refresh "
              f"retrains them): {', '.join(skipped)}")
    names = {t.name for t, _ in asked}
    rows = manifest[manifest["task"].isin(names) & manifest["algo"].isin(algos)]
    columns = [c for c in ("task", "algo", "timesteps", "mean_return", "meets_bar", "status")
               if c in rows]  # the full manifest is in manifest.csv; this fits a terminal
    print(rows[columns].to_string(index=False))
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
    from ibt.distill.tree_file import save_tree_file
    from ibt.experts.expert import load_expert
    from ibt.tasks.catalogue import resolve_task

    task = resolve_task(args.task)
    out = check_output(args.output, (".json",))
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
    from ibt.distill.tree_file import save_tree_file
    from ibt.refine.by_return import refine, task_config

    out = check_output(args.output, (".json",))
    doc = load_tree_file(args.tree, args)
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
    # refinement starts from the tree with same-action sibling leaves merged (it decides alike)
    given, merged = int(doc["tree"].get_n_leaves()), record.candidates[0].n_leaves
    start = (f"{given}" if given == merged
             else f"{given} ({merged} once leaves that always decide alike are merged)")
    print(f"{task.name}: {start} -> {record.best.n_leaves} leaves, "
          f"held-out return {before:.2f} -> {after:.2f} ({record.episodes} refinement "
          f"episodes, {record.cpu_seconds:.0f} s CPU); written to {out}")
    return 0


def _synthesize(args: argparse.Namespace) -> int:
    from ibt.bt.json_io import save_json
    from ibt.synth.imitation import NotEquivalentError, imitation_bt

    out = check_output(args.output, (".json",))
    doc = load_tree_file(args.tree, args)
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


def _convert_tree(args: argparse.Namespace) -> int:
    from ibt.distill.tree_file import PICKLE_SUFFIXES, convert_tree_file

    out = check_output(args.output, (".json",))
    source = check_input(args.tree, "pickled decision-tree file", "pass the .joblib file to "
                         "convert")
    if source.suffix.lower() not in PICKLE_SUFFIXES:
        raise UsageError(f"{source} is not a pickled tree file ({', '.join(PICKLE_SUFFIXES)}); "
                         "JSON tree files need no conversion")
    if not args.trust_pickle:
        raise UsageError(f"reading {source} runs the code a pickle holds; if it comes from a "
                         f"trusted source, run `{_again(args, '--trust-pickle')}`")
    doc = convert_tree_file(source, out)
    print(f"{source} ({doc['task']}, {doc['tree'].get_n_leaves()} leaves) converted; written "
          f"to {out}")
    return 0


def _matching_tasks(bt: Any) -> list[str]:
    from ibt.tasks.catalogue import TASKS

    return [t.name for t in TASKS.values()
            if (t.feature_names, t.action_names) == (bt.feature_names, bt.action_names)]


def _load_policy(path: Path, args: argparse.Namespace):
    from ibt.distill.tree_file import PICKLE_SUFFIXES, TREE_FORMAT
    from ibt.evaluate.policies import BTPolicy, TreePolicy
    from ibt.tasks.catalogue import resolve_task

    doc = None
    if path.suffix.lower() not in PICKLE_SUFFIXES:
        if path.suffix.lower() != ".json" and not path.exists():
            raise UsageError(f"{path}: expected a BT (.json), a decision-tree file (.json) or "
                             f"an expert ({', '.join(ALGOS)})")
        doc = _read_json(path, "BT or decision-tree file", _bt_hint(path))
    if doc is not None and not (isinstance(doc, dict) and doc.get("format") == TREE_FORMAT):
        bt = _load_bt(path, doc)
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
    doc = load_tree_file(path, args)
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

    hint = "write one with `python -m ibt export BT.json --format btcpp-xml -o BT.xml`"
    xml = check_input(args.xml, "BehaviorTree.CPP XML", hint)
    read_input(xml, "BehaviorTree.CPP XML", hint)  # a regular file of bounded size
    run = run_btcpp(xml, resolve_task(args.task), args.episodes, args.groot_port,
                    args.step_delay)
    print(run.summary())
    if not run.ok:
        print("error: BehaviorTree.CPP and the Python BT disagree (a bug: please report it)",
              file=sys.stderr)
    return 0 if run.ok else 1


def _pipeline(args: argparse.Namespace) -> int:
    from ibt.runs.recommend import recommend
    from ibt.runs.recommend_files import write_outputs
    from ibt.tasks.catalogue import resolve_task

    out = check_output_folder(args.output, "-o")
    task = resolve_task(args.task)
    checkpoint = args.checkpoint
    if checkpoint is None:
        from ibt.experts.expert import expert_path

        checkpoint = expert_path(task, args.algo)
    check_input(checkpoint, "SB3 checkpoint", "pass your agent's zip with --checkpoint")
    rec = recommend(task, args.algo, checkpoint, keep=args.keep, budget=args.budget,
                    leaf_limits=args.leaves, seed=args.seed, episodes=args.episodes,
                    cache_dir=args.cache_dir or Path(args.output) / "cache",
                    progress=not args.quiet, argv=args.argv, env_modules=args.env_module)
    write_outputs(rec, out)
    verdict = "meets" if rec.met else "MISSES"
    print(f"{task.name}/{args.algo}: recommended a {rec.chosen.bt_nodes}-node BT keeping "
          f"{rec.retention:.1f} % of the agent (random-normalised, {rec.episodes} held-out "
          f"episodes); {verdict} the {100 * args.keep:.0f} % target; see {out / 'report.md'}")
    return 0


def _keep(text: str) -> float:
    """An argparse type: a share in (0, 1]."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a share such as 0.95, got {text!r}") from None
    if not 0 < value <= 1:
        raise argparse.ArgumentTypeError(f"must be in (0, 1] (a share of the agent), got {text}")
    return value


def _budget(text: str) -> Any:
    from ibt.runs.recommend import parse_budget

    try:
        return parse_budget(text)
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err).split(": ", 1)[-1]) from None


def _leaf_limits(text: str) -> tuple[int, ...]:
    """An argparse type: comma-separated leaf limits, each at least 2."""
    try:
        values = tuple(sorted({int(v) for v in text.split(",") if v.strip()}))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected leaf limits such as 4,8,16,32, got "
                                         f"{text!r}") from None
    if not values or values[0] < 2:
        raise argparse.ArgumentTypeError(f"leaf limits must be at least 2, got {text!r}")
    return values


# ----------------------------------------------------------------------------- parser
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
    train.set_defaults(func=_train)

    rnd = command("random-baselines", help="write data/experts/random.csv")
    rnd.add_argument("tasks", nargs="*", metavar="TASK")
    rnd.add_argument("--episodes", type=EPISODES, default=100)
    rnd.add_argument("-o", "--output", help="CSV to write (default: data/experts/random.csv)")
    rnd.set_defaults(func=_random)

    dist = command("distill", help="distil an expert into a decision tree")
    dist.add_argument("task", help="a registered task, any gymnasium env id, or MODULE:EnvId")
    dist.add_argument("algo", choices=ALGOS)
    dist.add_argument("-o", "--output", required=True, help="decision-tree file (.json)")
    dist.add_argument("--checkpoint", help="SB3 checkpoint (default: the committed expert); a "
                      "checkpoint is code (pickles): use only ones from a trusted source")
    dist.add_argument("--method", default="imitation-bt",
                      choices=("bc", "dagger", "viper", "imitation-bt"))
    dist.add_argument("--seed", type=SEED, default=0)
    dist.add_argument("--iterations", type=ITERATIONS, default=50)
    dist.add_argument("--selection-episodes", type=EPISODES, default=20)
    dist.add_argument("--labels", type=LABELS, default=None,
                      help="at least this many new expert labels per iteration: whole episodes "
                      "are collected until that many steps have been taken, so an iteration "
                      "adds a little more (default: the task's budget)")
    dist.add_argument("--max-leaf-nodes", type=LEAVES, default=None,
                      help="leaf limit of the tree (default: the task's budget in its "
                      f"catalogue entry, Task.budget; {DEFAULT_MAX_LEAF_NODES} for other "
                      "tasks)")
    dist.add_argument("--quiet", action="store_true", help="no progress bar")
    dist.set_defaults(func=_distill)

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
    ref.set_defaults(func=_refine)

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
    syn.set_defaults(func=_synthesize)

    ev = command("evaluate", help="returns of a BT (.json), a decision tree (.json) or an "
                 "expert (dqn/ppo/a2c) on the fixed evaluation episodes")
    ev.add_argument("policy", help="BT JSON, decision-tree file, or dqn|ppo|a2c")
    ev.add_argument("--task", help="task (required for BT files and experts)")
    ev.add_argument("--checkpoint", help="SB3 checkpoint for an expert; a checkpoint is code "
                    "(pickles): use only ones from a trusted source")
    ev.add_argument("--episodes", type=EPISODES, default=100)
    ev.add_argument("--trust-pickle", action="store_true", help=TRUST_HELP)
    ev.set_defaults(func=_evaluate)

    conv = command("convert-tree", help="convert a decision-tree file of earlier versions "
                   "(.joblib, a pickle) into the JSON format")
    conv.add_argument("tree", help="the .joblib file (it runs code when read: trusted only)")
    conv.add_argument("-o", "--output", required=True, help="decision-tree file (.json)")
    conv.add_argument("--trust-pickle", action="store_true",
                      help="required: you trust the file's source (unpickling runs its code)")
    conv.set_defaults(func=_convert_tree)

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
    rb.add_argument("--episodes", type=EPISODES, default=10)
    rb.add_argument("--groot-port", type=PORT, default=None, metavar="PORT",
                    help="publish the tree to Groot2 on this port while it runs "
                    "(behaviortreepy's Groot2Publisher; connect Groot2 to it)")
    rb.add_argument("--step-delay", type=_seconds, default=0.0, metavar="SECONDS",
                    help="sleep between steps, to watch a run in Groot2")
    rb.set_defaults(func=_run_btcpp)

    pl = command("pipeline", help="from an agent to a recommended BT: distil at several leaf "
                 "limits, refine, synthesise every verified BT, evaluate on held-out episodes, "
                 "and write bt.json, bt.xml, bt.png, front.png and report.md")
    pl.add_argument("task", help="a registered task, any gymnasium env id, or MODULE:EnvId")
    pl.add_argument("algo", choices=ALGOS)
    pl.add_argument("-o", "--output", required=True, metavar="DIR", help="folder to write")
    pl.add_argument("--checkpoint", help="SB3 checkpoint (default: the committed expert)")
    pl.add_argument("--keep", type=_keep, default=0.95,
                    help="target share of the agent's random-normalised return (default 0.95)")
    pl.add_argument("--budget", type=_budget, default="1x",
                    help="smoke (seconds), a scale of the default budget such as 2x, or "
                    "refinement episodes per leaf limit such as 40000 (default 1x)")
    pl.add_argument("--leaves", type=_leaf_limits, default=(4, 8, 16, 32), metavar="L,L,...",
                    help="leaf limits to distil at (default 4,8,16,32)")
    pl.add_argument("--episodes", type=POSITIVE, default=None,
                    help="held-out episodes per evaluation (default: 100; 5 with --budget smoke)")
    pl.add_argument("--seed", type=SEED, default=0)
    pl.add_argument("--cache-dir", metavar="DIR", help="cache of every step (default: DIR/cache)")
    pl.add_argument("--quiet", action="store_true", help="no progress bars")
    pl.set_defaults(func=_pipeline)
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


def _terminate(signum: int, frame: Any) -> None:
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
