"""BT-Espresso and RE:BT-Espresso: exact, structured as published, larger than Imitation-BT."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.tree import DecisionTreeClassifier

from ibt.bt.model import Action, Condition, Fallback, Inverter, Selector, Sequence
from ibt.synth.baselines import (
    bt_espresso,
    bt_espresso_symbols,
    factor_common,
    re_bt_espresso,
    re_bt_espresso_symbols,
)
from ibt.synth.imitation import NotEquivalentError, imitation_bt, verify
from ibt.synth.rules import Literal, action_template_library
from ibt.tasks.catalogue import Task
from tests.conftest import fit_tree

TOY = Task(name="toy", gym_id="none", feature_names=("f0", "f1", "f2", "f3"),
           action_names=("a0", "a1", "a2", "a3"), low=(-1,) * 4, high=(1,) * 4)
BASELINES = {"bt-espresso": bt_espresso, "re-bt-espresso": re_bt_espresso}


def _task(n_features: int, n_actions: int = 4) -> Task:
    return Task(name="tiny", gym_id="none",
                feature_names=tuple(f"f{i}" for i in range(n_features)),
                action_names=tuple(f"a{i}" for i in range(n_actions)),
                low=(-2,) * n_features, high=(2,) * n_features)


def _xor_tree() -> DecisionTreeClassifier:
    """Root on one feature, both children on the other at the same threshold (0.0)."""
    corners = np.array(list(itertools.product([-1.0, 1.0], repeat=2)), dtype=np.float32)
    counts = [5, 3, 2, 4]  # unequal masses so the first split has a gain
    x = np.repeat(corners, counts, axis=0)
    y = (x[:, 0] > 0) ^ (x[:, 1] > 0)
    return DecisionTreeClassifier(random_state=0).fit(x, y.astype(int))


def _internal(tree: DecisionTreeClassifier) -> list[int]:
    t = tree.tree_
    return [i for i in range(t.node_count) if t.children_left[i] != t.children_right[i]]


def _literals(bt) -> list:
    return [n for n in bt.nodes() if isinstance(n, Condition)]


@pytest.mark.parametrize("method", sorted(BASELINES))
def test_root_selector_guards_every_action(method):
    tree, _ = fit_tree(leaves=14, n_actions=4, seed=3)
    result = BASELINES[method](tree, TOY)
    assert result.method == method
    assert result.default_action is None and result.default_strategy is None
    root = result.bt.root
    assert isinstance(root, Selector)
    actions = sorted(action_template_library(tree))
    assert [g.children[-1] for g in root.children] == [Action(a) for a in actions]
    assert all(isinstance(g, Sequence) for g in root.children)  # no unguarded default
    assert [rs.action for rs in result.rule_sets] == actions


def test_bt_espresso_negates_inside_the_condition():
    """As its authors' code: a negated literal is the one condition ``x > t``, no Inverter."""
    tree, _ = fit_tree(leaves=20, n_actions=3, seed=11)
    bt = bt_espresso(tree, TOY).bt
    assert {c.op for c in _literals(bt)} == {"<=", ">"}
    assert not any(isinstance(n, Inverter) for n in bt.nodes())
    _assert_no_single_child_composites(bt)


def test_re_bt_espresso_negates_by_inverter():
    """As its authors' code: only ``<=`` conditions; a negated literal is an Inverter."""
    tree, _ = fit_tree(leaves=20, n_actions=3, seed=11)
    bt = re_bt_espresso(tree, TOY).bt
    assert {c.op for c in _literals(bt)} == {"<="}
    assert any(isinstance(n, Inverter) for n in bt.nodes())
    _assert_no_single_child_composites(bt)


def _assert_no_single_child_composites(bt) -> None:
    """As in the reference implementations, no Sequence or Fallback has a single child."""
    for node in bt.nodes():
        if isinstance(node, Sequence | Fallback):
            assert len(node.children) >= 2


