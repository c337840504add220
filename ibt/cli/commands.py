"""The command line's subcommands: each takes the parsed arguments and returns an exit code;
the compute stack is imported inside each, when it runs."""


from __future__ import annotations

import argparse
import os
import shlex
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ibt.synth.registry import get_synthesiser
from ibt.tasks.settings import ALGOS, BOX_MAX_LEAF_NODES

if TYPE_CHECKING:  # the CLI imports the compute stack only when a command runs
    from ibt.tasks.task import Task

from ibt.cli.checks import (
    EXIT_INTERRUPTED,
    EXIT_TERMINATED,
    EXPORT_SUFFIXES,
    MAX_LEAVES,
    MAX_REFINE_EPISODES,
    UsageError,
    _again,
    _bt_hint,
    _load_bt,
    _read_json,
    _tree_task,
    check_cache_folder,
    check_input,
    check_not_input,
    check_output,
    check_output_folder,
    load_tree_file,
    one_line_warnings,
    read_input,
    same_path,
    task_for,
)


def _train(args: argparse.Namespace) -> int:
    from ibt.experts.expert import hyperparams
    from ibt.experts.training import train_missing
    from ibt.paths import DATA_DIR
    from ibt.tasks.catalogue import resolve_task

    # `train CartPole-v1 ppo` reads as `train CartPole-v1 --algo ppo`
    named_algos = [t.lower() for t in args.tasks if t.lower() in ALGOS]
    # none named: each task's own catalogue algorithms
    algos = list(dict.fromkeys([*(args.algo or []), *named_algos])) or None
    tasks = [resolve_task(t) for t in args.tasks if t.lower() not in ALGOS]
    for task in tasks:
        for algo in algos or ():
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
    from ibt.experts.training import catalogue_pairs

    asked = catalogue_pairs(tasks, algos)

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
    rows = manifest[manifest["task"].isin(names) & manifest["algo"].isin({a for _, a in asked})]
    columns = [c for c in ("task", "algo", "timesteps", "mean_return", "meets_bar", "status")
               if c in rows]  # the full manifest is in manifest.csv; this fits a terminal
    print(rows[columns].to_string(index=False))
    return 0


def _random(args: argparse.Namespace) -> int:
    from ibt.experts.training import random_baselines
    from ibt.paths import DATA_DIR

    tasks = [task_for(args, t) for t in args.tasks]
    path = check_output(args.output or DATA_DIR / "experts" / "random.csv", (".csv",))
    print(random_baselines(tasks or None, n_episodes=args.episodes, path=path)
          .to_string(index=False))
    return 0


def _distill(args: argparse.Namespace) -> int:
    from ibt.distill.loop import DistillConfig, distill
    from ibt.distill.tree_file import save_tree_file
    from ibt.experts.expert import load_expert

    task = task_for(args, args.task)
    out = check_output(args.output, (".json",))
    expert = load_expert(task, args.algo, args.checkpoint)
    if task.continuous:  # a regression tree, merged into named commands
        return _distill_box(task, expert, out, args)
    overrides = {"n_iterations": args.iterations if args.iterations is not None else
                 DISCRETE_ITERATIONS, "selection_episodes": args.selection_episodes}
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
          f"mean return {best['selection_mean']:.2f} on {config.selection_episodes} selection "
          f"episodes); {run.expert_labels} expert labels; "
          f"written to {out}")
    return 0


DISCRETE_ITERATIONS = 50  #: distill's --iterations on a discrete task (the paper's)


