"""ATL extraction, threshold merging and Espresso minimisation keep the logic exact."""

from __future__ import annotations

import numpy as np
import pytest
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
    literal_count,
    merge_thresholds,
    term_holds,
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


# ------------------------------------------------------------------- variables and Espresso
L = Literal


def test_variables_number_each_distinct_test_in_feature_then_threshold_order():
    terms = [(L(1, 0.5, True), L(0, 0.2, False)), (L(0, -0.3, True), L(1, 0.5, False))]
    variables = Variables(terms)
    assert variables.keys == [(0, -0.3), (0, 0.2), (1, 0.5)] and len(variables) == 3
    assert variables.index == {(0, -0.3): 0, (0, 0.2): 1, (1, 0.5): 2}
    assert variables.cube(terms[0]) == (3, 1, 2)  # absent, false (x > t), true (x <= t)
    assert variables.cube(()) == (3, 3, 3)
    for term in terms:
        assert set(variables.term(variables.cube(term))) == set(term)
    assert variables.cube((L(1, 0.5, True), L(1, 0.5, True))) == (3, 3, 2)  # repeated: fine
    with pytest.raises(ValueError, match="contradictory term"):
        variables.cube((L(1, 0.5, True), L(1, 0.5, False)))
    with pytest.raises(ValueError):  # a cube of another rule set's variables
        variables.term((2, 1))


def test_implication_dont_cares_are_every_lower_true_higher_false_pair_per_feature():
    variables = Variables([(L(0, 0.1, True), L(0, 0.2, True), L(0, 0.3, True),
                            L(1, 5.0, True), L(2, 1.0, True), L(2, 2.0, True))])
    assert sorted(variables.implication_dont_cares()) == sorted([
        (2, 1, 3, 3, 3, 3), (2, 3, 1, 3, 3, 3), (3, 2, 1, 3, 3, 3), (3, 3, 3, 3, 2, 1)])


def test_espresso_of_nothing_and_of_no_variables():
    assert espresso_cubes(3, [], [(3, 3, 3)]) == []
    assert espresso_cubes(0, [()], []) == [()]


def test_a_large_cover_runs_in_a_child_with_the_same_result():
    on = [(2, 1, 3), (2, 2, 3), (1, 3, 2)]
    here = espresso_cubes(3, on, [])
    assert here == [(2, 3, 3), (3, 3, 2)]  # a & ~b | a & b | c is a | c
    assert espresso_cubes(3, on, [], in_process_limit=8) == here  # 9 > 8: in a child


@pytest.fixture
def espresso_hangs(monkeypatch):
    """Espresso that never ends (in the child it runs in: forked, it inherits the patch)."""
    import time

    from ibt.synth import logic

    def hang(*args, **kwargs):
        time.sleep(10)

    monkeypatch.setattr(logic, "_run_espresso", hang)


def test_espresso_out_of_time_keeps_the_unminimised_cover_with_a_warning(espresso_hangs):
    terms = [(L(0, 0.5, True), L(1, 0.0, True)), (L(0, 0.5, True), L(1, 0.0, False))]
    variables = Variables(terms)
    assert espresso_cubes(2, [(2, 2), (2, 1)], [], timeout=0.2, in_process_limit=0) is None
    with pytest.warns(UserWarning, match=r"Espresso exceeded 0 s on 2 cubes over 2 variables"):
        kept = minimise(terms, variables, timeout=0.2, in_process_limit=0)
    assert kept == sorted(terms)


def test_covers_up_to_the_limit_run_here_and_larger_ones_in_a_child(monkeypatch):
    import os

    from ibt.synth import logic

    monkeypatch.setattr(logic, "_run_espresso", lambda *args: [(os.getpid(),)])
    here = [(os.getpid(),)]
    on, dc = [(2, 1, 3), (2, 2, 3), (1, 2, 3)], [(1, 1, 1)]  # 4 cubes x 3 variables: 12
    assert espresso_cubes(3, on, dc, in_process_limit=12) == here
    assert espresso_cubes(3, on, dc, in_process_limit=100) == here
    assert espresso_cubes(3, on, dc, in_process_limit=11) != here
    assert espresso_cubes(1, [(2,)] * 4_000, []) == here  # the default limit: 4,000 cells
    assert espresso_cubes(1, [(2,)] * 4_001, []) != here


def test_minimise_minimises():
    terms = [(L(0, 0.5, True), L(1, 0.0, True)), (L(0, 0.5, True), L(1, 0.0, False))]
    assert minimise(terms, Variables(terms)) == [(L(0, 0.5, True),)]


def test_minimise_of_nothing_is_nothing():
    assert minimise([], Variables([])) == []