def _authors_node_count(tree: DecisionTreeClassifier) -> int:
    """BT-Espresso's size by its authors' construction (``fnivek/bt-espresso``, ``lfd``).

    Their rule, restated: one boolean variable per internal node; each action's leaf paths
    are OR-ed and, when the action has more than one path, minimised by pyeda's
    ``espresso_exprs``; a Parallel root holds, per action, ``Sequence(literals..., action)`` for
    one product term, else ``Sequence(Fallback(terms...), action)`` where a one-literal term is
    a bare condition and a longer one a Sequence; a literal, negated or not, is one condition.
    """
    from pyeda.inter import And, Not, Or, espresso_exprs, exprvar

    t = tree.tree_
    paths: dict[int, list[list[tuple[int, bool]]]] = {}
    stack: list[tuple[int, list[tuple[int, bool]]]] = [(0, [])]
    while stack:
        node, path = stack.pop()
        if t.children_left[node] == t.children_right[node]:
            action = int(tree.classes_[int(np.argmax(t.value[node][0]))])
            paths.setdefault(action, []).append(path)
            continue
        stack.append((t.children_left[node], [*path, (node, True)]))
        stack.append((t.children_right[node], [*path, (node, False)]))
    variables = {i: exprvar(f"a{i}") for i in _internal(tree)}
    count = 1  # the root
    for action_paths in paths.values():
        if len(action_paths) == 1:
            term_sizes = [len(action_paths[0])]
        else:
            sop = Or(*[And(*[variables[i] if le else Not(variables[i]) for i, le in path])
                       for path in action_paths]).to_dnf()
            (minimised,) = espresso_exprs(sop)
            terms = minimised.xs if minimised.ASTOP == "or" else (minimised,)
            term_sizes = [len(term.xs) if term.ASTOP == "and" else 1 for term in terms]
        if len(term_sizes) == 1:
            count += term_sizes[0] + 2  # Sequence(literals..., action)
        else:  # Sequence(Fallback(terms...), action)
            count += 3 + sum(1 if size == 1 else size + 1 for size in term_sizes)
    return count


@pytest.mark.parametrize("seed", range(6))
def test_bt_espresso_size_equals_its_authors_construction(seed):
    tree, _ = fit_tree(leaves=6 + 5 * seed, n_actions=2 + seed % 3, seed=seed, n=600)
    assert bt_espresso(tree, TOY).bt.node_count == _authors_node_count(tree)


# The committed seed-best BC trees the BT-Espresso baseline is built from, and its size by the
# authors' rule (an Inverter over ``x <= t`` for each negated literal gave 68 and 313 nodes).
COMMITTED = [("CartPole-v1", "dqn", 3, 52), ("LunarLander-v3", "dqn", 0, 235)]


@pytest.mark.parametrize(("task", "algo", "seed", "authors_nodes"), COMMITTED)
def test_committed_trees_match_the_authors_node_counts(task, algo, seed, authors_nodes):
    import ibt
    from ibt.bt.model import BehaviorTree
    from ibt.paths import DATA_DIR
    from ibt.tasks.catalogue import get_task

    cfg = ibt.config("paper", progress=False)  # a cache hit on the committed data/cache
    tree = ibt.distill_cached(cfg, task, algo, "bc", seed).best_tree
    assert _authors_node_count(tree) == authors_nodes
    bt = bt_espresso(tree, get_task(task)).bt
    assert bt.node_count == authors_nodes
    committed = BehaviorTree.from_json(
        (DATA_DIR / "trees" / task / algo / "bt-espresso.json").read_bytes())
    assert committed.node_count == authors_nodes


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 5_000), leaves=st.integers(2, 40), n_actions=st.integers(2, 4),
       method=st.sampled_from(sorted(BASELINES)))
def test_baseline_decides_as_tree_everywhere(seed, leaves, n_actions, method):
    tree, _ = fit_tree(leaves=leaves, n_actions=n_actions, seed=seed, n=500)
    result = BASELINES[method](tree, TOY, check=False)
    states = np.random.default_rng(seed).uniform(-1.5, 1.5, size=(3000, 4)).astype(np.float32)
    assert np.array_equal(result.bt.decide(states), tree.predict(states))
    verify(result.bt, tree, TOY, seed=seed, n_random=2_000)


def test_check_rejects_a_wrong_tree(monkeypatch):
    import ibt.synth.baselines as baselines

    tree, _ = fit_tree(leaves=10)
    monkeypatch.setattr(baselines, "factor_common", lambda terms: ((), terms[:1]))
    with pytest.raises(NotEquivalentError):
        baselines.re_bt_espresso(tree, TOY)


def test_single_leaf_tree_is_one_unguarded_action():
    x = np.zeros((5, 4), dtype=np.float32)
    tree = DecisionTreeClassifier().fit(x, np.full(5, 2))
    for method in BASELINES.values():
        assert method(tree, TOY).bt.root == Selector((Action(2),))


def test_bt_espresso_keeps_one_symbol_per_internal_node():
    tree = _xor_tree()
    internal = _internal(tree)
    t = tree.tree_
    tests = {(int(t.feature[i]), float(t.threshold[i])) for i in internal}
    assert len(internal) == 3 and len(tests) == 2  # two nodes share one test
    symbols = bt_espresso_symbols(tree)
    assert [s.nodes for s in symbols] == [(i,) for i in internal]
    assert len(re_bt_espresso_symbols(tree)) == 2  # RE:BT-Espresso merges them
    for method in BASELINES.values():
        method(tree, _task(2))  # both exact


