"""The widgets' callbacks and wiring, without a browser (the browser test is test_browser.py)."""

from __future__ import annotations

import json
import re

import nbformat
import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ibt.bt.json_io import load_json
from ibt.bt.model import Action, BehaviorTree, Condition, Selector, Sequence
from ibt.paths import DATA_DIR
from ibt.tasks.catalogue import get_task
from ibt.views import widgets

CARTPOLE_BT = DATA_DIR / "trees" / "CartPole-v1" / "ppo" / "imitation-bt.json"
AXES = ("pole_angle", "pole_angular_velocity")


@pytest.fixture(scope="module")
def cartpole_bt() -> BehaviorTree:
    return load_json(CARTPOLE_BT)


def small_bt() -> BehaviorTree:
    """push_left when x0 <= 0.5 and x1 > 0, else push_right."""
    root = Selector((Sequence((Condition(0, "<=", 0.5), Condition(1, ">", 0.0), Action(0))),
                     Action(1)))
    return BehaviorTree(root, ("x0", "x1"), ("push_left", "push_right"))


@pytest.fixture
def batch_env(monkeypatch):
    """No batch-run variables: the mode is decided by the other rules."""
    monkeypatch.delenv("IBT_PROFILE", raising=False)
    monkeypatch.delenv("IBT_STATIC", raising=False)
    return monkeypatch


# ------------------------------------------------------------------------------- the mode
def test_widget_mode_rules(batch_env):
    # Expect: widgets in a plain session; static for the parameter, IBT_STATIC and IBT_PROFILE
    assert widgets.widget_mode(True) == (True, "JupyterLab with ipywidgets")
    assert widgets.widget_mode(False)[0] is False
    batch_env.setenv("IBT_STATIC", "1")
    assert widgets.widget_mode(True) == (False, "IBT_STATIC=1")
    batch_env.delenv("IBT_STATIC")
    batch_env.setenv("IBT_PROFILE", "smoke")
    use, reason = widgets.widget_mode(True)
    assert not use and "IBT_PROFILE=smoke" in reason


# --------------------------------------------------------------------------- trace callback
def test_trace_view_tick_table():
    bt = small_bt()
    # Expect: x0 <= 0.5 and x1 > 0 -> push_left, every node of the first branch ticked
    view = widgets.trace_view(bt, [0.2, 1.0])
    assert view.action == "push_left" and view.decision == 0
    assert list(view.trace.node) == ["Selector", "Sequence", "x0 <= 0.5", "x1 > 0", "push_left"]
    assert set(view.trace.status) == {"SUCCESS"}
    # Expect: x0 > 0.5 -> the sequence fails at its first condition, the default fires
    view = widgets.trace_view(bt, [0.9, 1.0])
    assert view.action == "push_right"
    assert list(zip(view.trace.node, view.trace.status, strict=True)) == [
        ("Selector", "SUCCESS"), ("Sequence", "FAILURE"), ("x0 <= 0.5", "FAILURE"),
        ("push_right", "SUCCESS")]
    # every condition is listed, ticked or not, with whether it holds
    assert view.conditions[["condition", "holds", "ticked"]].values.tolist() == [
        ["x0 <= 0.5", False, True], ["x1 > 0", True, False]]
    assert view.text().splitlines()[-1] == "decision: push_right"


def test_trace_html_carries_the_state_and_colours():
    view = widgets.trace_view(small_bt(), [0.9, -2.0])
    page = view.html()
    assert 'class="ibt-trace"' in page and "decision: push_right" in page
    state = re.search(r'data-state="([^"]+)"', page).group(1).replace("&quot;", '"')
    assert json.loads(state) == [pytest.approx(0.9), -2.0]
    assert "#d7191c" in page and "#1a9641" in page  # a failure and a success


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-1, 1), min_size=4, max_size=4))
def test_trace_view_decides_as_the_bt(fractions):
    # law: the traced tick and the vectorised executor agree on every state of the box
    bt = load_json(CARTPOLE_BT)
    task = get_task("CartPole-v1")
    state = np.asarray(fractions) * np.asarray(task.high)
    view = widgets.trace_view(bt, state)
    assert view.decision == int(bt.decide(state.reshape(1, -1).astype(np.float32))[0])
    ticked = view.conditions[view.conditions.ticked]
    conditions = view.trace[view.trace.node.isin(ticked.condition)]
    assert len(conditions) >= len(ticked)  # every ticked condition appears in the trace