def _distill_box(task: Any, expert: Any, out: Path, args: argparse.Namespace) -> int:
    """``distill`` on a Box task: the loop with a regression tree, its leaves merged into the
    fewest commands that keep its held-out return (within 1 % of expert minus random)."""
    from ibt.distill.continuous import BoxDistillConfig, distill_box
    from ibt.distill.tree_file import save_tree_file
    from ibt.evaluate.rollouts import rollout, selection_seeds
    from ibt.experts.training import BoxRandomPolicy
    from ibt.synth.commands import choose_commands

    overrides: dict[str, Any] = {"selection_episodes": args.selection_episodes,
                                 "method": args.method}
    if args.iterations is not None:
        overrides["n_iterations"] = args.iterations
    if args.labels is not None:
        overrides["labels_per_iteration"] = args.labels
    if args.max_leaf_nodes is not None:
        overrides["max_leaf_nodes"] = args.max_leaf_nodes
    if task.budget.max_leaf_nodes is None and args.max_leaf_nodes is None:
        overrides["max_leaf_nodes"] = BOX_MAX_LEAF_NODES
    config = BoxDistillConfig.for_task(task, **overrides)
    run = distill_box(task, expert, config, seed=args.seed, progress=not args.quiet)
    seeds = selection_seeds(args.selection_episodes, args.seed, offset=1)
    scale = (rollout(task, expert.act, seeds).mean
             - rollout(task, BoxRandomPolicy(task, args.seed).act, seeds).mean)
    chosen, rows = choose_commands(run.best_tree, task, seeds, scale=scale, seed=args.seed)
    best = run.iterations[run.best_index]
    save_tree_file(out, chosen.tree, chosen.task,
                   {"algo": args.algo, "method": args.method, "seed": args.seed,
                    "iterations": run.iterations, "best_index": run.best_index,
                    "commands": chosen.commands.to_dict(), "command_choice": rows,
                    "env_modules": args.env_module})
    print(f"{task.name}/{args.algo}/{args.method}: best regression tree at iteration "
          f"{run.best_index} ({best['leaves']} leaves of at most {config.max_leaf_nodes}, "
          f"mean return {best['selection_mean']:.2f} on {config.selection_episodes} selection "
          f"episodes); {chosen.n_commands} commands (mean return "
          f"{rows[-1]['mean_return']:.2f} on {len(seeds)} other episodes): "
          f"{'; '.join(chosen.task.action_names)}; written to {out}")
    return 0


def _refine(args: argparse.Namespace) -> int:
    from ibt.distill.tree_file import save_tree_file
    from ibt.refine.by_return import refine, task_config

    out = check_output(args.output, (".json",), inputs=[args.tree])
    doc = load_tree_file(args.tree, args)
    task = _tree_task(doc, args.tree, args)
    overrides: dict[str, Any] = {"max_leaves": args.max_leaves}
    if args.episodes is not None:
        overrides["episodes"] = args.episodes
    if "commands" in doc:  # continuous actions: CMA-ES on thresholds and command values
        return _refine_commands(doc, task, out, overrides, args)
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
          f"mean return {before:.2f} -> {after:.2f} on {config.selection_episodes} held-out "
          f"episodes of refinement's own, not distill's ({record.episodes} refinement episodes, "
          f"{record.cpu_seconds:.0f} s CPU); written to {out}")
    return 0


def _refine_commands(doc: dict[str, Any], task: Any, out: Path, overrides: dict[str, Any],
                     args: argparse.Namespace) -> int:
    """``refine`` of a command tree: its shape and command ids stay, thresholds and
    command values are tuned by CMA-ES (:mod:`ibt.refine.commands`)."""
    import numpy as np

    from ibt.bt.model import Commands
    from ibt.distill.tree_file import save_tree_file
    from ibt.engine.budgets import box_refine_task_config
    from ibt.engine.synthesis import command_tree_of
    from ibt.refine.commands import CommandArrays, refine_commands
    from ibt.refine.tree_arrays import TreeArrays
    from ibt.synth.commands import DECIMALS

    if overrides.pop("max_leaves") is not None:
        raise UsageError(f"{args.tree} is a command tree: refinement keeps its shape, so "
                         "--max-leaves does not apply; distil with --max-leaf-nodes instead")
    box = task_for(args, task.name)
    commands = Commands.from_dict(doc["commands"], len(doc["action_names"]))
    arrays = CommandArrays(TreeArrays.from_sklearn(doc["tree"]),
                           commands.array().astype(np.float64))
    config = box_refine_task_config(box, **overrides)
    record = refine_commands(arrays, box, config, seed=args.seed, decimals=DECIMALS,
                             progress=not args.quiet)
    chosen = command_tree_of(record.best, box)
    info = {k: v for k, v in doc.items() if k in ("algo", "method", "seed")}
    save_tree_file(out, chosen.tree, chosen.task, {
        **info, "refined_from": str(args.tree), "commands": chosen.commands.to_dict(),
        "refinement": {"stages": record.stages, "selection_means": record.selection_means,
                       "best_index": record.best_index, "config": record.config},
        "env_modules": args.env_module})
    before, after = record.selection_means[0], record.selection_means[record.best_index]
    print(f"{box.name}: {record.best.n_leaves} leaves, {record.best.n_commands} commands "
          f"({'; '.join(chosen.task.action_names)}), mean return {before:.2f} -> "
          f"{after:.2f} on {config.selection_episodes} held-out episodes of refinement's own, "
          f"not distill's ({record.episodes} refinement episodes, "
          f"{record.cpu_seconds:.0f} s CPU); written to {out}")
    return 0


