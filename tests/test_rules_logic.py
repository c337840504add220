"""ATL extraction, threshold merging and Espresso minimisation keep the logic exact."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from ibt.evaluate.policies import CompiledTree
from ibt.synth.logic import Variables, espresso_cubes, minimise
from ibt.synth.rules import (
    Literal,
    action_template_library,
    dnf_holds,
    leaf_paths,
    leaf_witnesses,
    merge_thresholds,
)
from tests.conftest import fit_tree


def test_atl_partitions_the_space_like_the_tree():
    tree, x = fit_tree()
    atl = action_template_library(tree)
    assert sum(len(t) for t in atl.values()) == tree.get_n_leaves()
    pred = tree.predict(x)
    for action, terms in atl.items():
        assert np.array_equal(dnf_holds(terms, x), pred == action)


def test_compiled_tree_equals_sklearn_on_boundaries():
    tree, x = fit_tree(leaves=20)
    probe = leaf_witnesses(tree, np.full(4, -1.0), np.full(4, 1.0))
    both = np.concatenate([x, probe])
    assert np.array_equal(CompiledTree(tree).predict(both), tree.predict(both))


def test_merge_thresholds_keeps_the_tightest_bounds():
    term = (Literal(0, 0.5, True), Literal(0, 0.2, True), Literal(1, -1.0, False),
            Literal(1, 0.3, False), Literal(0, -0.4, False))
    assert merge_thresholds(term) == (Literal(0, 0.2, True), Literal(0, -0.4, False),
                                      Literal(1, 0.3, False))


def test_espresso_uses_dont_cares():
    # ON a & ~b, DC a & b  ->  a   (Espresso with a don't-care cube)
    assert espresso_cubes(2, [(2, 1)], [(2, 2)]) == [(2, 3)]
    assert espresso_cubes(2, [(2, 1)], []) == [(2, 1)]


def test_implication_dont_cares_shrink_covers_but_stay_exact():
    tree, x = fit_tree(leaves=40, n_actions=4, seed=3)
    atl = action_template_library(tree)
    variables = Variables(t for terms in atl.values() for t in terms)
    probe = np.concatenate([x, leaf_witnesses(tree, np.full(4, -1.0), np.full(4, 1.0))])
    plain = dc = 0
    for terms in atl.values():
        a = minimise(terms, variables)
        b = minimise(terms, variables, dont_cares=True)
        plain += sum(map(len, a))
        dc += sum(map(len, b))
        truth = dnf_holds(terms, probe)
        assert np.array_equal(dnf_holds(a, probe), truth)
        assert np.array_equal(dnf_holds(b, probe), truth)
    assert dc <= plain


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), leaves=st.integers(2, 30), n_actions=st.integers(2, 4))
def test_minimised_rule_sets_are_equivalent_to_the_tree(seed, leaves, n_actions):
    tree, _ = fit_tree(leaves=leaves, n_actions=n_actions, seed=seed, n=400)
    atl = action_template_library(tree)
    variables = Variables(t for terms in atl.values() for t in terms)
    rng = np.random.default_rng(seed)
    probe = np.concatenate([rng.uniform(-1.2, 1.2, size=(2000, 4)).astype(np.float32),
                            leaf_witnesses(tree, np.full(4, -1.0), np.full(4, 1.0))])
    pred = tree.predict(probe)
    for action, terms in atl.items():
        assert np.array_equal(dnf_holds(minimise(terms, variables), probe), pred == action)


def test_leaf_paths_follow_sklearn_semantics():
    tree, x = fit_tree()
    leaf_of = tree.apply(x)
    paths = leaf_paths(tree)
    assert len(paths) == len(set(leaf_of))
    for path in paths:
        inside = np.ones(len(x), bool)
        for lit in path.term:
            inside &= lit.holds(x)
        assert len(set(leaf_of[inside])) == 1
