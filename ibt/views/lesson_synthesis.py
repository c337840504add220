"""The lesson's synthesis chain (stage 2 of ``notebooks/08_lesson.ipynb``): a decision tree's
way to its Imitation-BT, one stage at a time (tree, paths, DNF per action, Espresso, threshold
merge, ordering and default, BT), with the rule, literal and node counts at each stage and the
nodes of tree and BT side by side. Plain data; the views are in :mod:`ibt.views.widgets`.
"""

from __future__ import annotations

from collections.abc import Sequence as Seq
from dataclasses import dataclass
from typing import Any

import pandas as pd
from sklearn.tree import DecisionTreeClassifier

from ibt.bt.model import BehaviorTree
from ibt.synth.logic import Variables, minimise
from ibt.synth.rules import action_template_library, leaf_paths, literal_count
from ibt.tasks.catalogue import Task, get_task


# ------------------------------------------------------------------------ 2. the synthesis chain
@dataclass(frozen=True)
class SynthesisChain:
    """The stages from a decision tree to its Imitation-BT, with their sizes."""

    stages: pd.DataFrame  # one row per stage: terms, literals (or conditions), nodes
    per_action: pd.DataFrame  # one row per action: terms and literals at each stage
    bt: BehaviorTree
    tree_splits: int
    tree_leaves: int

    def node_breakdown(self) -> pd.DataFrame:
        """Where the nodes are: tests, branching nodes and decisions, tree beside BT."""
        types = self.bt.node_types()
        composites = sum(types[k] for k in ("selector", "sequence", "fallback", "inverter"))
        return pd.DataFrame({
            "decision tree": {"tests (splits / conditions)": self.tree_splits,
                              "branching (composites)": 0, "decisions (leaves / actions)":
                              self.tree_leaves, "total": self.tree_splits + self.tree_leaves},
            "Behavior Tree": {"tests (splits / conditions)": types["condition"],
                              "branching (composites)": composites,
                              "decisions (leaves / actions)": types["action"],
                              "total": self.bt.node_count}})

    def why_more_nodes(self) -> str:
        """The node counts of tree and BT, explained with this tree's numbers."""
        types = self.bt.node_types()
        composites = self.bt.node_count - types["condition"] - types["action"]
        paths = self.stages.set_index("stage").loc["2. paths", "literals"]
        return (
            f"The tree has {self.tree_splits} splits and {self.tree_leaves} leaves "
            f"({self.tree_splits + self.tree_leaves} nodes): a split is a test and a branch point "
            f"at once, shared by every leaf below it. The BT has {self.bt.node_count} nodes: "
            f"{types['condition']} conditions, {composites} composites and {types['action']} "
            f"actions. Written as rules, a split is repeated in the path of every leaf below it "
            f"({paths} literals over {self.tree_leaves} paths); Espresso and the threshold merge "
            f"remove many but not all of the repeats. The branching that the tree gets for free "
            f"costs composite nodes in a BT (the root Selector, one Sequence per guarded action, "
            f"a Fallback for a rule of several terms, a Sequence for a term of several "
            f"literals). The BT saves only on decisions: one action node per action instead of "
            f"one leaf per region.")


def _terms_literals(terms: Seq[Any]) -> tuple[int, int]:
    return len(terms), literal_count(list(terms))


def synthesis_stages(tree: DecisionTreeClassifier, task: str | Task) -> SynthesisChain:
    """Every stage of :func:`ibt.synth.imitation.imitation_bt` on ``tree``, with its counts.

    Espresso and the merge are run here stage by stage (:func:`ibt.synth.logic.minimise` without,
    then with the merge); the ordering, the default and the BT are ``imitation_bt``'s own.
    """
    from ibt.synth.imitation import imitation_bt

    spec = get_task(task)
    names = spec.action_names
    paths = leaf_paths(tree)
    atl = action_template_library(tree)
    variables = Variables(t for terms in atl.values() for t in terms)
    espresso = {a: minimise(terms, variables, merge=False) for a, terms in atl.items()}
    merged = {a: minimise(terms, variables, merge=True) for a, terms in atl.items()}
    result = imitation_bt(tree, spec)
    order = [rs.action for rs in result.rule_sets]
    default = result.default_action
    guarded = [rs for rs in result.rule_sets if rs.action != default]
    splits = int(tree.tree_.node_count - tree.get_n_leaves())
    types = result.bt.node_types()

    def row(stage: str, terms: int | None, literals: int | None, nodes: int | None,
            note: str) -> dict[str, Any]:
        return {"stage": stage, "terms": terms, "literals": literals, "nodes": nodes,
                "note": note}

    all_paths = [p.term for p in paths]
    esp_t, esp_l = _terms_literals([t for ts in espresso.values() for t in ts])
    mer_t, mer_l = _terms_literals([t for ts in merged.values() for t in ts])
    stages = pd.DataFrame([
        row("1. decision tree", None, splits, int(tree.tree_.node_count),
            f"{splits} splits (literals: one test each), {tree.get_n_leaves()} leaves"),
        row("2. paths", *_terms_literals(all_paths), None,
            "one conjunction per leaf, root to leaf"),
        row("3. DNF per action", *_terms_literals(all_paths), None,
            f"the paths grouped by their leaf's action: {len(atl)} rule sets"),
        row("4. Espresso", esp_t, esp_l, None, "each action's DNF minimised on its own"),
        row("5. threshold merge", mer_t, mer_l, None,
            "x <= a and x <= b -> x <= min(a, b); x > a and x > b -> x > max(a, b)"),
        row("6. ordering and default", *_terms_literals([t for rs in guarded for t in rs.terms]),
            None, f"guards sorted by k: {', '.join(names[a] for a in order if a != default)}; "
                  f"default {names[default] if default is not None else '-'} (largest k) "
                  f"goes last, unguarded"),
        row("7. Behavior Tree", None, types["condition"], result.bt.node_count,
            f"{types['condition']} conditions, "
            f"{result.bt.node_count - types['condition'] - types['action']} composites, "
            f"{types['action']} actions"),
    ])
    for col in ("terms", "literals", "nodes"):
        stages[col] = stages[col].astype("Int64")
    k = {rs.action: rs.k for rs in result.rule_sets}
    per_action = pd.DataFrame([{
        "action": names[a],
        "paths": len(atl[a]), "path literals": literal_count(atl[a]),
        "Espresso terms": len(espresso[a]), "Espresso literals": literal_count(espresso[a]),
        "merged terms": len(merged[a]), "k (merged literals)": literal_count(merged[a]),
        "k in the BT": k.get(a), "position": order.index(a) + 1 if a in order else None,
        "default": a == default} for a in sorted(atl)])
    return SynthesisChain(stages, per_action, result.bt, splits, int(tree.get_n_leaves()))