def _synthesize(args: argparse.Namespace) -> int:
    from ibt.bt.json_io import save_json
    from ibt.synth.imitation import NotEquivalentError, imitation_bt

    out = check_output(args.output, (".json",), inputs=[args.tree])
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
    if "commands" in doc:  # a Box task's command tree: the BT carries the command table
        from dataclasses import replace

        from ibt.bt.model import Commands

        result = replace(result, bt=replace(result.bt, commands=Commands.from_dict(
            doc["commands"], len(doc["action_names"]))))
    result.bt.validate()  # every state reaches an action, so the file will load again
    save_json(result.bt, out)
    print(f"{args.method}: {result.bt.node_count} nodes, verified equivalent to the tree; "
          f"written to {out}")
    return 0


def _convert_tree(args: argparse.Namespace) -> int:
    from ibt.distill.tree_file import PICKLE_SUFFIXES, convert_tree_file

    out = check_output(args.output, (".json",), inputs=[args.tree])
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
        task = task_for(args, args.task)
        if (bt.commands is None) == task.continuous:
            has = (f"sends commands ({', '.join(bt.commands.dimensions)})" if bt.commands
                   else f"has discrete actions ({', '.join(bt.action_names)})")
            wants = ("continuous actions (a Box), whose BTs send commands" if task.continuous
                     else f"discrete actions ({', '.join(task.action_names)})")
            known = _matching_tasks(bt)
            fix = (f"run `{_again(args, '--task', known[0])}`" if len(known) == 1
                   else "pass the task the BT was made for")
            raise UsageError(f"{path} {has}, but {task.name} has {wants}; {fix}")
        if bt.commands is not None:  # continuous actions: a BT with commands
            from ibt.synth.commands import CommandBTPolicy

            try:
                return task, CommandBTPolicy(task, bt)
            except ValueError as err:
                raise UsageError(f"{path}: {err}") from None
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
    if "commands" in doc:  # a command tree: acts on the Box task with its command vectors
        from ibt.bt.model import Commands
        from ibt.synth.commands import CommandTree

        box = task_for(args, task.name)
        tree = CommandTree(doc["tree"], Commands.from_dict(doc["commands"],
                                                           len(doc["action_names"])), task)
        return box, _Act(tree.policy(box))
    return task, TreePolicy(task, doc["tree"])


class _Act:
    """An ``act`` function as a policy object."""

    def __init__(self, act: Any) -> None:
        self.act = act


def _evaluate(args: argparse.Namespace) -> int:
    from ibt.evaluate.rollouts import episode_metrics, final_seeds, rollout
    from ibt.experts.expert import load_expert

    if args.policy in ALGOS:
        if args.task is None:
            raise UsageError(f"evaluating an expert needs --task, e.g. "
                             f"`{_again(args, '--task', 'CartPole-v1')}`")
        task = task_for(args, args.task)
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

    out = check_output(args.output, EXPORT_SUFFIXES[args.format], inputs=[args.bt])
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

    hint = "write one with `python -m ibt export BT.json --format btcpp-xml -o BT.xml`"
    xml = check_input(args.xml, "BehaviorTree.CPP XML", hint)
    read_input(xml, "BehaviorTree.CPP XML", hint)  # a regular file of bounded size
    run = run_btcpp(xml, task_for(args, args.task), args.episodes, args.groot_port,
                    args.step_delay)
    print(run.summary())
    if not run.ok:
        print(f"error: BehaviorTree.CPP and the Python BT disagree; {_disagreement(xml, run)}",
              file=sys.stderr)
    return 0 if run.ok else 1


def _disagreement(xml: Path, run: Any) -> str:
    """Why the engine and the Python BT may disagree: an edited file, or a bug of ours."""
    from ibt.export.btcpp import DIFFERS, to_btcpp_xml

    bt = run.bt
    try:
        text = xml.read_text(encoding="utf-8")
        written = {to_btcpp_xml(bt, flavour=f) for f in ("portable", "check-feature")} if bt \
            else set()
    except (OSError, ValueError):
        written = set()
    if bt is not None and text not in written:
        return (f"{DIFFERS} for the BT it reads as (edited by hand or by another tool?): "
                "export the BT again with `python -m ibt export BT.json --format btcpp-xml`")
    return ("the file is exactly what ibt writes, so this is a bug of ibt: please report it "
            "with the file")