def test_region_grid_holds_the_other_features(cartpole_bt):
    task = get_task("CartPole-v1")
    state = np.array([0.5, -0.2, 0.01, 0.1])
    i, j = (cartpole_bt.feature_names.index(a) for a in AXES)
    extent = (task.low[i], task.high[i], task.low[j], task.high[j])
    grid = widgets.region_grid(cartpole_bt, state, (i, j), extent, n=21)
    assert grid.shape == (21, 21)
    # the grid's centre is the box's centre with the other features at the state's values
    centre = state.copy()
    centre[i], centre[j] = (extent[0] + extent[1]) / 2, (extent[2] + extent[3]) / 2
    assert grid[10, 10] == cartpole_bt.decide(centre.reshape(1, -1).astype(np.float32))[0]
    assert set(np.unique(grid)) <= {0, 1}


def test_region_figure_marks_the_state(cartpole_bt):
    fig = widgets.region_figure(cartpole_bt, "CartPole-v1", [0.0, 0.1, 0.05, -0.2], AXES, n=30)
    ax = fig.axes[0]
    star = ax.lines[0]
    assert (star.get_xdata()[0], star.get_ydata()[0]) == (0.05, -0.2)
    assert ax.get_xlabel() == "pole_angle"
    assert widgets.figure_png(fig).startswith(b"\x89PNG")


# ----------------------------------------------------------------------- the widget wiring
def test_state_explorer_updates_on_a_slider(cartpole_bt):
    explorer = widgets.StateExplorer(cartpole_bt, "CartPole-v1", [0.0, 0.1, 0.02, -0.3], AXES,
                                     n=30)
    first_plot, first_graph = explorer.plot.value, explorer.graph.value
    assert "<svg" in first_graph and explorer.view.action in explorer.trace.value
    for angle in (-0.2, 0.2):
        explorer.sliders["pole_angle"].value = angle  # what the browser's slider does
        expected = widgets.trace_view(cartpole_bt, [0.0, 0.1, angle, -0.3])
        assert explorer.view.text() == expected.text()
        assert f"decision: {expected.action}" in explorer.trace.value
    assert explorer.plot.value != first_plot and explorer.graph.value != first_graph


def test_state_explorer_static_fallback(batch_env, cartpole_bt, capsys):
    shown = []
    batch_env.setattr(widgets, "_display", lambda *objects: shown.extend(objects))
    batch_env.setenv("IBT_PROFILE", "smoke")
    out = widgets.state_explorer(cartpole_bt, "CartPole-v1", [0.0, 0.1, 0.02, -0.3], AXES, n=20)
    assert out is None
    kinds = [type(o).__name__ for o in shown]
    assert kinds == ["Markdown", "DataFrame", "Figure", "InlineDigraph"]  # PNG and SVG
    assert "IBT_PROFILE=smoke" in shown[0].data
    assert "decision: push_" in capsys.readouterr().out
    batch_env.delenv("IBT_PROFILE")
    widget = widgets.state_explorer(cartpole_bt, "CartPole-v1", [0.0, 0.1, 0.02, -0.3], AXES,
                                    n=20)
    assert type(widget).__name__ == "VBox"


def fake_view(schedule: str, leaves: int):
    """A ScheduleView from a small synthetic tree of ``leaves`` leaves."""
    from ibt.synth.imitation import imitation_bt
    from ibt.tasks.catalogue import Task
    from ibt.views.lesson import ScheduleView
    from tests.conftest import fit_tree

    task = Task("Synthetic", "none", ("a", "b", "c", "d"), ("u", "v", "w"), (-1,) * 4, (1,) * 4)
    tree, _ = fit_tree(leaves=leaves)
    bt = imitation_bt(tree, task).bt
    facts = {"schedule": schedule, "leaf limit": leaves, "tree nodes": tree.tree_.node_count,
             "BT nodes": bt.node_count, "BT conditions": bt.node_types()["condition"],
             "mean return": 1.0, "retention_norm %": 50.0, "episodes": 3}
    return ScheduleView(schedule, leaves, tree, bt, facts)


def test_schedule_explorer_recomputes_on_both_controls():
    calls = []

    def compute(schedule, leaves):
        calls.append((schedule, leaves))
        return fake_view(schedule, leaves)

    explorer = widgets.ScheduleExplorer(compute, ["linear", "first_only"], [2, 4, 8], "linear", 4)
    assert calls == [("linear", 4)]
    explorer.leaves.value = 8
    explorer.schedule.value = "first_only"
    assert calls == [("linear", 4), ("linear", 8), ("first_only", 8)]
    view = fake_view("first_only", 8)
    assert f"tree <b>{view.facts['tree nodes']}</b> nodes" in explorer.summary.value
    assert f"BT <b>{view.bt.node_count}</b> nodes" in explorer.summary.value
    assert explorer.tree.value.startswith("<svg") and explorer.bt.value.startswith("<svg")


