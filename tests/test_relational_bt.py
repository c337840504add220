"""Relational conditions (issue 26, part A): the BT model and JSON, the executors, the coverage
proof, synthesis of relational trees by every synthesiser, verification on polytopes, drawings
and BehaviorTree.CPP export."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from ibt.bt.executors import py_trees_decide, tick, to_py_trees
from ibt.bt.json_io import load_json
from ibt.bt.linear import DEFAULT_WEIGHTS, FeatureMap, LinearForm, exact_threshold
from ibt.bt.model import (
    Action,
    BehaviorTree,
    Condition,
    Fallback,
    Inverter,
    Node,
    Selector,
    Sequence,
    iterate,
    relational_tests,
)
from ibt.bt.polytope import bt_regions, crossing_rows, find_state
from ibt.distill.relational import RelationalTreeClassifier
from ibt.evaluate.speed import compile_python
from ibt.export.btcpp import from_btcpp_xml, to_btcpp_xml
from ibt.paths import DATA_DIR
from ibt.synth.decision_list import decision_list_bt
from ibt.synth.imitation import NotEquivalentError, imitation_bt, rules_frame, verify
from ibt.synth.registry import SYNTHESISERS
from ibt.synth.relational import augmented_task, verification_states
from tests.fixtures.relational_line import LINE

DIFF = LinearForm(0, 2, 1.0, -1.0)  # x - target


def fit_relational(seed: int = 0, leaves: int = 10, n_actions: int = 3, n_forms: int = 3,
                   n: int = 1500) -> RelationalTreeClassifier:
    """A relational tree on a random feature map, fitted to labels that follow linear forms."""
    rng = np.random.default_rng(seed)
    pairs = [(i, j) for i in range(3) for j in range(3) if i < j]
    forms = []
    for _ in range(n_forms):
        i, j = pairs[int(rng.integers(len(pairs)))]
        w1, w2 = DEFAULT_WEIGHTS[int(rng.integers(len(DEFAULT_WEIGHTS)))]
        form = LinearForm(i, j, w1, w2)
        if form not in forms:
            forms.append(form)
    fm = FeatureMap(3, tuple(forms))
    x = LINE.sample_features(n, rng)
    score = forms[0].value(x.astype(np.float64))  # the first form decides most labels
    for form in forms[1:]:
        score += 0.3 * rng.normal() * form.value(x.astype(np.float64))
    score += 0.2 * np.sin(3 * x[:, 0])
    y = np.digitize(score, np.quantile(score, np.linspace(0, 1, n_actions + 1)[1:-1]))
    return RelationalTreeClassifier(max_leaf_nodes=leaves, random_state=seed).fit_relational(
        x, y, fm)


def line_bt(root: Node) -> BehaviorTree:
    return BehaviorTree(root, LINE.feature_names, LINE.action_names)


def go_to_target() -> BehaviorTree:
    """The issue's three-rule policy: right below target - 0.5, left above target + 0.5."""
    return line_bt(Selector((
        Sequence((Condition.relational(DIFF, "<=", -0.5), Action(2))),
        Sequence((Condition.relational(DIFF, ">", 0.5), Action(0))),
        Action(1))))


# ------------------------------------------------------------------------- model, JSON
def test_a_relational_condition_is_one_condition_node_and_reads_as_written():
    bt = go_to_target()
    assert bt.node_count == 8 and bt.node_types()["condition"] == 2
    assert bt.relational_count == relational_tests(bt.root) == 2
    assert bt.label(bt.root.children[0].children[0]) == "x - target <= -0.5"
    assert Condition.relational(LinearForm(1, 0, 0.5, 2.0), ">", 1).features == (1, 0)
    assert line_bt(Selector((Sequence((Condition(0, "<=", 0.0), Action(0))),
                             Action(1)))).relational_count == 0


def test_json_round_trips_and_names_the_rule():
    bt = go_to_target()
    doc = bt.to_dict()
    condition = doc["root"]["children"][0]["children"][0]
    assert condition == {"type": "condition", "form": {"features": [0, 2],
                                                       "weights": [1.0, -1.0]},
                         "op": "<=", "threshold": -0.5}
    assert "w1 * x[i]" in doc["tick_rule"]
    assert BehaviorTree.from_json(bt.to_json()) == bt


