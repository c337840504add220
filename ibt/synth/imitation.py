"""Action Template Library -> Behavior Tree (Imitation-BT), and the proof that it is exact.

Imitation-BT's construction, step by step:

1. read one DNF per action off the decision tree (:mod:`ibt.synth.rules`);
2. minimise each with Espresso and merge thresholds on one feature (:mod:`ibt.synth.logic`);
3. give each rule set its complexity k (literal count) and sort by k;
4. pick a default action (strategy ``max_complexity``: the largest k, the paper's eq. 14;
   ``most_frequent``: the action most training samples reach; ``smallest_tree``: whichever of
   the candidates gives the fewest nodes);
5. build a root Selector with one Sequence per non-default action, in increasing k, each
   ``Sequence(rule, action)`` where the rule is a Fallback over the action's terms (a term of
   several literals is a Sequence of Conditions); the default action comes last, unguarded.

Single-child composites are not emitted: a rule of one term puts its conditions straight into
the action's Sequence, and a one-literal term is a bare Condition. Because the rule sets of a
tree partition the state space, the order of the Sequences never changes a decision, and the
default action is reached exactly on its own region. :func:`verify` checks this on every leaf
region, on each split boundary and on random states, and :func:`imitation_bt` refuses to return
a BT that disagrees with its source tree.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
from sklearn.tree import DecisionTreeClassifier

from ibt.bt.linear import FeatureMap
from ibt.bt.model import Action, BehaviorTree, Condition, Fallback, Node, Selector, Sequence
from ibt.evaluate.policies import CompiledTree
from ibt.synth.logic import Variables, minimise
from ibt.synth.rules import ATL, Literal, Term, action_template_library, leaf_paths, literal_count
from ibt.tasks.catalogue import Task

DEFAULT_STRATEGIES = ("max_complexity", "most_frequent", "smallest_tree")


class NotEquivalentError(AssertionError):
    """A synthesised BT decides differently from its source tree on some state."""


@dataclass(frozen=True)
class RuleSet:
    action: int
    terms: tuple[Term, ...]

    @property
    def k(self) -> int:
        return literal_count(list(self.terms))


@dataclass(frozen=True)
class Synthesis:
    """A synthesised BT with how it was made (``search``: what a searching synthesiser tried,
    e.g. :func:`ibt.synth.decision_list.decision_list_bt`'s candidates and work)."""

    bt: BehaviorTree
    method: str
    default_action: int | None
    default_strategy: str | None
    rule_sets: tuple[RuleSet, ...]
    search: dict[str, Any] = field(default_factory=dict)
    # a relational tree's feature map: its rule sets' literals read augmented columns
    feature_map: FeatureMap | None = None


def minimised_rule_sets(tree: DecisionTreeClassifier, *, dont_cares: bool = False
                        ) -> list[RuleSet]:
    """The ATL minimised per action, sorted by (k, action)."""
    atl: ATL = action_template_library(tree)
    variables = Variables(t for terms in atl.values() for t in terms)
    sets = [RuleSet(a, tuple(minimise(terms, variables, dont_cares=dont_cares)))
            for a, terms in atl.items()]
    return sorted(sets, key=lambda rs: (rs.k, rs.action))


def _condition(lit: Literal) -> Condition:
    return Condition(lit.feature, lit.op, lit.threshold)


def _term_node(term: Term) -> Node:
    if len(term) == 1:
        return _condition(term[0])
    return Sequence(tuple(_condition(lit) for lit in term))


def _guarded_action(rs: RuleSet) -> Node:
    if len(rs.terms) == 1:
        return Sequence((*(_condition(lit) for lit in rs.terms[0]), Action(rs.action)))
    return Sequence((Fallback(tuple(_term_node(t) for t in rs.terms)), Action(rs.action)))


def assemble(rule_sets: list[RuleSet], default: int) -> Node:
    """Root Selector: guarded non-default actions in increasing k, then the default."""
    guarded = [_guarded_action(rs) for rs in rule_sets if rs.action != default]
    return Selector((*guarded, Action(default)))


def _most_frequent(tree: DecisionTreeClassifier) -> int:
    mass: dict[int, float] = {}
    for path in leaf_paths(tree):
        mass[path.action] = mass.get(path.action, 0.0) + path.samples
    return max(mass, key=lambda a: (mass[a], -a))


def imitation_bt(tree: DecisionTreeClassifier, task: Task, *,
                 default_strategy: str = "max_complexity", dont_cares: bool = False,
                 check: bool = True, rng_seed: int = 0) -> Synthesis:
    """Synthesise the Imitation-BT of ``tree`` (verified exact unless ``check=False``); a
    relational tree goes through :func:`ibt.synth.relational.synthesise`."""
    from ibt.synth import relational

    if relational.is_relational(tree):
        return relational.synthesise(imitation_bt, tree, task, default_strategy=default_strategy,
                                     dont_cares=dont_cares, check=check, rng_seed=rng_seed)
    if default_strategy not in DEFAULT_STRATEGIES:
        raise ValueError(f"unknown default strategy {default_strategy!r}; expected one of "
                         f"{', '.join(DEFAULT_STRATEGIES)}")
    sets = minimised_rule_sets(tree, dont_cares=dont_cares)
    if default_strategy == "max_complexity":
        default = sets[-1].action  # the largest k; ties broken towards the larger action index
    elif default_strategy == "most_frequent":
        default = _most_frequent(tree)
    else:
        default = min((rs.action for rs in sets),
                      key=lambda a: (_node_total(assemble(sets, a)), -_k_of(sets, a)))
    bt = BehaviorTree(assemble(sets, default), task.feature_names, task.action_names,
                      task.value_labels)
    result = Synthesis(bt, "imitation-bt", default, default_strategy, tuple(sets))
    if check:
        verify(bt, tree, task, seed=rng_seed)
    return result


def rules_frame(result: Synthesis) -> pd.DataFrame:
    """The minimised rule sets as a table: action, k, rule text, and which is the default."""
    bt = result.bt
    names = (bt.feature_names if result.feature_map is None
             else result.feature_map.names(bt.feature_names))  # augmented columns' names
    rows = []
    for rs in result.rule_sets:
        text = " OR ".join("(" + " and ".join(
            f"{names[lit.feature]} {lit.op} {lit.threshold:.4g}" for lit in term)
            + ")" if term else "(always)" for term in rs.terms)
        rows.append({"action": bt.action_names[rs.action], "k": rs.k, "terms": len(rs.terms),
                     "default": rs.action == result.default_action, "rule": text})
    return pd.DataFrame(rows)


def _k_of(sets: list[RuleSet], action: int) -> int:
    return next(rs.k for rs in sets if rs.action == action)


def _node_total(root: Node) -> int:
    from ibt.bt.model import iterate

    return sum(1 for _ in iterate(root))


def verification_states(tree: DecisionTreeClassifier, task: Task, n_random: int = 20_000,
                        seed: int = 0) -> np.ndarray:
    """States that test a BT against its tree: inside every leaf, on every split, random ones.

    For discrete-state tasks the whole state space is included.
    """
    from ibt.synth.rules import leaf_witnesses

    low = np.full(task.n_features, -np.inf)
    high = np.full(task.n_features, np.inf)
    parts = [leaf_witnesses(tree, low, high),
             task.sample_features(n_random, np.random.default_rng(seed))]
    if task.discrete_state:
        parts.append(np.arange(task.low[0], task.high[0] + 1, dtype=np.float32)[:, None])
    return np.concatenate([p.astype(np.float32) for p in parts])


def verify(bt: BehaviorTree, tree: DecisionTreeClassifier, task: Task, *, seed: int = 0,
           n_random: int = 20_000) -> int:
    """Raise :class:`NotEquivalentError` unless ``bt`` decides as ``tree`` on every test state.

    The states are finite: NaN and infinity are refused by every executor, the tree's and the
    BT's alike (:mod:`ibt.bt.executors`), so finite states are the whole domain on which the two
    must agree. Returns the number of states checked. A relational tree is checked in
    observed space by :func:`ibt.synth.relational.verify_relational`.
    """
    from ibt.synth import relational

    if relational.is_relational(tree):
        return relational.verify_relational(bt, tree, task, seed=seed, n_random=n_random)
    states = verification_states(tree, task, n_random=n_random, seed=seed)
    return check_agreement(bt, states, CompiledTree(tree).predict(states), "tree")


def check_agreement(bt: BehaviorTree, states: np.ndarray, expected: np.ndarray,
                    source: str) -> int:
    """Raise :class:`NotEquivalentError` unless ``bt`` decides ``expected`` (its ``source``'s
    actions, e.g. ``"tree"``) on every row of ``states``; returns how many states were checked.
    The one comparison of :func:`verify` and :func:`ibt.synth.relational.verify_relational`."""
    got = bt.decide(states)
    bad = np.flatnonzero(expected != got)
    if len(bad):
        i = bad[0]
        raise NotEquivalentError(
            f"BT disagrees with its {source} on {len(bad)} of {len(states)} states; first: "
            f"{states[i].tolist()} -> BT {got[i]}, tree {expected[i]}")
    return len(states)
