"""Decision-list synthesis: exact on every state, never larger than Imitation-BT, deterministic,
and inside its time limit on the committed trees."""

from __future__ import annotations

import time
import warnings

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from sklearn.tree import DecisionTreeClassifier

from ibt.bt.executors import decide_batch
from ibt.bt.model import Action, Selector, iterate
from ibt.synth.decision_list import MAX_WORK, METHOD, decision_list_bt, size_table
from ibt.synth.decision_list_exact import decides_like, simplify, term_box
from ibt.synth.decision_list_factoring import Factorer, root_selector
from ibt.synth.decision_list_search import (
    CandidateSearch,
    EspressoBudget,
    Leaf,
    tree_view,
    view_paths,
)
from ibt.synth.imitation import imitation_bt, verify
from ibt.synth.rules import Literal, leaf_witnesses
from ibt.tasks.catalogue import Task

N_FEATURES = 5
TOY = Task(name="toy", gym_id="none", feature_names=tuple(f"f{i}" for i in range(N_FEATURES)),
           action_names=tuple(f"a{i}" for i in range(8)), low=(-1,) * N_FEATURES,
           high=(1,) * N_FEATURES)


def random_tree(seed: int, leaves: int, n_actions: int, n: int = 1500) -> DecisionTreeClassifier:
    """A CART tree on a nonlinear labelling whose labels are ``n_actions`` of the 8 actions
    (not 0..k-1, in shuffled order), with thresholds repeated across features."""
    rng = np.random.default_rng(seed)
    x = rng.uniform(-1, 1, size=(n, N_FEATURES)).astype(np.float32)
    x[:, 3] = np.round(x[:, 3] * 3) / 3  # a coarse feature: many ties, boundary states
    score = np.sin(3 * x[:, 0]) + x[:, 1] * x[:, -1] + 0.5 * x[:, 1] ** 2 + 0.3 * x[:, 3]
    bins = np.digitize(score, np.quantile(score, np.linspace(0, 1, n_actions + 1)[1:-1]))
    labels = rng.permutation(8)[:n_actions]
    return DecisionTreeClassifier(max_leaf_nodes=leaves, random_state=seed).fit(x, labels[bins])


def probe_states(tree: DecisionTreeClassifier, seed: int) -> np.ndarray:
    """Random states plus every leaf's interior, each split value and the float32 above it."""
    rng = np.random.default_rng(seed)
    witnesses = leaf_witnesses(tree, np.full(N_FEATURES, -1.0), np.full(N_FEATURES, 1.0))
    return np.concatenate([rng.uniform(-1.5, 1.5, size=(3000, N_FEATURES)).astype(np.float32),
                           witnesses])


# A reduced work budget keeps the property fast; exactness cannot depend on the budget.
FAST = {"max_work": 100_000}


TREES = {"seed": st.integers(0, 10_000), "leaves": st.integers(2, 64),
         "n_actions": st.integers(2, 8)}


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(**TREES)
def test_decision_list_bt_decides_exactly_as_the_tree(seed, leaves, n_actions):
    check_exact(seed, leaves, n_actions)


@pytest.mark.slow
@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(**TREES)
def test_decision_list_bt_decides_exactly_as_the_tree_many(seed, leaves, n_actions):
    check_exact(seed, leaves, n_actions)


def check_exact(seed: int, leaves: int, n_actions: int) -> None:
    tree = random_tree(seed, leaves, n_actions)
    result = decision_list_bt(tree, TOY, check=False, **FAST)
    states = probe_states(tree, seed)
    # Expect: the BT's decision is the tree's on every probe, boundaries included
    assert np.array_equal(result.bt.decide(states), tree.predict(states))
    verify(result.bt, tree, TOY, seed=seed)
    result.bt.validate()  # and provably every state reaches an action (what loading checks)
    assert result.method == METHOD
    assert isinstance(result.bt.root, Selector)


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 10_000), leaves=st.integers(2, 32), n_actions=st.integers(2, 6))
def test_search_never_returns_more_than_the_papers_ordering(seed, leaves, n_actions):
    tree = random_tree(seed, leaves, n_actions)
    result = decision_list_bt(tree, TOY, **FAST)
    paper = imitation_bt(tree, TOY)
    assert result.bt.node_count <= paper.bt.node_count
    # the decision list in the paper's action order, simplified and factored, is one candidate
    view = tree_view(tree)
    if not isinstance(view, Leaf):
        search = CandidateSearch(view, EspressoBudget(FAST["max_work"], 60))
        boxes = [(term_box(t, N_FEATURES), a) for t, a in search.paths]
        paper_order = simplify(search.paper_order(tree), boxes)
        size = sum(1 for _ in iterate(root_selector(search.factorer(paper_order))))
        assert result.bt.node_count <= size
    assert result.bt.node_count == min(result.search["candidates"].values())


