"""Imitation-BT+SR on the front: structure search with relational tests, then a polish.

Beyond the paper. For one task, expert, seed and leaf limit, exactly
Imitation-BT+S (:mod:`ibt.runs.search`: the same seed trees, budget and polish) but searched
over the observed features *and* the relational learner's candidate columns
(:func:`ibt.refine.relational_structure.evolve_relational`), so the two methods side by side
measure what tests that compare features add at a leaf limit:

1. the search, cached under its own kind ``evolve-rel``;
2. the polish of its winner (kept to the derived columns it tests): CMA-ES on every threshold,
   relational ones included, then free pruning (:func:`ibt.refine.relational.refine_relational`,
   cached under ``refine-rel`` with ``source_method`` :data:`METHOD`).

Optionally (``plus_seeds``) Imitation-BT+'s trees at smaller leaf limits join the seed trees: a
refined 16-leaf tree cut to 10 leaves loses less than a 32-leaf one (LunarLander DQN seed 0:
the budget trees cut to 10 leaves started the search at a return of about 3).

:func:`relational_search_table` gives one row per run on the anchors' protocol (1,000 final
episodes of the smallest verified BT, rolled out from its JSON) with the 100-episode final
evaluation and the BT's relational tests.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Any

from ibt.cache.store import load_or_compute
from ibt.engine.budgets import evolve_config, polish_config, relational_search_config
from ibt.profiles import Config
from ibt.refine.structure import Evolution
from ibt.runs.search import StructureResult, seed_trees
from ibt.tasks.catalogue import get_task
from ibt.tasks.settings import EvolveConfig
from ibt.tasks.task import Task

METHOD = "imitation-bt+sr"  # structure search with relational tests, polished
def search_seeds(cfg: Config, task: Task, algo: str, seed: int,
                 plus_seeds: Sequence[int] = ()) -> list[Any]:
    """Imitation-BT+S's seed trees (:func:`ibt.runs.search.seed_trees`), then Imitation-BT+'s
    tree at each leaf limit of ``plus_seeds`` (a refined tree nearer the search's limit loses
    less when it is cut down to it)."""
    from ibt.runs.front import plus_run

    return [*seed_trees(cfg, task, algo, seed),
            *(plus_run(cfg, task, algo, seed, limit).tree for limit in plus_seeds)]


def evolve_rel_cached(cfg: Config, task: str | Task, algo: str, seed: int, max_leaves: int,
                      plus_seeds: Sequence[int] = (), search_episodes: int | None = None,
                      scaled_weights: bool = False, leaf_rule: str = "vote",
                      selection_episodes: int | None = None) -> Evolution:
    """The relational structure search of one run (cached on its seed trees and settings);
    ``search_episodes``: the search's budget where not the task's; ``scaled_weights``: the
    candidates' weights scaled to each pair's spreads; ``leaf_rule``: how the expert's help
    picks leaf actions; ``selection_episodes``: the held-out episodes that choose among its
    finalists where not the task's (the same search, chosen again:
    :func:`ibt.refine.structure.reselect`, cached as ``evolve-select``; not under ``smoke``)."""
    from ibt.engine.agent import committed_agent
    from ibt.engine.search import evolve_key, evolve_one
    from ibt.refine.relational_structure import reselect_relational

    spec = get_task(task)
    config = relational_search_config(cfg, spec, max_leaves, search_episodes, leaf_rule)
    sources = search_seeds(cfg, spec, algo, seed, plus_seeds)
    agent = committed_agent(spec, algo, cfg.experts_dir)
    record = evolve_one(cfg, agent, sources, config, seed, relational=True,
                        scaled_weights=scaled_weights, agent_in_key=False)
    _, params = evolve_key(agent, sources, config, seed, True, scaled_weights=scaled_weights,
                           agent_in_key=False)
    choice = chosen_on(cfg, config, selection_episodes)
    if choice == config.selection_episodes:
        return record
    return load_or_compute("evolve-select", {**params, "selection_episodes": choice},
                           lambda: reselect_relational(record, spec, choice),
                           cache_dir=cfg.cache_dir, codec="evolution", refresh=cfg.refresh)


def chosen_on(cfg: Config, config: EvolveConfig, selection_episodes: int | None) -> int:
    """The held-out episodes of a run's choices (the search's among its finalists, the
    polish's): ``selection_episodes`` where given, the task's otherwise and under ``smoke``."""
    if selection_episodes is None or cfg.profile == "smoke":
        return config.selection_episodes
    if selection_episodes < 1:
        raise ValueError(f"selection_episodes must be at least 1, not {selection_episodes}")
    return int(selection_episodes)


@dataclass(frozen=True)
class RelationalSearchResult(StructureResult):
    """Imitation-BT+SR for one task, expert, seed and leaf limit (its costs as
    :class:`ibt.runs.search.StructureResult`'s); the tree is relational."""

    @property
    def tree(self) -> Any:
        from ibt.refine.relational import best_tree

        return best_tree(self.polish)


def relational_search_run(cfg: Config, task: str | Task, algo: str, seed: int,
                          max_leaves: int, plus_seeds: Sequence[int] = (),
                          search_episodes: int | None = None, scaled_weights: bool = False,
                          leaf_rule: str = "vote", selection_episodes: int | None = None
                          ) -> RelationalSearchResult:
    """The relational structure search, then the polish of its winner (each cached);
    ``plus_seeds``: leaf limits of Imitation-BT+ trees added to the seed trees;
    ``search_episodes``: the search's budget where not the task's (the polish is the same);
    ``scaled_weights``: candidate weights scaled to each pair's spreads; ``leaf_rule``: how the
    expert's help picks leaf actions ("vote" or "score"); ``selection_episodes``: the held-out
    episodes of the search's and the polish's choices where not the task's."""
    from ibt.engine.refine import refinement_cached
    from ibt.refine.relational_structure import winner

    spec = get_task(task)
    evolution = evolve_rel_cached(cfg, spec, algo, seed, max_leaves, plus_seeds,
                                  search_episodes, scaled_weights, leaf_rule,
                                  selection_episodes)
    base = evolve_config(cfg, spec, max_leaves)
    polish = polish_config(cfg, replace(base, selection_episodes=chosen_on(
        cfg, base, selection_episodes)))
    return RelationalSearchResult(evolution, refinement_cached(cfg, spec, algo, seed, METHOD,
                                                               winner(evolution), polish))


def relational_search_row(cfg: Config, task: str | Task, algo: str, seed: int,
                          max_leaves: int, episodes: int = 1000,
                          threshold: float | None = 200.0, plus_seeds: Sequence[int] = (),
                          search_episodes: int | None = None, scaled_weights: bool = False,
                          leaf_rule: str = "vote", selection_episodes: int | None = None
                          ) -> dict[str, Any]:
    """One run: its smallest verified BT (nodes, relational tests), the 100-episode final
    evaluation of its tree and the anchors' protocol (``episodes`` final episodes of the BT
    from its JSON, the share at or above ``threshold``), and what the run cost."""
    from ibt.bt.model import BehaviorTree
    from ibt.distill.relational import relational_tests
    from ibt.engine.measure import evaluate_tree, expert_evaluation, protocol_evaluation
    from ibt.evaluate.rollouts import retention_norm
    from ibt.runs.front import bar_of, bt_sizes

    spec = get_task(task)
    found = relational_search_run(cfg, spec, algo, seed, max_leaves, plus_seeds,
                                  search_episodes, scaled_weights, leaf_rule,
                                  selection_episodes)
    config = relational_search_config(cfg, spec, max_leaves, search_episodes)
    budget, choice = config.episodes, chosen_on(cfg, config, selection_episodes)
    tree = found.tree
    sizes = bt_sizes(cfg, spec, tree)
    bt = BehaviorTree.from_dict(sizes["bt"])
    evaluation = evaluate_tree(cfg, spec, tree)
    protocol = protocol_evaluation(cfg, spec, bt, episodes, threshold)
    expert = expert_evaluation(cfg, spec, algo)["mean_return"]
    return {"task": spec.name, "expert": algo, "method": METHOD, "seed": seed,
            "max_leaf_nodes": max_leaves,
            "seeded_with": " + ".join(["budget trees",
                                       *(f"Imitation-BT+ at {L} leaves" for L in plus_seeds)]),
            "search_budget": budget,
            "candidate_weights": "scaled to spreads" if scaled_weights else "fixed",
            "leaf_rule": leaf_rule,
            # the choices' held-out episodes where not the task's (None: the task's)
            "selection_episodes": None if choice == config.selection_episodes else choice,
            "default_setting": (
                not plus_seeds and not scaled_weights and leaf_rule == "vote"
                and budget == relational_search_config(cfg, spec, max_leaves).episodes
                and choice == config.selection_episodes),
            "tree_leaves": int(tree.get_n_leaves()),
            "tree_relational_tests": relational_tests(tree), "bt_nodes": bt.node_count,
            "bt_method": sizes["bt_method"], "relational_tests": bt.relational_count,
            "mean_return": evaluation["mean_return"],
            "retention_norm": retention_norm(evaluation["mean_return"], expert,
                                             spec.random_return(cfg.experts_dir)),
            "protocol_episodes": protocol["episodes"],
            "protocol_mean_return": protocol["mean_return"],
            "protocol_std_return": protocol["std_return"],
            "share_at_threshold": protocol["share_at_threshold"],
            "threshold": protocol["threshold"],
            "cpu_seconds": round(found.cpu_seconds, 1), "episodes": found.episodes,
            "env_steps": found.steps,
            "search_steps_per_second": round(found.evolution.steps_per_second),
            "random_steps_per_second": round(found.evolution.random_steps_per_second),
            **bar_of(spec.name, max_leaves)}


def relational_search_table(cfg: Config, experts: list[tuple[str, str]], seeds: list[int],
                            leaves: list[int], threshold: dict[str, float] | None = None,
                            plus_seeds: Sequence[int] = (), search_episodes: int | None = None,
                            scaled_weights: bool = False, leaf_rule: str = "vote",
                            selection_episodes: int | None = None) -> Any:
    """:func:`relational_search_row` for every (task, expert), leaf limit and seed."""
    import pandas as pd
    from tqdm import tqdm

    threshold = threshold or {}
    runs = [(t, a, L, s) for t, a in experts for L in leaves for s in seeds]
    rows = [relational_search_row(cfg, t, a, s, L, threshold=threshold.get(t),
                                  plus_seeds=plus_seeds, search_episodes=search_episodes,
                                  scaled_weights=scaled_weights, leaf_rule=leaf_rule,
                                  selection_episodes=selection_episodes)
            for t, a, L, s in tqdm(runs, desc="imitation-bt+sr", disable=not cfg.progress)]
    return pd.DataFrame(rows)


__all__ = ["METHOD", "RelationalSearchResult", "chosen_on", "evolve_rel_cached",
           "relational_search_row", "relational_search_run", "relational_search_table",
           "search_seeds"]