def test_schedule_explorer_static_fallback(batch_env):
    shown = []
    batch_env.setattr(widgets, "_display", lambda *objects: shown.extend(objects))
    assert widgets.schedule_explorer(fake_view, ["linear"], [4], "linear", 4,
                                     interactive=False) is None
    assert [type(o).__name__ for o in shown] == ["Markdown", "HTML", "InlineDigraph",
                                                    "InlineDigraph"]
    assert "leaf limit" not in shown[1].data and "at most 4 leaves" in shown[1].data


# ------------------------------------------------------------------ the lesson's figures
def test_diff_figure_counts_every_cell():
    from ibt.views.lesson_edits import add_guard, all_states, decision_diff, guard

    bt = load_json(DATA_DIR / "trees" / "PackageDelivery-v0" / "dqn" / "imitation-bt.json")
    edited = add_guard(bt, guard(bt, [["battery", "<=", 4]], "go_charger"))
    diff = decision_diff(bt, edited, all_states("PackageDelivery-v0"))
    fig = widgets.diff_figure(diff, "PackageDelivery-v0", "location", "battery")
    ax = fig.axes[0]
    counted = sum(int(t.get_text()) for t in ax.texts)
    assert counted == len(diff) > 0
    assert [t.get_text() for t in ax.get_yticklabels()] == ["depot", "zone_a", "zone_b",
                                                            "charger"]
    assert len(ax.get_xticklabels()) == 11  # battery 0..10, changed or not


# ------------------------------------------------------------------------ the scrubber
def test_scrub_drops_widget_views_and_state(tmp_path):
    from ibt.notebooks import WIDGET_VIEW, scrub

    nb = nbformat.v4.new_notebook()
    nb.metadata["widgets"] = {"application/vnd.jupyter.widget-state+json": {"state": {}}}
    view = {WIDGET_VIEW: {"model_id": "abc", "version_major": 2}}
    cell = nbformat.v4.new_code_cell("widgets.state_explorer(...)")
    cell.outputs = [
        nbformat.v4.new_output("execute_result", {**view, "text/plain": "VBox(children=(...))"},
                               execution_count=1),
        nbformat.v4.new_output("display_data", {**view, "text/plain": "x",
                                                "text/html": "<b>static</b>"}),
        nbformat.v4.new_output("display_data", {"image/png": "iVBORw0KGgo=",
                                                "text/plain": "<Figure>"}),
    ]
    nb.cells = [cell]
    path = tmp_path / "nb.ipynb"
    nbformat.write(nb, path)
    scrub(path)
    out = nbformat.read(path, as_version=4)
    nbformat.validate(out)
    assert "widgets" not in out.metadata
    outputs = out.cells[0].outputs
    # Expect: the widget-only output gone, the view dropped beside other data, the figure kept
    assert [sorted(o.data) for o in outputs] == [["text/html", "text/plain"],
                                                 ["image/png", "text/plain"]]


def test_iteration_and_shift_figures():
    from sklearn.tree import DecisionTreeClassifier

    from ibt.views.lesson import OpenIteration

    task = get_task("MountainCar-v0")
    rng = np.random.default_rng(0)
    x = rng.uniform(task.low, task.high, size=(9000, 2))
    y = (x[:, 1] > 0).astype(int) * 2
    data = pd.DataFrame(x, columns=list(task.feature_names)).assign(
        expert_action=y, weight=rng.uniform(0, 2, len(x)), draws=rng.poisson(1.0, len(x)))
    steps = data.iloc[:100].assign(tree_action=2, actor=["expert", "tree"] * 50)
    tree = DecisionTreeClassifier(max_leaf_nodes=4, random_state=0).fit(x, y)
    it = OpenIteration(task, "dqn", 0, 5, 10, 0.5, True, steps, data, tree, tree)
    fig = widgets.iteration_figure(it, max_points=3000)
    titles = [ax.get_title() for ax in fig.axes]
    assert "beta = 0.50" in titles[0] and "9,000 states, 1 in 3 shown" in titles[1]
    assert len(fig.axes[1].collections[0].get_offsets()) == 3000  # the thinned labels
    assert fig.axes[2].images[0].get_array().shape == (200, 200)  # the tree's regions
    states = data.assign(driver=["expert", "other"] * 4500)
    fig = widgets.shift_figure(states, ("position", "velocity"))
    assert [ax.get_title() for ax in fig.axes[:2]] == ["expert drives (4,500 states)",
                                                      "other drives (4,500 states)"]