def test_axis_aligned_documents_are_unchanged():
    """Every committed BT reads and writes back byte for byte (its digest is the same); the
    axis-aligned ones (all but Imitation-BT+SR's) still say nothing of forms."""
    paths = sorted(DATA_DIR.glob("trees/*/*/*.json"))
    assert paths
    relational = {p for p in paths if p.stem == "imitation-bt-plus-sr"}
    for path in paths:
        bt = load_json(path)
        assert bt.to_json() + "\n" == path.read_text(), path
        if path in relational:
            continue
        assert bt.relational_count == 0, path
        assert "form" not in bt.to_dict()["tick_rule"]
    assert relational and all(load_json(p).relational_count for p in relational)


def _with_condition(condition: dict) -> str:
    doc = go_to_target().to_dict()
    doc["root"]["children"][0]["children"][0] = condition
    return json.dumps(doc)


@pytest.mark.parametrize(("condition", "message"), [
    ({"type": "condition", "form": {"features": [0, 0], "weights": [1, -1]}, "op": "<=",
      "threshold": 0}, "two different features"),
    ({"type": "condition", "form": {"features": [0, 1], "weights": [0, -1]}, "op": "<=",
      "threshold": 0}, "finite and non-zero"),
    ({"type": "condition", "form": {"features": [0, 1], "weights": ["1", -1]}, "op": "<=",
      "threshold": 0}, "must be a number"),
    ({"type": "condition", "form": {"features": [0, 1], "weights": [1e300, -1]}, "op": "<=",
      "threshold": 0}, "too large"),
    ({"type": "condition", "form": {"features": [0, 1.5], "weights": [1, -1]}, "op": "<=",
      "threshold": 0}, "integer index"),
    ({"type": "condition", "form": {"features": [0, 1]}, "op": "<=", "threshold": 0},
     "features.*weights"),
    ({"type": "condition", "form": {"features": [0, 1, 2], "weights": [1, 1, 1]}, "op": "<=",
      "threshold": 0}, "ibt-behavior-tree/2"),
    ({"type": "condition", "form": {"features": [0, 7], "weights": [1, -1]}, "op": "<=",
      "threshold": 0}, "feature 7"),
    ({"type": "condition", "feature": 0, "form": {"features": [0, 1], "weights": [1, -1]},
      "op": "<=", "threshold": 0}, "not both"),
    ({"type": "condition", "form": {"features": [0, 1], "weights": [1, -1]}, "op": "<",
      "threshold": 0}, "op must be"),
    ({"type": "condition", "form": [0, 1], "op": "<=", "threshold": 0}, "linear form must"),
])
def test_bad_forms_are_refused_with_a_clear_error(condition, message):
    with pytest.raises(ValueError, match=message):
        BehaviorTree.from_json(_with_condition(condition))


def test_bad_forms_in_a_file_exit_2_from_the_cli(tmp_path):
    from ibt.cli import main

    path = tmp_path / "bt.json"
    path.write_text(_with_condition({"type": "condition", "form": {
        "features": [0, 0], "weights": [1, -1]}, "op": "<=", "threshold": 0}))
    assert main(["export", str(path), "--format", "btcpp-xml", "-o",
                 str(tmp_path / "bt.xml")]) == 2
    assert not (tmp_path / "bt.xml").exists()


def test_a_relational_feature_must_be_its_forms_first():
    with pytest.raises(ValueError, match=r"Condition\.relational"):
        Condition(1, "<=", 0.0, DIFF)


# --------------------------------------------------------------------------- executors
def test_the_executors_agree_with_the_floating_point_rule():
    bt = go_to_target()
    rng = np.random.default_rng(0)
    states = LINE.sample_features(500, rng)
    x = states.astype(np.float64)
    z = x[:, 0] - x[:, 2]
    want = np.where(z <= -0.5, 2, np.where(z > 0.5, 0, 1))
    assert np.array_equal(bt.decide(states), want)
    assert [tick(bt, s)[0] for s in states[:50]] == want[:50].tolist()
    root, io = to_py_trees(bt)
    assert np.array_equal(py_trees_decide(root, io, states[:50]), want[:50])
    compiled = compile_python(bt)
    assert [compiled(s.tolist()) for s in x[:50]] == want[:50].tolist()


def test_tick_traces_label_the_form():
    _, trace = tick(go_to_target(), np.array([0.0, 0.0, 1.0], dtype=np.float32))
    assert trace[2].label == "x - target <= -0.5" and trace[2].success


# ----------------------------------------------------------------------- the coverage proof
def test_guards_that_cover_every_state_on_one_form_are_proved():
    """No default action: the guards of one form cover the line (the baselines' shape)."""
    bt = line_bt(Selector((Sequence((Condition.relational(DIFF, "<=", -0.5), Action(2))),
                           Sequence((Inverter(Condition.relational(DIFF, "<=", -0.5)),
                                     Condition(1, "<=", 0.0), Action(1))),
                           Sequence((Condition.relational(DIFF, ">", -0.5),
                                     Condition(1, ">", 0.0), Action(0))))))
    bt.validate()
    assert BehaviorTree.from_json(bt.to_json()) == bt