def test_minimise_sorts_by_length_then_literals_and_merges_only_when_asked():
    terms = [(L(0, 0.5, True), L(1, 0.0, True), L(2, 0.0, True)), (L(3, 1.0, False),)]
    variables = Variables(terms)
    assert minimise(terms, variables) == [terms[1], terms[0]]
    # x0 <= 0.2 and x0 <= 0.5 (a cover Espresso keeps): merged to x0 <= 0.2, or left whole
    nested = [(L(0, 0.2, True), L(0, 0.5, True), L(1, 0.0, True))]
    both = Variables(nested)
    assert minimise(nested, both) == [(L(0, 0.2, True), L(1, 0.0, True))]
    assert minimise(nested, both, merge=False) == [(L(0, 0.2, True), L(0, 0.5, True),
                                                    L(1, 0.0, True))]


def test_terms_that_merge_to_one_are_kept_once(espresso_hangs):
    # Espresso never returns such a pair; the unminimised cover kept after a timeout may
    terms = [(L(0, 0.2, True), L(0, 0.5, True)), (L(0, 0.2, True),)]
    with pytest.warns(UserWarning, match="Espresso exceeded"):
        kept = minimise(terms, Variables(terms), timeout=0.2, in_process_limit=0)
    assert kept == [(L(0, 0.2, True),)]


def test_extra_dont_cares_let_espresso_drop_a_literal():
    terms = [(L(0, 0.5, True), L(1, 0.0, True))]
    variables = Variables([*terms, (L(1, 0.0, False),)])
    assert minimise(terms, variables) == terms
    assert minimise(terms, variables, extra_dont_cares=[(L(0, 0.5, True), L(1, 0.0, False))]
                    ) == [(L(0, 0.5, True),)]


def test_implication_dont_cares_are_used_only_when_asked():
    # x <= 0.2 implies x <= 0.5: with the implication known, the cover is x <= 0.5 alone
    one = [(L(0, 0.2, True),), (L(0, 0.2, False), L(0, 0.5, True))]
    variables = Variables(one)
    assert minimise(one, variables) == [(L(0, 0.2, True),), (L(0, 0.5, True),)]
    assert minimise(one, variables, dont_cares=True) == [(L(0, 0.5, True),)]


class _Waited:
    """A stand-in for multiprocessing's fork context: records how long the parent waits."""

    def __init__(self) -> None:
        self.waits: list[float] = []

    def get_context(self, method: str) -> _Waited:
        assert method == "fork"
        return self

    def Pipe(self, duplex: bool):  # multiprocessing's names
        waits = self.waits

        class End:
            def poll(self, timeout: float) -> bool:
                waits.append(timeout)
                return True

            def recv(self) -> list:
                return [(2,)]

            def close(self) -> None:
                pass

        return End(), End()

    def Process(self, **kwargs):
        class Child:
            def start(self) -> None:
                pass

            def join(self) -> None:
                pass

        return Child()


def test_espresso_waits_thirty_seconds_by_default(monkeypatch):
    from ibt.synth import logic

    fake = _Waited()
    monkeypatch.setattr(logic, "mp", fake)
    assert espresso_cubes(1, [(2,)], [], in_process_limit=0) == [(2,)]
    assert minimise([(L(0, 0.0, True),)], Variables([(L(0, 0.0, True),)]),
                    in_process_limit=0) == [(L(0, 0.0, True),)]
    assert minimise([(L(0, 0.0, True),)], Variables([(L(0, 0.0, True),)]), timeout=7.0,
                    in_process_limit=0) == [(L(0, 0.0, True),)]
    assert fake.waits == [30.0, 30.0, 7.0]


# ----------------------------------------------------------------------- literals and terms
def test_a_literal_tests_one_feature_each_way_and_negates():
    x = np.array([[0.0, 0.5], [0.0, 0.7], [0.0, 0.2]], dtype=np.float32)
    le, gt = L(1, 0.5, True), L(1, 0.5, False)
    assert le.op == "<=" and gt.op == ">"
    assert le.holds(x).tolist() == [True, False, True]
    assert gt.holds(x).tolist() == [False, True, False]
    assert le.negated() == gt and gt.negated() == le


def test_a_literal_compares_the_float32_observation_widened():
    # 0.1 as float32 is above the double 0.1: x <= 0.1 fails on the float32 value
    x = np.array([[0.1]], dtype=np.float64)
    assert not L(0, 0.1, True).holds(x)[0]
    assert L(0, float(np.float32(0.1)), True).holds(x)[0]