def test_single_leaf_and_relabelled_trees():
    x = np.zeros((10, N_FEATURES), dtype=np.float32)
    single = DecisionTreeClassifier().fit(x, np.full(10, 6))
    result = decision_list_bt(single, TOY)
    # Expect: one action under the root, as Imitation-BT writes it (2 nodes)
    assert result.bt.root == Selector((Action(6),))
    assert result.default_action == 6
    tree = random_tree(3, 12, 3)
    assert set(tree.classes_) != set(range(3))  # labels are not 0..k-1
    assert verify(decision_list_bt(tree, TOY).bt, tree, TOY) > 0


def test_tree_rebuilt_from_arrays_keeps_its_classes():
    """A tree whose arrays were copied into a new estimator (as refinement does)."""
    import copy

    tree = random_tree(5, 10, 4)
    clone = copy.deepcopy(tree)
    clone.classes_ = np.asarray(tree.classes_, dtype=np.float64)  # floats, as some rebuilds do
    result = decision_list_bt(clone, TOY)
    states = probe_states(tree, 5)
    assert np.array_equal(result.bt.decide(states), tree.predict(states))


def test_a_feature_outside_the_task_is_a_clear_error():
    tree = random_tree(1, 8, 2)
    narrow = Task(name="narrow", gym_id="none", feature_names=("f0",),
                  action_names=TOY.action_names, low=(-1,), high=(1,))
    with pytest.raises(ValueError, match="features; synthesise with the task"):
        decision_list_bt(tree, narrow)


def test_same_tree_gives_the_identical_bt_json():
    tree = random_tree(11, 24, 5)
    first = decision_list_bt(tree, TOY, **FAST)
    second = decision_list_bt(tree, TOY, **FAST)
    assert first.bt.to_json() == second.bt.to_json()
    assert first.search == second.search


def test_decides_like_is_exact_where_sampling_is_not():
    # Expect: a list that errs only on the float32 value just above a threshold is caught
    leaves = [(term_box((Literal(0, 0.5, True),), 2), 0),
              (term_box((Literal(0, 0.5, False),), 2), 1)]
    exact = [((Literal(0, 0.5, True),), 0), ((), 1)]
    off = [((Literal(0, 0.5000001, True),), 0), ((), 1)]
    assert decides_like(exact, leaves)
    assert not decides_like(off, leaves)
    assert not decides_like(exact[:1], leaves)  # no default: states above 0.5 undecided


def test_simplify_and_factoring_keep_every_decision():
    tree = random_tree(7, 30, 4)
    view = tree_view(tree)
    leaves = [(term_box(t, N_FEATURES), a) for t, a in view_paths(view)]
    search = CandidateSearch(view, EspressoBudget(MAX_WORK, 60))
    flat = search.tree_shaped()
    assert decides_like(flat, leaves)
    short = simplify(flat, leaves)
    assert decides_like(short, leaves)
    assert sum(map(len, (t for t, _ in short))) <= sum(map(len, (t for t, _ in flat)))
    root = root_selector(Factorer()(short))
    states = probe_states(tree, 7)
    assert np.array_equal(decide_batch(root, states), tree.predict(states))


def test_size_table_reads_the_synthesis_rows():
    rows = []
    for seed, (ib, dl) in enumerate([((60, 40), (40, 15)), ((64, 42), (44, 17))]):
        for method, (nodes, conditions) in (("imitation-bt", ib), ("decision-list", dl)):
            rows.append({"task": "T", "expert": "dqn", "method": method, "seed": seed,
                         "nodes": nodes, "conditions": conditions, "tree_nodes": 31})
    rows.append({"task": "T", "expert": "dqn", "method": "bt-espresso", "seed": 0, "nodes": 99,
                 "conditions": 50, "tree_nodes": 31})
    table = size_table(pd.DataFrame(rows))
    assert table.loc[0, "tree splits"] == 15 and table.loc[0, "seeds"] == 2
    assert table.loc[0, "Imitation-BT conditions"] == 41
    assert table.loc[0, "decision-list conditions"] == 16
    assert table.loc[0, "nodes / Imitation-BT"] == round(42 / 62, 2)
    assert table.loc[0, "conditions / splits"] == round(16 / 15, 2)


