"""The command line's commands that use a BT or a tree: evaluate (returns of a BT, a decision
tree or an expert), export (JSON, DOT, SVG, PNG, BehaviorTree.CPP XML) and run-btcpp (the
BehaviorTree.CPP engine against the Python BT). Each takes the parsed arguments and returns an
exit code; the compute stack is imported inside each, when it runs."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from ibt.cli.checks import (
    EXPORT_SUFFIXES,
    UsageError,
    bt_file_hint,
    check_input,
    check_output,
    load_bt_file,
    load_tree_file,
    read_input,
    read_json_input,
    rerun_command,
    task_for,
    tree_file_task,
)
from ibt.tasks.settings import ALGOS


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
        doc = read_json_input(path, "BT or decision-tree file", bt_file_hint(path))
    if doc is not None and not (isinstance(doc, dict) and doc.get("format") == TREE_FORMAT):
        bt = load_bt_file(path, doc)
        if args.task is None:
            known = _matching_tasks(bt)
            if len(known) == 1:
                raise UsageError(f"a BT file does not name its task; its names are "
                                 f"{known[0]}'s: run `{rerun_command(args, '--task', known[0])}`")
            raise UsageError("a BT file does not name its task; pass --task with the "
                             "environment it was made for")
        task = task_for(args, args.task)
        if (bt.commands is None) == task.continuous:
            has = (f"sends commands ({', '.join(bt.commands.dimensions)})" if bt.commands
                   else f"has discrete actions ({', '.join(bt.action_names)})")
            wants = ("continuous actions (a Box), whose BTs send commands" if task.continuous
                     else f"discrete actions ({', '.join(task.action_names)})")
            known = _matching_tasks(bt)
            fix = (f"run `{rerun_command(args, '--task', known[0])}`" if len(known) == 1
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
            fix = (f"run `{rerun_command(args, '--task', known[0])}`" if len(known) == 1
                   else "pass the task the BT was made for")
            raise UsageError(f"{path} reads {', '.join(bt.feature_names)} and acts "
                             f"{', '.join(bt.action_names)}, but {task.name} has "
                             f"{', '.join(task.feature_names)} and "
                             f"{', '.join(task.action_names)}; {fix}")
        return task, BTPolicy(task, bt)
    doc = load_tree_file(path, args)
    task = tree_file_task(doc, path, args)
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


def evaluate_command(args: argparse.Namespace) -> int:
    """The ``evaluate`` command: the returns of a BT, a decision tree or an expert."""
    from ibt.evaluate.rollouts import episode_metrics, final_seeds, rollout
    from ibt.experts.expert import load_expert

    if args.policy in ALGOS:
        if args.task is None:
            raise UsageError(f"evaluating an expert needs --task, e.g. "
                             f"`{rerun_command(args, '--task', 'CartPole-v1')}`")
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


def export_command(args: argparse.Namespace) -> int:
    """The ``export`` command: a BT file to another format."""
    from ibt.bt.json_io import save_json
    from ibt.export.drawing import require_dot, to_graphviz
    from ibt.export.pictures import save_drawing
    from ibt.files import atomic_write_text

    out = check_output(args.output, EXPORT_SUFFIXES[args.format], inputs=[args.bt])
    if args.format in ("svg", "png"):
        require_dot()
    bt = load_bt_file(args.bt)
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


def run_btcpp_command(args: argparse.Namespace) -> int:
    """The ``run-btcpp`` command: BehaviorTree.CPP ticks an exported BT on its task."""
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
