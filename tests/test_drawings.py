"""Drawings and figures fit a page: every committed PNG is readable at README width, every tree
drawing is at most 3:1, every BT (committed or random) draws readably, traces mark the right
nodes, and the figure fixes hold (intervals never clipped, statuses marked, one scale)."""

from __future__ import annotations

import re
from pathlib import Path

import matplotlib
import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ibt.bt.executors import tick as tick_bt
from ibt.bt.json_io import load_json
from ibt.bt.model import (
    OPS,
    Action,
    BehaviorTree,
    Condition,
    Fallback,
    Inverter,
    Selector,
    Sequence,
)
from ibt.export.drawing import deciding_condition, drawing_elements, require_dot, to_graphviz
from ibt.export.pictures import compose, draw_bt, fit_graphviz, measure_graph, save_drawing
from ibt.export.readable import (
    MAX_ASPECT,
    MIN_TEXT_PT,
    README_WIDTH_PX,
    measure,
    text_pt_at_readme_width,
)
from ibt.paths import DATA_DIR, FIGURES_DIR

matplotlib.use("Agg")
pytestmark = pytest.mark.skipif(not __import__("shutil").which("dot"), reason="needs dot")

TREE_STEM = re.compile(r"(_bt|_trees?|espresso|imitation-bt)$")


def _committed_pngs() -> list[Path]:
    """Every committed figure we draw (the book's screenshots are a browser's rendering of a
    page, shown at their own width, not figures of ours)."""
    return sorted(p for p in FIGURES_DIR.rglob("*.png")
                  if p.relative_to(FIGURES_DIR).parts[0] != "book")


# -------------------------------------------------------------------- the committed figures
def test_text_size_at_readme_width_follows_the_scale():
    # Expect: a PNG no wider than the README shows 12 pt text at 12 pt x dpi/96; a PNG twice
    # as wide as the README shows it at half that
    assert text_pt_at_readme_width(12, 96, README_WIDTH_PX) == 12
    assert text_pt_at_readme_width(12, 96, 2 * README_WIDTH_PX) == 6
    assert text_pt_at_readme_width(12, 144, 400) == 18


@pytest.mark.parametrize("png", _committed_pngs(), ids=lambda p: str(p.relative_to(FIGURES_DIR)))
def test_every_committed_figure_is_readable_at_readme_width(png):
    reading = measure(png)  # an unstamped PNG fails here, naming the fix
    assert reading.problems() == []
    if TREE_STEM.search(png.stem):
        assert reading.kind == "tree", f"{png} is a tree drawing but is stamped {reading.kind}"
        assert reading.aspect <= MAX_ASPECT


def test_the_committed_figures_include_the_tree_drawings():
    stems = {p.stem for p in _committed_pngs()}
    assert {"quickstart_bt", "cliffwalking_trees", "frozenlake_bt", "mountaincar_bt"} <= stems


def test_an_unstamped_png_is_refused(tmp_path):
    from PIL import Image

    Image.new("RGB", (10, 10)).save(tmp_path / "x.png")
    with pytest.raises(ValueError, match="no readability stamp"):
        measure(tmp_path / "x.png")


# ------------------------------------------------------------------------- every BT draws
def _committed_bts() -> list[Path]:
    return sorted((DATA_DIR / "trees").glob("*/*/*.json"))


@pytest.mark.parametrize("path", _committed_bts(),
                         ids=lambda p: "/".join(p.relative_to(DATA_DIR / "trees").parts))
def test_every_committed_bt_draws_readably(path):
    bt = load_json(path)
    graph, _ = fit_graphviz(bt, title=f"{path.parent.parent.name} {path.parent.name}")
    layout = measure_graph(graph)
    assert layout.readable, (layout.width_pt, layout.height_pt, layout.text_pt())
    assert layout.aspect <= MAX_ASPECT and layout.text_pt() >= MIN_TEXT_PT


def _bts(draw_children=True):
    conditions = st.builds(Condition, st.integers(0, 2), st.sampled_from(OPS),
                           st.integers(-500, 500).map(lambda v: v / 100))
    actions = st.builds(Action, st.integers(0, 2))

    def composite(children):
        many = st.lists(children, min_size=1, max_size=6).map(tuple)
        return st.one_of(st.builds(Sequence, many), st.builds(Fallback, many),
                         st.builds(Inverter, children))

    nodes = st.recursive(conditions | actions, composite, max_leaves=40)
    return st.builds(lambda root: BehaviorTree(root, ("speed", "distance", "angle"),
                                               ("brake", "go", "turn")),
                     st.builds(Selector, st.lists(nodes, min_size=1, max_size=10).map(tuple)))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_bts())
