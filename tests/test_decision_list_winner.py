"""How the decision-list synthesis (:func:`ibt.synth.decision_list.decision_list_bt`) picks and
reports its winner, in seconds: the smallest candidate, the earliest of equals; the winner's own
default action and rule sets; the task's features; the check when asked only; the 60 s safety
net, read off a stand-in clock."""

from __future__ import annotations

import types

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sklearn.tree import DecisionTreeClassifier

import ibt.synth.decision_list as dl
from ibt.bt.model import Action, Selector
from ibt.synth.decision_list import decision_list_bt
from ibt.synth.imitation import imitation_bt, verify
from ibt.tasks.catalogue import Task

N_FEATURES = 4
TOY = Task(name="toy", gym_id="none", feature_names=tuple(f"f{i}" for i in range(N_FEATURES)),
           action_names=tuple(f"a{i}" for i in range(5)), low=(-1,) * N_FEATURES,
           high=(1,) * N_FEATURES)
FAST = {"max_work": 50_000}


def tree_of(seed: int, leaves: int, n_actions: int) -> DecisionTreeClassifier:
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1, 1, size=(800, N_FEATURES)).astype(np.float32)
    score = np.sin(3 * x[:, 0]) + x[:, 1] * x[:, 2] + 0.3 * x[:, 3]
    y = np.digitize(score, np.quantile(score, np.linspace(0, 1, n_actions + 1)[1:-1]))
    return DecisionTreeClassifier(max_leaf_nodes=leaves, random_state=seed).fit(x, y)


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), leaves=st.integers(2, 16), n_actions=st.integers(2, 4))
def test_the_smallest_candidate_wins_with_its_own_default_and_rule_sets(seed, leaves,
                                                                         n_actions):
    """Law: the BT is the smallest candidate; its root Selector ends with the default action;
    a decision list's rule sets are its entries (the default's last rule the empty term),
    Imitation-BT's are Imitation-BT's."""
    tree = tree_of(seed, leaves, n_actions)
    result = decision_list_bt(tree, TOY, **FAST)
    search = result.search
    assert result.bt.node_count == search["candidates"][search["winner"]]
    assert result.bt.node_count == min(search["candidates"].values())
    assert result.bt.root.children[-1] == Action(result.default_action)
    if search["winner"] == "imitation-bt":
        paper = imitation_bt(tree, TOY)
        assert (result.rule_sets, result.default_action) == (paper.rule_sets,
                                                             paper.default_action)
    else:
        default = [rs for rs in result.rule_sets if rs.action == result.default_action]
        assert len(default) == 1 and default[0].terms[-1] == ()
        assert all(() not in rs.terms for rs in result.rule_sets
                   if rs.action != result.default_action)


def test_the_earliest_of_equally_small_candidates_wins():
    """One split: every candidate is ``Selector(Sequence(c, a), b)``, so the first,
    the tree-shaped list, wins; one leaf: the tree-shaped list ties Imitation-BT's."""
    one_split = tree_of(0, 2, 2)
    result = decision_list_bt(one_split, TOY)
    assert set(result.search["candidates"].values()) == {5}
    assert len(result.search["candidates"]) > 2
    assert result.search["winner"] == "tree-shaped"
    single = DecisionTreeClassifier().fit(np.zeros((4, N_FEATURES)), np.full(4, 3))
    result = decision_list_bt(single, TOY)
    assert result.search["candidates"] == {"tree-shaped": 2, "imitation-bt": 2}
    assert result.search["winner"] == "tree-shaped" and result.bt.root == Selector((Action(3),))
    assert result.rule_sets[-1].terms == ((),)


def test_a_tree_testing_a_feature_beyond_the_task_is_refused_from_the_first_one_over():
    tree = tree_of(1, 10, 3)
    tested = int(tree.tree_.feature.max())
    for n in (tested, tested + 1):
        task = Task(name="narrow", gym_id="none", feature_names=TOY.feature_names[:n],
                    action_names=TOY.action_names, low=TOY.low[:n], high=TOY.high[:n])
        if n == tested:
            with pytest.raises(ValueError, match=f"tests feature {tested}, but task narrow "
                                                 f"has {n} features"):
                decision_list_bt(tree, task)
        else:
            assert verify(decision_list_bt(tree, task).bt, tree, task) > 0


def test_the_bt_is_checked_against_its_tree_when_asked_and_only_then(monkeypatch):
    calls = []
    monkeypatch.setattr(dl, "verify", lambda bt, tree, task, seed: calls.append(seed))
    tree = tree_of(2, 6, 3)
    decision_list_bt(tree, TOY, check=False)
    assert calls == []
    decision_list_bt(tree, TOY, rng_seed=7)
    assert calls == [7]


class _Clock:
    """``time.monotonic`` reading 0 s first (the search's start), then ``later`` s."""

    def __init__(self, later: float) -> None:
        self.readings = 0
        self.later = later

    def monotonic(self) -> float:
        self.readings += 1
        return 0.0 if self.readings == 1 else self.later


def _on_clock(monkeypatch: pytest.MonkeyPatch, later: float) -> None:
    from ibt.synth import decision_list_exact, decision_list_factoring, decision_list_search

    clock = types.SimpleNamespace(monotonic=_Clock(later).monotonic)
    for module in (dl, decision_list_exact, decision_list_factoring, decision_list_search):
        monkeypatch.setattr(module, "time", clock)


def test_the_default_safety_net_is_sixty_seconds_and_its_result_is_still_exact(monkeypatch):
    """At 60 s the search goes on (the net bites past its limit); at 60.5 s it stops, warns
    (naming the caller's line) and returns the tree-shaped list, still exact."""
    tree = tree_of(3, 12, 3)
    import warnings

    _on_clock(monkeypatch, 60.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        full = decision_list_bt(tree, TOY)
    assert not full.search["stopped_by_time_limit"] and "imitation-bt" in full.search[
        "candidates"]
    _on_clock(monkeypatch, 60.5)
    with pytest.warns(UserWarning, match="stopped at its 60 s safety net") as caught:
        late = decision_list_bt(tree, TOY)
    assert caught[0].filename == __file__
    assert late.search["stopped_by_time_limit"] and late.search["winner"] == "tree-shaped"
    assert list(late.search["candidates"]) == ["tree-shaped"]
    assert verify(late.bt, tree, TOY) > 0