@pytest.mark.parametrize("seed", range(5))
def test_symbol_count_equals_internal_node_count(seed):
    tree, _ = fit_tree(leaves=8 + 6 * seed, seed=seed)
    symbols = bt_espresso_symbols(tree)
    assert len(symbols) == len(_internal(tree)) == tree.tree_.node_count // 2
    assert len(re_bt_espresso_symbols(tree)) <= len(symbols)


def test_rounding_never_merges_tests_that_decide_differently():
    x = np.array([[0.123], [0.1232], [0.1236]], dtype=np.float32)
    tree = DecisionTreeClassifier(random_state=0).fit(x, [0, 1, 0])
    thresholds = sorted(float(t) for t in tree.tree_.threshold if t != -2)
    assert round(thresholds[0], 3) == round(thresholds[1], 3) == 0.123  # same rounded key
    symbols = re_bt_espresso_symbols(tree)
    assert sorted(s.threshold for s in symbols) == thresholds  # kept apart, exact
    bt = re_bt_espresso(tree, _task(1)).bt
    probe = np.array([[0.1233]], dtype=np.float32)
    assert bt.decide(probe)[0] == tree.predict(probe)[0] == 1


def test_rounding_merges_float32_identical_tests():
    tree = _xor_tree()
    internal = _internal(tree)
    threshold = tree.tree_.threshold  # a writable view on the tree's nodes
    # a threshold a hair above the other child's: no float32 observation tells them apart
    threshold[internal[2]] = np.nextafter(threshold[internal[1]], np.inf)
    assert len(re_bt_espresso_symbols(tree)) == 2
    re_bt_espresso(tree, _task(2))
    # now noticeably apart, though both round to 0.0: two symbols
    threshold[internal[2]] = threshold[internal[1]] + 4e-4
    assert len(re_bt_espresso_symbols(tree)) == 3
    re_bt_espresso(tree, _task(2))


def _shared_literal_tree() -> DecisionTreeClassifier:
    """a0 iff f0 <= 0 and (f1 <= 0 or f2 <= 0); a1 iff f0 <= 0 otherwise; a2 iff f0 > 0."""
    corners = np.array(list(itertools.product([-1.0, 1.0], repeat=3)), dtype=np.float32)
    x = np.repeat(corners, np.arange(1, 9), axis=0)
    y = np.where(x[:, 0] > 0, 2, np.where((x[:, 1] <= 0) | (x[:, 2] <= 0), 0, 1))
    return DecisionTreeClassifier(random_state=0).fit(x, y)


def test_re_bt_espresso_factors_the_common_literal():
    tree = _shared_literal_tree()
    task = _task(3)
    guard = re_bt_espresso(tree, task).bt.root.children[0]
    assert guard.children[0] == Condition(0, "<=", 0.0)
    assert isinstance(guard.children[1], Fallback)
    assert set(guard.children[1].children) == {Condition(1, "<=", 0.0), Condition(2, "<=", 0.0)}
    assert guard.children[2] == Action(0)
    assert len(guard.children) == 3
    # BT-Espresso repeats the shared literal in each term instead
    plain = bt_espresso(tree, task).bt.root.children[0]
    assert isinstance(plain.children[0], Fallback) and len(plain.children[0].children) == 2
    assert all(Condition(0, "<=", 0.0) in term.children for term in plain.children[0].children)


def test_factor_common():
    a, b, c = Literal(0, 0.0, True), Literal(1, 0.0, False), Literal(2, 1.0, True)
    assert factor_common([(a, b), (a, c)]) == ((a,), [(b,), (c,)])
    assert factor_common([(a, b), (c,)]) == ((), [(a, b), (c,)])
    assert factor_common([(a, b)]) == ((), [(a, b)])
    assert factor_common([(a,), (a, b)]) == ((a,), [])  # the remainder is always true


def test_re_bt_espresso_merges_thresholds_within_terms():
    for seed in range(4):
        tree, _ = fit_tree(leaves=24, seed=seed)
        for rs in re_bt_espresso(tree, TOY, check=False).rule_sets:
            for term in rs.terms:
                keys = [(lit.feature, lit.le) for lit in term]
                assert len(keys) == len(set(keys))


def test_imitation_bt_is_smallest_on_typical_trees():
    rng = np.random.default_rng(2024)
    for seed in range(20):
        leaves = int(rng.integers(8, 33))
        tree, _ = fit_tree(leaves=leaves, n_actions=int(rng.integers(2, 5)), seed=seed, n=800)
        ours, *baselines = [f(tree, TOY, check=False).bt.node_count
                            for f in (imitation_bt, re_bt_espresso, bt_espresso)]
        # RE:BT-Espresso's Inverters can outweigh what its factoring saves over BT-Espresso's
        # in-condition negation, so the two baselines are not ordered; Imitation-BT is smallest
        assert ours <= min(baselines), (seed, leaves, ours, baselines)
