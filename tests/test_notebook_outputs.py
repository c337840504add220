"""Committed notebooks render in an untrusted JupyterLab (every fresh clone): JupyterLab draws no
``image/svg+xml`` output of an untrusted notebook, so every drawing carries a PNG beside it."""

from __future__ import annotations

import shutil
from pathlib import Path

import nbformat
import pytest

ROOT = Path(__file__).resolve().parent.parent
NOTEBOOKS = sorted((ROOT / "notebooks").glob("[0-9]*.ipynb"))
needs_dot = pytest.mark.skipif(shutil.which("dot") is None, reason="needs graphviz's dot")


def test_the_notebooks_are_there():
    assert len(NOTEBOOKS) >= 10


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_every_svg_output_has_a_png_beside_it(path):
    nb = nbformat.read(path, as_version=4)
    svg_only = [k for k, cell in enumerate(nb.cells) if cell.cell_type == "code"
                for output in cell.get("outputs", [])
                if "image/svg+xml" in output.get("data", {})
                and "image/png" not in output.get("data", {})]
    assert not svg_only, f"{path.name}: cells {svg_only} show SVG only (re-run the notebook)"


def _bundle(obj: object) -> tuple[dict, dict]:
    from IPython.core.formatters import DisplayFormatter

    return DisplayFormatter().format(obj)


@needs_dot
def test_drawings_show_as_png_and_svg():
    # Expect: what the notebooks display (a BT, a tick's trace, a decision tree) carries both,
    # the PNG shown at the SVG's size
    import numpy as np
    from sklearn.tree import DecisionTreeClassifier

    import ibt
    from ibt.export.drawing import decision_tree_graphviz, to_graphviz, trace_graph

    bt = ibt.load_json(ROOT / "data" / "trees" / "MountainCar-v0" / "dqn" / "imitation-bt.json")
    tree = DecisionTreeClassifier(max_leaf_nodes=3, random_state=0).fit(
        np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]]), [0, 1, 1, 2])
    for graph in (to_graphviz(bt), trace_graph(bt, np.zeros(2)),
                  decision_tree_graphviz(tree, ["x", "v"], ["a", "b", "c"])):
        data, metadata = _bundle(graph)
        assert data["image/png"].startswith(b"\x89PNG")
        assert "<svg" in data["image/svg+xml"]
        assert 0 < metadata["image/png"]["width"] and 0 < metadata["image/png"]["height"]
        assert graph.copy().__class__ is graph.__class__  # saving and measuring copy it


@needs_dot
def test_a_png_only_request_gets_only_the_png():
    import ibt
    from ibt.export.drawing import to_graphviz

    bt = ibt.load_json(ROOT / "data" / "trees" / "MountainCar-v0" / "dqn" / "imitation-bt.json")
    data, _ = to_graphviz(bt)._repr_mimebundle_(include=["image/png"])
    assert list(data) == ["image/png"]


def test_front_has_a_panel_per_task_and_expert():
    # Expect: one task run with two experts is two panels, each with its own expert's points
    import matplotlib
    import pandas as pd

    matplotlib.use("Agg")
    from ibt.report import front_figures

    means = pd.DataFrame({"task": ["A", "B", "B"], "expert": ["dqn", "dqn", "ppo"],
                          "method": ["imitation-bt+"] * 3, "bt_nodes": [5, 9, 7],
                          "retention_norm": [90, 95, 60], "low": [88, 94, 50],
                          "high": [92, 96, 65]})
    points = means[["task", "expert", "method", "bt_nodes", "retention_norm"]]
    anchors = pd.DataFrame({"source": ["S"] * 2, "task": ["B"] * 2, "expert": ["dqn", "ppo"],
                            "tree_nodes": [20, 20], "retention_norm": [80.0, 40.0]})
    fig = front_figures.size_retention_front(points, means, anchors, notes="X*: the variants.")
    panels = [ax for ax in fig.axes if ax.get_title()]
    assert [ax.get_title() for ax in panels] == ["A, DQN expert", "B, DQN expert",
                                                 "B, PPO expert"]
    ppo_anchor = [c.get_offsets().tolist() for c in panels[2].collections
                  if len(c.get_offsets()) == 1 and c.get_offsets()[0][0] == 20]
    assert ppo_anchor == [[[20.0, 40.0]]]  # the anchor on the PPO expert's scale
    caption = [t.get_text() for t in fig.texts if "variants" in t.get_text()]
    assert caption and "X*: the variants." in caption[0].replace("\n", " ")
    matplotlib.pyplot.close(fig)