def _committed_tree(task: str, algo: str, seed: int) -> DecisionTreeClassifier:
    import ibt

    cfg = ibt.config("paper", progress=False)  # a cache hit on the committed data/cache
    return ibt.distill_cached(cfg, task, algo, "imitation-bt", seed).best_tree


def _cpu_seconds() -> float:
    """CPU time of this process and its finished children (Espresso may run in a child)."""
    import resource

    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


@pytest.mark.parametrize("task, algo, seed", [("LunarLander-v3", "a2c", 1),
                                              ("PackageDelivery-v0", "ppo", 1)])
def test_time_limit_holds_on_the_largest_committed_trees(task, algo, seed):
    """The slowest committed trees (32 leaves and 4 actions; 8 actions): well inside 10 s of
    one core and inside the work budget, so neither the safety net nor the budget decides."""
    from ibt.tasks.catalogue import get_task

    tree = _committed_tree(task, algo, seed)
    start = _cpu_seconds()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the safety-net warning would fail the test
        result = decision_list_bt(tree, get_task(task), check=False)
    assert _cpu_seconds() - start < 10.0
    assert result.search["work"] < MAX_WORK / 2
    assert not result.search["stopped_by_time_limit"]
    assert result.bt.node_count <= 0.7 * imitation_bt(tree, get_task(task)).bt.node_count


def test_cli_synthesizes_a_decision_list_bt(tmp_path, capsys):
    import ibt
    from ibt.cli import main
    from ibt.distill.tree_file import save_tree_file

    task = ibt.get_task("MountainCar-v0")
    rng = np.random.default_rng(0)
    x = task.sample_features(800, rng)
    y = np.where(x[:, 0] < -0.9, 1, (x[:, 1] > 0).astype(int) * 2)  # left, none, right
    tree = DecisionTreeClassifier(max_leaf_nodes=6, random_state=0).fit(x, y)
    tree_file = save_tree_file(tmp_path / "tree.json", tree, task, {})
    out = tmp_path / "dl.json"
    assert main(["synthesize", str(tree_file), "-o", str(out), "--method", "decision-list"]) == 0
    assert "decision-list:" in capsys.readouterr().out
    bt = ibt.load_json(out)
    assert verify(bt, tree, task) > 0
    assert bt.node_count <= imitation_bt(tree, task).bt.node_count


def _tick_document(node: dict, x: np.ndarray, decided: list[int]) -> bool:
    """The README's ticking rule, on the JSON document alone (no ibt.bt.model): a condition compares
    float64(float32(obs[feature])); the first action ticked is the decision."""
    kind = node["type"]
    if kind == "condition":
        value = float(np.float32(x[node["feature"]]))
        return value <= node["threshold"] if node["op"] == "<=" else value > node["threshold"]
    if kind == "action":
        if not decided:
            decided.append(node["action"])
        return True
    if kind == "inverter":
        return not _tick_document(node["children"][0], x, decided)
    if kind == "sequence":
        return all(_tick_document(child, x, decided) for child in node["children"])
    return any(_tick_document(child, x, decided) for child in node["children"])


def test_committed_decision_list_files_decide_as_their_trees():
    """Every data/trees/<task>/<algo>/decision-list.json, ticked from the file alone, decides as
    its source tree (the seed-best Imitation-BT tree), and its environment rollout returned
    what the tree returned (the synthesis table's matches_tree)."""
    import json

    import ibt
    from ibt.paths import DATA_DIR
    from ibt.synth.imitation import verification_states

    synthesis = pd.read_csv(DATA_DIR / "results" / "synthesis.csv")
    rows = synthesis[(synthesis.method == METHOD) & synthesis.seed_best]
    assert len(rows) and rows.equivalent.all() and rows.matches_tree.all()
    cfg = ibt.config("paper", progress=False)
    for row in rows.itertuples():
        path = DATA_DIR / "trees" / row.task / row.expert / f"{METHOD}.json"
        doc = json.loads(path.read_text())
        task = ibt.get_task(row.task)
        tree = ibt.distill_cached(cfg, row.task, row.expert, "imitation-bt", int(row.seed)
                                  ).best_tree
        states = verification_states(tree, task, n_random=500)
        decisions = []
        for x in states:
            decided: list[int] = []
            _tick_document(doc["root"], x, decided)
            decisions.append(decided[0] if decided else -1)
        assert np.array_equal(decisions, tree.predict(states)), path
        assert doc["root"]["type"] == "selector"
        assert ibt.BehaviorTree.from_dict(doc).node_count == row.nodes