def test_terms_and_dnfs_hold_on_batches_and_on_one_state():
    terms = [(L(0, 0.0, True), L(1, 0.0, True)), (L(0, 1.0, False),)]
    x = np.array([[-1, -1], [-1, 1], [2, 0], [0.5, -1]], dtype=np.float32)
    assert term_holds(terms[0], x).tolist() == [True, False, False, False]
    assert term_holds((), x).tolist() == [True] * 4  # the empty term: always true
    assert dnf_holds(terms, x).tolist() == [True, False, True, False]
    assert dnf_holds([], x).tolist() == [False] * 4  # no term: never
    assert dnf_holds(terms, np.array([2.0, 0.0], dtype=np.float32)).tolist() == [True]
    assert literal_count(terms) == 3 and literal_count([]) == 0


def test_merge_thresholds_sorts_by_feature_then_direction():
    term = (L(2, 0.0, False), L(1, 1.0, False), L(1, 3.0, True), L(0, 9.0, False),
            L(1, 2.0, True), L(1, 0.5, False))
    assert merge_thresholds(term) == (L(0, 9.0, False), L(1, 2.0, True), L(1, 1.0, False),
                                      L(2, 0.0, False))
    assert merge_thresholds(()) == ()


def test_leaf_paths_carry_the_leaf_s_action_and_training_samples():
    tree, x = fit_tree(leaves=6, n_actions=3)
    paths = leaf_paths(tree)
    leaf_of = tree.apply(x)
    assert sum(p.samples for p in paths) == len(x)
    for path in paths:
        inside = term_holds(path.term, x)
        assert path.samples == inside.sum()
        assert set(tree.predict(x[inside])) == {path.action}
        assert len(set(leaf_of[inside])) == 1
    assert paths[0].term[0].le  # the left branch first: root-to-leaf, <= before >


def test_the_atl_is_sorted_by_action_and_maps_actions_to_their_leaves():
    tree, _ = fit_tree(leaves=8, n_actions=3, seed=1)
    atl = action_template_library(tree)
    assert list(atl) == sorted(atl) and set(atl) <= {0, 1, 2}
    for action, terms in atl.items():
        assert terms == [p.term for p in leaf_paths(tree) if p.action == action]


def test_the_atl_maps_class_labels_not_class_indices():
    from sklearn.tree import DecisionTreeClassifier

    x = np.array([[0.0], [1.0], [2.0], [3.0]], dtype=np.float32)
    tree = DecisionTreeClassifier(random_state=0).fit(x, [5, 5, 7, 7])
    atl = action_template_library(tree)
    assert set(atl) == {5, 7} and atl[5] == [(L(0, float(tree.tree_.threshold[0]), True),)]


def test_leaf_witnesses_lie_inside_their_leaves_and_on_their_boundaries():
    tree, _ = fit_tree(leaves=10)
    paths = leaf_paths(tree)
    low, high = np.full(4, -1.0), np.full(4, np.inf)
    points = leaf_witnesses(tree, low, high)
    assert points.dtype == np.float32
    assert len(points) == sum(1 + 2 * len(p.term) for p in paths)
    at = 0
    for path in paths:
        assert term_holds(path.term, points[at:at + 1])[0]  # the inside point
        assert np.all(points[at] >= -1.0)  # within the finite bound
        for k, lit in enumerate(path.term):
            edge, nudged = points[at + 1 + 2 * k], points[at + 2 + 2 * k]
            assert edge[lit.feature] == np.float32(lit.threshold)
            assert nudged[lit.feature] == np.nextafter(np.float32(lit.threshold),
                                                       np.float32(np.inf))
        at += 1 + 2 * len(path.term)


def test_a_witness_is_the_midpoint_of_two_bounds_and_one_inside_a_single_bound():
    from sklearn.tree import DecisionTreeClassifier

    x = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]], dtype=np.float32)
    tree = DecisionTreeClassifier(random_state=0).fit(x, [0, 1, 1, 2])
    t = sorted(float(v) for v in tree.tree_.threshold if v != -2)
    assert len(t) == 2  # feature 0 only: three leaves
    points = leaf_witnesses(tree, np.array([-np.inf, -5.0]), np.array([np.inf, 5.0]))
    firsts, at = [], 0
    for path in leaf_paths(tree):
        firsts.append(points[at])
        at += 1 + 2 * len(path.term)
    assert sorted(float(p[0]) for p in firsts) == pytest.approx(
        [t[0] - 1.0, (t[0] + t[1]) / 2, t[1] + 1.0])
    assert all(p[1] == 0.0 for p in firsts)  # (-5 + 5) / 2: no test on it
    low_only = leaf_witnesses(tree, np.array([-np.inf, 4.0]), np.array([np.inf, np.inf]))
    assert low_only[0][1] == 5.0  # one above its only bound
    high_only = leaf_witnesses(tree, np.array([-np.inf, -np.inf]), np.array([np.inf, 4.0]))
    assert high_only[0][1] == 3.0  # one below
    free = leaf_witnesses(tree, np.array([-np.inf, -np.inf]), np.array([np.inf, np.inf]))
    assert free[0][1] == 0.0
