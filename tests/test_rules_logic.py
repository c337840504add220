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