def test_any_bt_draws_every_node_readably(bt):
    # Expect: each depth-first position is shown somewhere, and the drawing fits a page
    elements = drawing_elements(bt)
    assert sorted(elements) == list(range(bt.node_count))
    graph, _ = fit_graphviz(bt)
    layout = measure_graph(graph)
    assert layout.aspect <= MAX_ASPECT and layout.text_pt() >= MIN_TEXT_PT


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_bts(), st.lists(st.integers(-6, 6).map(float), min_size=3, max_size=3))
def test_a_trace_marks_exactly_its_ticked_nodes(bt, state):
    _, trace = tick_bt(bt, np.array(state))
    highlight = {s.index: s.success for s in trace}
    source = to_graphviz(bt, highlight, deciding=deciding_condition(bt, trace),
                         legend=False).source
    # every ticked condition row carries its status glyph, nothing else does
    ticked_rows = {s.index for s in trace if isinstance(list(bt.nodes())[s.index], Condition)}
    assert source.count("✓") + source.count("✗") >= len(ticked_rows) - sum(
        isinstance(n, Inverter) for n in bt.nodes())
    assert source.count("◆") == (deciding_condition(bt, trace) is not None)


def test_a_node_object_used_twice_is_drawn_twice():
    shared = Condition(0, "<=", 0.5)
    bt = BehaviorTree(Selector((Sequence((shared, Action(0))), Sequence((shared, Action(1))),
                                Action(2))), ("x",), ("a", "b", "c"))
    elements = drawing_elements(bt)
    assert elements[2] != elements[5]  # positions 2 and 5 hold the one object
    # Expect: x = 0.9 fails the shared condition twice, each row marked on its own
    _, trace = tick_bt(bt, np.array([0.9]))
    source = to_graphviz(bt, {s.index: s.success for s in trace}, legend=False).source
    assert source.count("✗") == 2


def test_deciding_condition_is_the_last_test_before_the_action():
    bt = BehaviorTree(Selector((Sequence((Condition(0, "<=", 0.0), Condition(1, ">", 1.0),
                                          Action(0))), Action(1))), ("x", "y"), ("a", "b"))
    # Expect: (-1, 2) passes both tests, the second decides; (-1, 0) fails the second
    _, trace = tick_bt(bt, np.array([-1.0, 2.0]))
    assert deciding_condition(bt, trace) == 3
    _, trace = tick_bt(bt, np.array([-1.0, 0.0]))
    assert deciding_condition(bt, trace) == 3
    _, trace = tick_bt(bt, np.array([1.0, 0.0]))
    assert deciding_condition(bt, trace) == 2


def test_a_large_bt_is_collapsed_with_every_node_in_the_svg(tmp_path):
    require_dot()
    bt = load_json(DATA_DIR / "trees" / "PackageDelivery-v0" / "ppo" / "imitation-bt.json")
    drawing = draw_bt(bt, tmp_path / "pd", title="PackageDelivery")
    assert drawing.collapsed
    reading = measure(drawing.png)
    assert reading.problems() == [] and reading.kind == "tree"
    svg = drawing.svg.read_text()
    # the SVG holds every condition of the tree, the PNG's title names it
    conditions = {bt.label(n) for n in bt.nodes() if isinstance(n, Condition)}
    import html

    assert all(html.escape(c, quote=False) in svg for c in conditions)


def test_compose_keeps_one_scale(tmp_path):
    small = BehaviorTree(Selector((Action(0),)), ("x",), ("a",))
    big = load_json(DATA_DIR / "trees" / "MountainCar-v0" / "dqn" / "imitation-bt.json")
    a = save_drawing(to_graphviz(small), tmp_path / "a", formats=("png",))[0]
    b = save_drawing(to_graphviz(big), tmp_path / "b", formats=("png",))[0]
    out = compose([a, b], tmp_path / "ab")[0]
    wa, wb, wo = measure(a).width_px, measure(b).width_px, measure(out)
    assert wo.width_px >= max(wa, wb)  # pasted at their own size, never shrunk
    assert wo.problems() == []