def _pipeline(args: argparse.Namespace) -> int:
    from ibt.engine.agent import callable_agent, sb3_agent
    from ibt.pipeline.outputs import OUTPUTS
    from ibt.pipeline.owned_folder import FolderError, claim, release, take

    # every path is checked before any work: the folder, the cache, the checkpoint
    out = check_output_folder(args.output, "-o")
    cache = check_cache_folder(args.cache_dir or out / "cache", "--cache-dir")
    if same_path(cache, out):
        raise UsageError(f"--cache-dir {cache} is the output folder itself; drop --cache-dir "
                         f"(the cache then goes to {out / 'cache'}) or name another folder")
    task = task_for(args, args.task)
    if args.algo == "callable":
        if args.agent is None or args.checkpoint is not None:
            raise UsageError("algo callable takes --agent MODULE:FUNCTION (and no --checkpoint)")
        agent = callable_agent(task, args.agent)
    else:
        if args.agent is not None:
            raise UsageError(f"--agent is for algo callable; a {args.algo} agent is an SB3 "
                             "checkpoint: pass it with --checkpoint")
        checkpoint = args.checkpoint
        if checkpoint is None:
            from ibt.experts.expert import expert_path

            checkpoint = expert_path(task, args.algo)
        check_input(checkpoint, "SB3 checkpoint", "pass your agent's zip with --checkpoint")
        check_not_input([out / name for name in OUTPUTS], checkpoint)
        agent = sb3_agent(task, args.algo, checkpoint)  # its kind and spaces, loaded once
    try:
        folder = claim(out, OUTPUTS, force=args.force, cache=cache)
    except FolderError as err:
        raise UsageError(str(err)) from None
    note = folder.note()
    if note:
        print(note)
    from ibt.pipeline.outputs import write_outputs
    from ibt.pipeline.recommend import recommend

    first = take(folder)  # marked as the pipeline's before the long work: a rerun may write
    try:
        with one_line_warnings():  # e.g. one line for a cache that cannot be written
            rec = recommend(agent, keep=args.keep, budget=args.budget,
                            leaf_limits=args.leaves, seed=args.seed, episodes=args.episodes,
                            cache_dir=cache, progress=not args.quiet, argv=args.argv,
                            env_modules=args.env_module, time_limit=args.time,
                            max_nodes=args.max_nodes, restarts=args.restarts,
                            n_jobs=args.jobs or os.cpu_count() or 1)
    except BaseException:
        if first:
            release(folder)
        raise
    try:
        write_outputs(rec, folder)
    except FolderError as err:
        raise UsageError(str(err)) from None
    verdict = "meets" if rec.met else "MISSES"
    stopped = {"time": f"; the --time budget ended the search after {rec.elapsed:.0f} s",
               "interrupted": "; stopped by Ctrl-C", "terminated": "; stopped by SIGTERM"
               }.get(rec.stopped or "", "")
    print(f"{task.name}/{args.algo}: recommended a {rec.chosen.bt_nodes}-node BT keeping "
          f"{rec.retention:.1f} % of the agent (random-normalised, {rec.episodes} held-out "
          f"episodes); {verdict} the {100 * args.keep:.0f} % target{stopped}; see "
          f"{out / 'report.md'}")
    if rec.stopped in ("interrupted", "terminated"):
        return EXIT_INTERRUPTED if rec.stopped == "interrupted" else EXIT_TERMINATED
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
    """An argparse type: ``smoke``, a scale (``2x``, at most 1000x) or refinement episodes per
    leaf limit, at most refine's ``--episodes`` maximum."""
    from ibt.pipeline.recommend import parse_budget

    try:
        budget = parse_budget(text if len(text) <= 40 else "?")
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err).split(": ", 1)[-1]) from None
    if (budget.refine_episodes or 0) > MAX_REFINE_EPISODES:
        raise argparse.ArgumentTypeError(f"refinement episodes per leaf limit must be at most "
                                         f"{MAX_REFINE_EPISODES:,}, got {text:.40}")
    return budget


MAX_LEAF_LIMITS = 12  #: --leaves: at most this many limits (each is a distillation)


def _leaf_limits(text: str) -> tuple[int, ...]:
    """An argparse type: comma-separated leaf limits, each from 2 to distill's
    ``--max-leaf-nodes`` maximum, at most :data:`MAX_LEAF_LIMITS` of them."""
    parts = [v for v in text.split(",") if v.strip()]
    if len(parts) > MAX_LEAF_LIMITS:
        raise argparse.ArgumentTypeError(f"at most {MAX_LEAF_LIMITS} leaf limits, got "
                                         f"{len(parts)}")
    try:
        if any(len(v) > 30 for v in parts):
            raise ValueError("too long")
        values = tuple(sorted({int(v) for v in parts}))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected leaf limits such as 4,8,16,32, got "
                                         f"{text!r:.60}") from None
    if not values or values[0] < 2:
        raise argparse.ArgumentTypeError(f"leaf limits must be at least 2, got {text!r:.60}")
    if values[-1] > MAX_LEAVES:
        raise argparse.ArgumentTypeError(f"leaf limits must be at most {MAX_LEAVES:,} (as "
                                         f"distill's --max-leaf-nodes), got {values[-1]:,}")
    return values


# ----------------------------------------------------------------------------- parser