def test_a_gap_between_relational_guards_is_found_with_a_state():
    bt = line_bt(Selector((Sequence((Condition.relational(DIFF, "<=", -0.5), Action(2))),
                           Sequence((Condition.relational(DIFF, ">", 0.5), Action(0))))))
    with pytest.raises(ValueError, match="no action is reached on some states"):
        bt.validate()


def test_guards_that_cover_only_geometrically_are_refused_not_trusted():
    """``x - target <= 0`` or ``target - x <= 0`` covers every state, but the proof treats
    forms as free values: it refuses, saying that it could not prove it (sound)."""
    other = LinearForm(2, 0, 1.0, -1.0)
    bt = line_bt(Selector((Sequence((Condition.relational(DIFF, "<=", 0.0), Action(2))),
                           Sequence((Condition.relational(other, "<=", 0.0), Action(0))))))
    with pytest.raises(ValueError, match="cannot prove"):
        bt.validate()


# ------------------------------------------------------------------- polytope states
def test_find_state_lands_strictly_inside_a_polytope():
    tests = [(DIFF, 0.25, False), (DIFF, 0.3, True), (0, 1.5, True), (1, 0.0, False)]
    state = find_state(3, tests, LINE.low, LINE.high)
    assert state is not None
    x = state.astype(np.float64)
    assert 0.25 < x[0] - x[2] <= 0.3 and x[0] <= 1.5 and x[1] > 0
    assert (x >= LINE.low).all() and (x <= LINE.high).all()
    assert find_state(3, [(DIFF, 0.3, False), (DIFF, 0.25, True)], LINE.low, LINE.high) is None


def test_crossing_rows_are_the_last_state_on_each_side():
    base = np.array([0.3, 0.0, 0.1], dtype=np.float32)
    t = 0.1234567
    rows = crossing_rows(DIFF, t, base)
    assert len(rows) == 4
    for inside, outside in (rows[:2], rows[2:]):
        assert DIFF.value(inside.astype(np.float64)) <= t < DIFF.value(
            outside.astype(np.float64))
        moved = np.flatnonzero(inside != outside)
        assert len(moved) == 1  # neighbouring float32 values of one feature
        assert np.nextafter(inside[moved], outside[moved]) == outside[moved]


def test_bt_regions_partition_the_go_to_target_policy():
    regions = bt_regions(go_to_target())
    assert sorted(action for _, action in regions) == [0, 1, 2]


# ----------------------------------------------------------------- synthesis and checks
@pytest.mark.parametrize("method", list(SYNTHESISERS))
def test_every_synthesiser_takes_a_relational_tree(method):
    tree = fit_relational(seed=3)
    assert (tree.tree_.feature >= 3).any()  # the tree does split on derived columns
    result = SYNTHESISERS[method](tree, LINE)
    bt = result.bt
    assert bt.feature_names == LINE.feature_names and bt.relational_count > 0
    assert result.feature_map == tree.feature_map_
    for node in iterate(bt.root):
        if isinstance(node, Condition):
            assert max(node.features) < 3
    assert verify(bt, tree, LINE) > 20_000
    states = LINE.sample_features(3000, np.random.default_rng(1))
    assert np.array_equal(bt.decide(states), tree.predict(states))
    assert BehaviorTree.from_json(bt.to_json()) == bt  # and its coverage is proved


def test_a_users_synthesiser_takes_relational_trees_through_the_registry():
    """A synthesiser registered by a user (no ``check`` option, knows nothing of forms) gets
    the augmented view; the registry rewrites and verifies its BT in observed space."""
    from ibt.synth.registry import Synthesiser

    toy = Synthesiser("toy-tree-shaped", "tests.fixtures.toy_synthesiser:tree_shaped_bt")
    tree = fit_relational(seed=3)
    result = toy(tree, LINE)
    assert result.bt.relational_count > 0 and result.feature_map == tree.feature_map_
    assert verify(result.bt, tree, LINE) > 20_000


def test_relational_thresholds_are_exact_thresholds_of_the_tree():
    tree = fit_relational(seed=4)
    bt = imitation_bt(tree, LINE).bt
    derived = {exact_threshold(t) for f, t in zip(tree.tree_.feature, tree.tree_.threshold,
                                                    strict=True) if f >= 3}
    assert {n.threshold for n in iterate(bt.root)
            if isinstance(n, Condition) and n.form is not None} <= derived