# -------------------------------------------------------------------------- figure fixes
def _summary(values, lows, highs, statuses=None):
    rows = []
    for k, (v, lo, hi) in enumerate(zip(values, lows, highs, strict=True)):
        rows.append({"task": f"T{k}", "expert": "dqn", "method": "imitation-bt",
                     "retention_norm": v, "interval_low": lo, "interval_high": hi,
                     "interval": "range over 3 seeds",
                     "expert_status": (statuses or {}).get(k, "ok")})
    return pd.DataFrame(rows)


def test_retention_limits_never_clip_an_interval():
    from ibt.report import plots

    fig = plots.retention_grid(_summary([-15, 90, 130], [-60, 80, 100], [5, 95, 180]))
    low, high = fig.axes[0].get_ylim()
    assert low < -60 and high > 180
    matplotlib.pyplot.close(fig)


def test_excluded_experts_are_marked_and_error_bars_named():
    from ibt.report import plots

    fig = plots.retention_grid(_summary([50, 90], [40, 80], [60, 95], {0: "excluded"}))
    texts = [t.get_text() for t in fig.findobj(matplotlib.text.Text)]
    assert "expert\nexcluded" in texts
    assert any("error bars: range over 3 seeds" in t for t in texts)
    matplotlib.pyplot.close(fig)


def test_unknown_and_new_methods_get_colours():
    from ibt.report import figure_style, plots

    frame = pd.DataFrame({"task": ["T"] * 3, "expert": ["dqn"] * 3,
                          "method": ["decision-list", "imitation-bt+", "brand-new"],
                          "nodes": [5, 7, 9]})
    assert figure_style.methods_in(frame) == ["imitation-bt+", "decision-list", "brand-new"]
    fig = plots.node_counts(frame)
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert labels == ["Imitation-BT+", "decision list", "brand-new"]
    matplotlib.pyplot.close(fig)


def test_saved_figures_are_stamped(tmp_path):
    from ibt.report import plots, task_figures

    fig = task_figures.frozenlake_map(np.full((64, 64, 3), 200, np.uint8), [0, 4, 8])
    png = plots.save_figure(fig, tmp_path / "lake", formats=("png",))[0]
    reading = measure(png)
    assert reading.kind == "plot" and reading.font_pt == 10 and reading.problems() == []
    matplotlib.pyplot.close(fig)


@pytest.mark.parametrize("figure", ["retention_grid", "node_counts"])
def test_status_labels_of_neighbouring_tasks_never_overlap(figure):
    import itertools

    # Expect: eight tasks (the catalogue's count), every other expert marked; no two labels'
    # boxes intersect, and each stays inside its task's band
    from ibt.report import figure_style, plots

    statuses = {k: ("excluded", "constant-action")[k % 2] for k in range(8)}
    frame = _summary([50.0] * 8, [40.0] * 8, [60.0] * 8, statuses)
    if figure == "node_counts":
        frame = frame.rename(columns={"retention_norm": "nodes"})
    fig = getattr(plots, figure)(frame)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    notes = set(figure_style.STATUS_NOTE.values())
    boxes = [t.get_window_extent(renderer) for t in fig.findobj(matplotlib.text.Text)
             if t.get_text() in notes]
    assert len(boxes) == 8
    for a, b in itertools.pairwise(boxes):
        assert a.x1 < b.x0, "status labels overlap"
    ax = fig.axes[0]
    band = ax.transData.transform([(0.52, 0), (1.48, 0)])[:, 0]  # task 1's band in pixels
    assert band[0] <= boxes[1].x0 and boxes[1].x1 <= band[1]
    matplotlib.pyplot.close(fig)


def test_every_front_panel_names_its_expert():
    from ibt.report import front_figures

    means = pd.DataFrame({"task": ["A", "A", "B"], "expert": ["dqn", "dqn", "ppo"],
                          "method": ["imitation-bt"] * 3, "bt_nodes": [5, 9, 7],
                          "retention_norm": [90, 95, 80], "low": [88, 94, 70],
                          "high": [92, 96, 85]})
    points = means[["task", "method", "bt_nodes", "retention_norm"]]
    anchors = pd.DataFrame(columns=["source", "task", "tree_nodes", "retention_norm"])
    fig = front_figures.size_retention_front(points, means, anchors)
    titles = [ax.get_title() for ax in fig.axes if ax.get_title()]
    assert titles == ["A, DQN expert", "B, PPO expert"]
    matplotlib.pyplot.close(fig)
