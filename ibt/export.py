"""Behavior trees out of Python: JSON files, graphviz drawings.

Drawings use the conventional BT glyphs: ``?`` for Selector/Fallback, ``→`` for Sequence, ``¬``
for Inverter, conditions as ellipses (``pole_angle <= 0.05``) and actions as green boxes.
Rendering needs graphviz's ``dot`` binary; without it, :func:`require_dot` says how to get it.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

from ibt.artifacts import atomic_write_text
from ibt.bt import Action, BehaviorTree, Condition, Inverter, Sequence, indexed

_GLYPH = {"selector": "?", "fallback": "?", "sequence": "→", "inverter": "¬"}


def save_json(bt: BehaviorTree, path: str | Path) -> Path:
    """Write the tree's JSON document atomically; returns the path."""
    path = Path(path)
    atomic_write_text(path, bt.to_json() + "\n")
    return path


def load_json(path: str | Path) -> BehaviorTree:
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no behavior tree at {path}")
    return BehaviorTree.from_json(path.read_text())


def require_dot() -> str:
    """Path of graphviz's ``dot``, or a one-line error naming the fix."""
    dot = shutil.which("dot")
    if dot is None:
        raise RuntimeError("graphviz's `dot` binary is missing: install it with "
                           "`sudo apt-get install graphviz` (Debian/Ubuntu), "
                           "`brew install graphviz` (macOS) or `conda install graphviz`")
    return dot


def to_graphviz(bt: BehaviorTree, highlight: dict[int, bool] | None = None,
                precision: int = 4):
    """A ``graphviz.Digraph`` of the tree; ``highlight`` maps node index -> ticked status
    (green success, red failure) for trace views."""
    import graphviz

    graph = graphviz.Digraph(graph_attr={"rankdir": "TB", "nodesep": "0.25", "ranksep": "0.35",
                                         "ordering": "out"},
                             node_attr={"fontname": "Helvetica", "fontsize": "11"},
                             edge_attr={"fontname": "Helvetica", "fontsize": "9"})
    # positions from one traversal: a node object used twice is drawn twice (see bt.indexed)
    for i, (node, children) in enumerate(indexed(bt.root)):
        attrs: dict[str, str] = {}
        if isinstance(node, Condition):
            attrs = {"label": bt.label(node, precision), "shape": "ellipse"}
        elif isinstance(node, Action):
            attrs = {"label": bt.label(node), "shape": "box", "style": "filled,rounded",
                     "fillcolor": "#d9f2d9"}
        else:
            attrs = {"label": _GLYPH[node.type], "shape": "box", "width": "0.4",
                     "fontsize": "16", "style": "filled", "fillcolor": "#eeeeee"}
            if isinstance(node, Sequence | Inverter):
                attrs["fillcolor"] = "#e3ecf7"
        if highlight is not None and i in highlight:
            attrs["color"] = "#1a9641" if highlight[i] else "#d7191c"
            attrs["penwidth"] = "3"
        graph.node(f"n{i}", **attrs)
        for child in children:
            graph.edge(f"n{i}", f"n{child}")
    return graph


def save_drawing(graph, stem: str | Path, formats: tuple[str, ...] = ("svg", "png")
                 ) -> list[Path]:
    """Render ``graph`` to ``<stem>.<fmt>`` for each format, atomically."""
    require_dot()
    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    written = []
    for fmt in formats:
        target = stem.with_suffix(f".{fmt}")
        with tempfile.TemporaryDirectory(dir=stem.parent) as tmp:
            out = graph.render(filename="drawing", directory=tmp, format=fmt, cleanup=True)
            os.replace(out, target)
        written.append(target)
    return written


def trace_graph(bt: BehaviorTree, state, precision: int = 4):
    """The drawing of one tick: ticked nodes outlined green (success) or red (failure)."""
    from ibt.bt import tick

    _, trace = tick(bt, state)
    return to_graphviz(bt, highlight={step.index: step.success for step in trace},
                       precision=precision)


def decision_tree_graphviz(tree, feature_names, action_names,
                           precision: int = 4):
    """A drawing of a fitted scikit-learn tree with the same labels as the BTs (left = true)."""
    import graphviz
    import numpy as np

    t = tree.tree_
    classes = np.asarray(tree.classes_)
    graph = graphviz.Digraph(graph_attr={"rankdir": "TB", "nodesep": "0.25", "ranksep": "0.35",
                                         "ordering": "out"},
                             node_attr={"fontname": "Helvetica", "fontsize": "11"},
                             edge_attr={"fontname": "Helvetica", "fontsize": "9"})
    for node in range(t.node_count):
        left, right = t.children_left[node], t.children_right[node]
        if left == right:
            action = int(classes[int(np.argmax(t.value[node][0]))])
            graph.node(f"d{node}", action_names[action], shape="box", style="filled,rounded",
                       fillcolor="#d9f2d9")
            continue
        label = f"{feature_names[t.feature[node]]} <= {t.threshold[node]:.{precision}g}"
        graph.node(f"d{node}", label, shape="box")
        graph.edge(f"d{node}", f"d{left}", label="yes")
        graph.edge(f"d{node}", f"d{right}", label="no")
    return graph