def test_dont_cares_and_rule_tables_work_on_relational_trees():
    tree = fit_relational(seed=5, leaves=14)
    plain, with_dc = imitation_bt(tree, LINE), imitation_bt(tree, LINE, dont_cares=True)
    assert with_dc.bt.node_count <= plain.bt.node_count
    table = rules_frame(with_dc)
    assert table["rule"].str.contains(" - | \\+ ").any()  # derived columns named as forms


def test_the_verifier_finds_a_state_in_every_region_and_both_sides_of_every_test():
    tree = fit_relational(seed=6, leaves=12)
    check = verification_states(tree, LINE, n_random=1000)
    assert check.regions == tree.get_n_leaves()
    assert check.regions_found == check.regions  # every leaf holds training samples
    leaves = tree.apply(check.states)
    assert len(set(leaves.tolist())) == check.regions  # every leaf is reached
    assert check.boundary_states >= 2 * tree.get_depth()
    assert check.random_states == 1000


def test_the_verifier_catches_a_threshold_off_by_a_few_ulps_and_a_flipped_test():
    tree = fit_relational(seed=7)
    bt = decision_list_bt(tree, LINE).bt

    def moved(node: Node, how: str) -> Node:
        if isinstance(node, Condition) and node.form is not None:
            if how == "shift":
                return dataclasses.replace(node, threshold=node.threshold
                                           + 1e-6 * max(1.0, abs(node.threshold)))
            return dataclasses.replace(node, op=">" if node.op == "<=" else "<=")
        if isinstance(node, Inverter):
            return Inverter(moved(node.child, how))
        if isinstance(node, Fallback | Sequence):
            return type(node)(tuple(moved(c, how) for c in node.children))
        return node

    for how in ("shift", "flip"):
        with pytest.raises(NotEquivalentError, match="relational tree"):
            verify(dataclasses.replace(bt, root=moved(bt.root, how)), tree, LINE)


def test_augmented_task_bounds_every_derived_column():
    tree = fit_relational(seed=8)
    task = augmented_task(LINE, tree.feature_map_)
    x = LINE.sample_features(2000, np.random.default_rng(0))
    z = tree.feature_map_.augment(x)
    assert (z >= np.asarray(task.low) - 1e-9).all() and (z <= np.asarray(task.high) + 1e-9).all()
    with pytest.raises(ValueError, match="feature map reads"):
        augmented_task(dataclasses.replace(LINE, feature_names=("a", "b"), low=(0, 0),
                                           high=(1, 1)), tree.feature_map_)


# -------------------------------------------------------------------- drawings and XML
def test_drawings_print_forms_as_a_reader_writes_them():
    from ibt.export.drawing import decision_tree_graphviz, to_graphviz

    source = to_graphviz(go_to_target()).source
    assert "x - target &lt;= -0.5" in source or "x - target <= -0.5" in source
    tree = fit_relational(seed=3)
    source = decision_tree_graphviz(tree, LINE.feature_names, LINE.action_names).source
    assert any(text in source for text in (" - ", " + "))


def test_btcpp_xml_writes_the_exact_script_and_reads_it_back():
    bt = go_to_target()
    xml = to_btcpp_xml(bt)
    assert 'code="1.0 * x + -1.0 * target &lt;= -0.5"' in xml
    assert 'name="x - target &lt;= -0.5"' in xml
    assert from_btcpp_xml(xml, LINE.feature_names, LINE.action_names) == bt
    with pytest.raises(ValueError, match="portable"):
        to_btcpp_xml(bt, flavour="check-feature")
    bad = xml.replace("* target", "* nowhere")
    with pytest.raises(ValueError, match="nowhere"):
        from_btcpp_xml(bad, LINE.feature_names, LINE.action_names)


def test_escaping_of_odd_feature_names_in_relational_labels():
    bt = BehaviorTree(go_to_target().root, ("x<&>", "v", 't"'), LINE.action_names)
    xml = to_btcpp_xml(bt)
    assert from_btcpp_xml(xml, bt.feature_names, bt.action_names).root == bt.root
    from ibt.export.drawing import to_graphviz

    assert "x<&>" not in to_graphviz(bt).source


