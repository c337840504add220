"""The command line's commands that build: train and random-baselines (experts), distill,
refine, synthesize and convert-tree (trees and BTs). Each takes the parsed arguments and returns
an exit code; the compute stack is imported inside each, when it runs. The commands that use a
BT are in :mod:`ibt.cli.bt_commands`, the pipeline in :mod:`ibt.cli.pipeline_command`."""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ibt.synth.registry import get_synthesiser
from ibt.tasks.settings import ALGOS, BOX_MAX_LEAF_NODES

if TYPE_CHECKING:  # the CLI imports the compute stack only when a command runs
    from ibt.tasks.task import Task

from ibt.cli.checks import (
    UsageError,
    callable_spec,
    check_input,
    check_output,
    check_output_folder,
    load_tree_file,
    rerun_command,
    task_for,
    tree_file_task,
)


def train_command(args: argparse.Namespace) -> int:
    """The ``train`` command: train, evaluate and record the missing (or all) experts."""
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


def random_command(args: argparse.Namespace) -> int:
    """The ``random-baselines`` command: write the random agents' returns."""
    from ibt.experts.training import random_baselines
    from ibt.paths import DATA_DIR

    tasks = [task_for(args, t) for t in args.tasks]
    path = check_output(args.output or DATA_DIR / "experts" / "random.csv", (".csv",))
    print(random_baselines(tasks or None, n_episodes=args.episodes, path=path)
          .to_string(index=False))
    return 0


def distill_command(args: argparse.Namespace) -> int:
    """The ``distill`` command: distil an expert into a decision-tree file."""
    from ibt.distill.loop import DistillConfig, distill
    from ibt.distill.tree_file import save_tree_file
    from ibt.experts.expert import load_expert

    task = task_for(args, args.task)
    out = check_output(args.output, (".json",))
    spec = callable_spec(args)
    if spec is not None:  # a MODULE:FUNCTION agent, read and checked as the pipeline does
        from ibt.engine.agent import callable_agent

        expert = callable_agent(task, spec).load()
    else:
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
                    "env_modules": args.env_module, **agent_info(spec)})
    print(f"{task.name}/{args.algo}/{args.method}: best tree at iteration {run.best_index} "
          f"({best['leaves']} leaves of at most {config.max_leaf_nodes}, {best['nodes']} nodes, "
          f"mean return {best['selection_mean']:.2f} on {config.selection_episodes} selection "
          f"episodes); {run.expert_labels} expert labels; "
          f"written to {out}")
    return 0


DISCRETE_ITERATIONS = 50  #: distill's --iterations on a discrete task (the paper's)


def agent_info(spec: str | None) -> dict[str, str]:
    """A tree file's record of a callable agent (its ``MODULE:FUNCTION``); none for SB3."""
    return {} if spec is None else {"agent": spec}


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
                    "env_modules": args.env_module, **agent_info(args.agent)})
    print(f"{task.name}/{args.algo}/{args.method}: best regression tree at iteration "
          f"{run.best_index} ({best['leaves']} leaves of at most {config.max_leaf_nodes}, "
          f"mean return {best['selection_mean']:.2f} on {config.selection_episodes} selection "
          f"episodes); {chosen.n_commands} commands (mean return "
          f"{rows[-1]['mean_return']:.2f} on {len(seeds)} other episodes): "
          f"{'; '.join(chosen.task.action_names)}; written to {out}")
    return 0


def refine_command(args: argparse.Namespace) -> int:
    """The ``refine`` command: raise a tree file's return by refinement."""
    from ibt.distill.tree_file import save_tree_file
    from ibt.refine.by_return import refine, task_config

    out = check_output(args.output, (".json",), inputs=[args.tree])
    doc = load_tree_file(args.tree, args)
    task = tree_file_task(doc, args.tree, args)
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


def synthesize_command(args: argparse.Namespace) -> int:
    """The ``synthesize`` command: a decision-tree file to an exact BT."""
    from ibt.bt.json_io import save_json
    from ibt.synth.imitation import NotEquivalentError, imitation_bt

    out = check_output(args.output, (".json",), inputs=[args.tree])
    doc = load_tree_file(args.tree, args)
    task = tree_file_task(doc, args.tree, args)
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


def convert_tree_command(args: argparse.Namespace) -> int:
    """The ``convert-tree`` command: a trusted pickled tree file to JSON."""
    from ibt.distill.tree_file import PICKLE_SUFFIXES, convert_tree_file

    out = check_output(args.output, (".json",), inputs=[args.tree])
    source = check_input(args.tree, "pickled decision-tree file", "pass the .joblib file to "
                         "convert")
    if source.suffix.lower() not in PICKLE_SUFFIXES:
        raise UsageError(f"{source} is not a pickled tree file ({', '.join(PICKLE_SUFFIXES)}); "
                         "JSON tree files need no conversion")
    if not args.trust_pickle:
        raise UsageError(f"reading {source} runs the code a pickle holds; if it comes from a "
                         f"trusted source, run `{rerun_command(args, '--trust-pickle')}`")
    doc = convert_tree_file(source, out)
    print(f"{source} ({doc['task']}, {doc['tree'].get_n_leaves()} leaves) converted; written "
          f"to {out}")
    return 0
