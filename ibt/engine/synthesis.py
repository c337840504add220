"""The synthesis stage: a tree's verified BTs, one cached home for the grid and the pipeline.

:func:`synthesised` is the one place a ``synthesis`` entry is written: one synthesiser's BT of
one tree, verified against it (a BT that disagrees raises and nothing is cached), with one row
of structure facts. The paper's grid asks for its synthesis study as well (``analysis``: the
imitation-bt construction under each default-action strategy and with don't-cares); the
pipeline does not pay for it. Both key the entry the same way, on the tree's digest, the method
it came from and whether the row holds that study, so two rows of one key never differ.

:func:`synthesise` is the stage the ladder calls: every registered synthesiser's BT of a
tree (the front's synthesisers for a command tree, whose BTs carry its command table).
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Any

from ibt.cache.store import load_or_compute
from ibt.engine.agent import Agent
from ibt.engine.keys import tree_key
from ibt.profiles import Config
from ibt.tasks.task import Task

PIPELINE_SOURCE = "pipeline"  #: the source method in the keys of the pipeline's trees


def smallest_bt(bts: dict[str, Any]) -> str:
    """The synthesiser whose BT has the fewest nodes (ties: the earlier one, in the order the
    BTs were made, the registry's): the one "smallest BT" rule of the grid, the front, the
    continuous study and the pipeline."""
    names = list(bts)
    return min(names, key=lambda m: (bts[m].node_count, names.index(m)))


def command_tree_of(arrays: Any, task: Task) -> Any:
    """The :class:`ibt.synth.commands.CommandTree` of command arrays on ``task``."""
    from ibt.bt.model import Commands
    from ibt.synth.commands import CommandTree, command_name, command_task

    names = tuple(command_name(task, row) for row in arrays.values)
    commands = Commands(task.action_names, task.action_units or ("",) * task.n_actions,
                        tuple(tuple(float(v) for v in row) for row in arrays.values))
    return CommandTree(arrays.structure.to_sklearn(), commands, command_task(task, names))


def command_bt(arrays: Any, task: Task, method: str) -> Any:
    """One synthesiser's verified BT of a command tree, with its command table."""
    from ibt.synth.registry import get_synthesiser

    tree = command_tree_of(arrays, task)
    bt = get_synthesiser(method)(tree.tree, tree.task).bt  # every synthesiser verifies
    return replace(bt, commands=tree.commands)


def _classifier_entry(synthesiser: Any, tree: Any, task: Task, algo: str, method: str, seed: int,
                      source_method: str, analysis: bool) -> dict[str, Any]:
    """Synthesise, verify and describe one BT of a classification tree."""
    from ibt.synth.imitation import DEFAULT_STRATEGIES, imitation_bt, verify

    started = time.process_time()
    result = synthesiser(tree, task)
    seconds = time.process_time() - started
    checked = verify(result.bt, tree, task)  # raises NotEquivalentError: nothing is cached
    types = result.bt.node_types()
    default_action = getattr(result, "default_action", None)
    row = {"task": task.name, "expert": algo, "method": method, "seed": seed,
           "source_method": source_method, "nodes": result.bt.node_count,
           "tree_nodes": int(tree.tree_.node_count), "conditions": types["condition"],
           **{f"n_{k}": v for k, v in types.items()},
           "default_action": (task.action_names[default_action]
                              if default_action is not None else ""),
           "default_strategy": getattr(result, "default_strategy", None) or "",
           "equivalent": True, "states_checked": checked}
    if method == "decision-list":  # what the search tried and what it cost
        row.update({"search_winner": result.search["winner"],
                    "search_work": result.search["work"],
                    "synthesis_cpu_seconds": round(seconds, 3)})
    if analysis and method == "imitation-bt":
        for strategy in DEFAULT_STRATEGIES:
            row[f"nodes_{strategy}"] = imitation_bt(
                tree, task, default_strategy=strategy).bt.node_count
        with_dc = imitation_bt(tree, task, dont_cares=True)
        verify(with_dc.bt, tree, task)
        row["nodes_dont_cares"] = with_dc.bt.node_count
    return {"row": row, "bt": result.bt}


def synthesised(cfg: Config, task: Task, algo: str, method: str, seed: int, source_method: str,
                tree: Any, *, analysis: bool = False) -> dict[str, Any]:
    """One synthesiser's BT of ``tree``, verified against it (kind ``synthesis``):
    ``{"row": structure facts, "bt": BehaviorTree}``. A command tree's BT carries its command
    table; ``analysis`` adds the grid's synthesis study to the row (imitation-bt only)."""
    from ibt.refine.commands import CommandArrays
    from ibt.synth.registry import get_synthesiser

    synthesiser = get_synthesiser(method)
    params: dict[str, Any] = {"task": task.key, "algo": algo, "method": method, "seed": seed,
                              "source_method": source_method, "tree": tree_key(tree)}
    if synthesiser.version is not None:  # its own version: a changed method re-keys its BTs
        params["method_version"] = synthesiser.version_number()
    if not analysis:  # the row's shape is in the key (the grid's keys, with it, predate the flag)
        params["analysis"] = False

    def compute() -> dict[str, Any]:
        if isinstance(tree, CommandArrays):
            bt = command_bt(tree, task, method)  # every synthesiser verifies
            return {"row": {"task": task.name, "expert": algo, "method": method, "seed": seed,
                            "source_method": source_method, "nodes": bt.node_count,
                            "equivalent": True}, "bt": bt}
        return _classifier_entry(synthesiser, tree, task, algo, method, seed, source_method,
                                 analysis)

    return load_or_compute("synthesis", params, compute, cache_dir=cfg.cache_dir,
                           codec="synthesis", refresh=cfg.refresh)


def synthesise(cfg: Config, agent: Agent, tree: Any, seed: int) -> dict[str, Any]:
    """Every registered synthesiser's BT of ``tree`` (each verified against it, cached): a
    command tree's BTs, the front's synthesisers', carry its command table; a tree whose
    learner lays out its own BTs (:attr:`ibt.engine.learners.Learner.lay_out`) gets those."""
    from ibt.engine.learners import learner_of_tree
    from ibt.refine.commands import CommandArrays
    from ibt.synth.registry import SYNTHESISERS, front_synthesisers

    learner = learner_of_tree(tree)
    if learner is not None and learner.lay_out is not None:
        return learner.lay_out(agent, tree, seed)

    names = front_synthesisers() if isinstance(tree, CommandArrays) else tuple(SYNTHESISERS)
    return {name: synthesised(cfg, agent.task, agent.algo, name, seed, PIPELINE_SOURCE,
                              tree)["bt"] for name in names}