@pytest.mark.parametrize("method", ["decision-list", "bt-espresso"])
def test_the_engine_agrees_on_regions_both_sides_of_every_test_and_random_states(method):
    from ibt.export.agreement import agreement_states
    from ibt.export.engine import load_engine_tree

    tree = fit_relational(seed=3, leaves=8)
    bt = SYNTHESISERS[method](tree, LINE).bt
    engine = load_engine_tree(to_btcpp_xml(bt), LINE, source=method)
    assert engine.bt.root == bt.root
    check = verification_states(tree, LINE, n_random=10_000)
    assert check.regions_found == check.regions and check.boundary_states > 0
    for states in (check.states, agreement_states(bt, LINE, n_random=2000)):
        assert np.array_equal(engine.decide(states), bt.decide(states))
    assert np.array_equal(bt.decide(check.states), tree.predict(check.states))


# --------------------------------------------------------------------- the property
@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 5_000), leaves=st.integers(2, 24), n_actions=st.integers(2, 3),
       n_forms=st.integers(1, 4), dont_cares=st.booleans())
def test_a_synthesised_bt_decides_as_its_random_relational_tree(seed, leaves, n_actions,
                                                                  n_forms, dont_cares):
    tree = fit_relational(seed=seed, leaves=leaves, n_actions=n_actions, n_forms=n_forms,
                          n=600)
    """Law: every registered synthesiser's BT of a random relational tree decides as the tree
    on one state in every region, both sides of every test and random states, and provably
    reaches an action on every state."""
    states = verification_states(tree, LINE, n_random=2000, seed=seed).states
    results = [imitation_bt(tree, LINE, dont_cares=dont_cares, check=False),
               *(synthesiser(tree, LINE, check=False) for synthesiser in SYNTHESISERS.values())]
    for result in results:
        assert np.array_equal(result.bt.decide(states), tree.predict(states))
        result.bt.validate()



@settings(max_examples=60, deadline=None)
@given(w1=st.one_of(st.sampled_from([1.0, -1.0, 0.5, -0.5, 2.0, 0.1, -0.3]),
                    st.floats(-100, 100, allow_nan=False).filter(lambda w: abs(w) > 1e-3)),
       w2=st.sampled_from([1.0, -1.0, 0.5, -2.0, 0.7]),
       threshold=st.floats(-5, 5, allow_nan=False),
       base=st.lists(st.floats(-3, 3, allow_nan=False, width=32), min_size=3, max_size=3),
       op=st.sampled_from(["<=", ">"]))
@example(w1=0.5, w2=1.0, threshold=-2.2250738585e-313, base=[0.0, 0.0, 0.0], op="<=")
def test_a_relational_script_condition_computes_exactly_as_ibt(w1, w2, threshold, base, op):
    """Law: the engine's ``w1 * x + w2 * target op T`` decides as ibt's floating-point rule
    on the last float32 states on each side of the threshold and on others; the XML reads
    back to the same BT (a subnormal threshold, which the engine's parser rejects, is written
    with both sides scaled by a power of two)."""
    from ibt.export.btcpp import from_btcpp_xml
    from ibt.export.engine import EngineTree

    form = LinearForm(0, 2, w1, w2)
    bt = line_bt(Selector((Sequence((Condition.relational(form, op, threshold), Action(0))),
                           Action(1))))
    xml = to_btcpp_xml(bt)
    assert from_btcpp_xml(xml, LINE.feature_names, LINE.action_names).root == bt.root
    engine = EngineTree(xml, LINE.feature_names, LINE.action_names)
    row = np.asarray(base, dtype=np.float32)
    states = np.asarray([row, *crossing_rows(form, threshold, row)], dtype=np.float32)
    assert np.array_equal(engine.decide(states), bt.decide(states))


def test_the_coverage_proof_decides_a_large_relational_baseline_bt():
    """RE:BT-Espresso has no default action, so reading its BT back needs the proof over every
    derived value: 100 leaves over LunarLander's 280 pair forms (the original split order gives
    up after 200,000 regions; the shared-bound order decides in well under a second)."""
    from ibt.synth.baselines import re_bt_espresso
    from ibt.tasks.catalogue import get_task

    task = get_task("LunarLander-v3")
    x = task.sample_features(5000, np.random.default_rng(0))
    z = x.astype(np.float64)
    score = 0.5 * z[:, 0] + z[:, 2] - z[:, 4] + 0.3 * np.sin(3 * z[:, 1])
    y = np.digitize(score, np.quantile(score, [0.25, 0.5, 0.75]))
    tree = RelationalTreeClassifier(max_leaf_nodes=100, random_state=0).fit_relational(
        x, y, FeatureMap.pairs(task.n_features))
    bt = re_bt_espresso(tree, task).bt
    assert bt.relational_count > 100
    assert BehaviorTree.from_json(bt.to_json()) == bt
