"""Behavior trees as graphviz graphs (rendered and fitted to a page by :mod:`ibt.export.pictures`).

Drawings are top-down and use the conventional BT glyphs: ``?`` Selector/Fallback, ``→``
Sequence, ``¬`` Inverter, actions as rounded boxes. To keep them narrow, a rule's conditions
stack in one node instead of fanning out sideways: a Sequence's leading conditions are rows of
the Sequence's own box, and a Fallback whose children are all conjunctions of conditions is one
box with a block of rows per conjunction (an HTML-like graphviz table). Any valid BT draws:
other shapes (nested Fallbacks and Sequences of any depth, inverters of subtrees) keep one
graphviz node per BT node.

A trace (node index -> ticked status) is drawn in a colour-blind-safe scheme: success blue with
``✓``, failure orange and dashed with ``✗``, ``◆`` on the deciding condition, untouched nodes
grey. Node indices are positions in depth-first order (:meth:`BehaviorTree.nodes`), never object
identities: the same frozen node object may appear at two places of a tree.

:func:`ibt.export.pictures.draw_bt` writes a drawing readable at README width
(:mod:`ibt.export.readable`): if the full tree is too wide it staggers the root's children over
two rows, then collapses each child of the root to one summary node (one per action), and
writes the full tree as an SVG beside it.
Rendering needs graphviz's ``dot`` binary; without it, :func:`require_dot` says how to get it.
"""

from __future__ import annotations

import functools
import html
import shutil
import struct
from dataclasses import dataclass
from typing import Any

from ibt.bt.model import (
    Action,
    BehaviorTree,
    Condition,
    Fallback,
    Inverter,
    Node,
    Sequence,
    indexed,
)
from ibt.export.btcpp import xml_safe

FONT = "Helvetica"
FONT_PT = 12  #: conditions, actions and summaries
GLYPH_PT = 16  #: the ?, → and ¬ glyphs
TITLE_PT = 14
DRAWING_DPI = 144  #: PNG resolution of every drawing (composites keep it)

# Okabe-Ito colours: distinguishable with every common colour-vision deficiency
OK_LINE, OK_FILL, OK_DECIDING = "#0072B2", "#d3e5f3", "#9cc8ea"
FAIL_LINE, FAIL_FILL, FAIL_DECIDING = "#E69F00", "#fde6bd", "#f6c46a"
IDLE = "#9a9a9a"  # nodes a trace did not tick
SEQUENCE_FILL, FALLBACK_FILL, ACTION_FILL = "#e3ecf7", "#ececec", "#d5eee3"
_GLYPH = {"selector": "?", "fallback": "?", "sequence": "→", "inverter": "¬"}
TRACE_LEGEND = ("✓ success (blue)   ✗ failure (orange, dashed)   ◆ deciding condition   "
                "grey: not ticked")


def require_dot() -> str:
    """Path of graphviz's ``dot``, or a one-line error naming the fix."""
    dot = shutil.which("dot")
    if dot is None:
        raise RuntimeError("graphviz's `dot` binary is missing: install it with "
                           "`sudo apt-get install graphviz` (Debian/Ubuntu), "
                           "`brew install graphviz` (macOS) or `conda install graphviz`")
    return dot


# ------------------------------------------------------------------ shown in a notebook
def _inline_bundle(graph: Any, include: Any = None, exclude: Any = None
                   ) -> tuple[dict[str, Any], dict[str, Any]]:
    """A notebook's view of ``graph``: PNG and SVG, and the PNG's display width.

    JupyterLab draws no ``image/svg+xml`` of an untrusted notebook (every fresh clone), so a
    drawing carries a PNG too; trusted viewers keep the sharper SVG. The PNG is rendered at
    :data:`DRAWING_DPI` and shown at the SVG's size (96 px per inch), sharp on dense screens.
    """
    wanted = {"image/png", "image/svg+xml"} if include is None else set(include)
    wanted -= set(exclude or ())
    data: dict[str, Any] = {}
    metadata: dict[str, Any] = {}
    if "image/png" in wanted:
        hi = graph.copy()
        hi.graph_attr["dpi"] = str(DRAWING_DPI)
        png = hi.pipe(format="png")
        width, height = struct.unpack(">II", png[16:24])  # the PNG header's IHDR chunk
        scale = 96 / DRAWING_DPI
        data["image/png"] = png
        metadata["image/png"] = {"width": round(width * scale), "height": round(height * scale)}
    if "image/svg+xml" in wanted:
        data["image/svg+xml"] = graph.pipe(format="svg", encoding="utf-8")
    return data, metadata


@functools.cache
def _inline_digraph() -> type:
    """``graphviz.Digraph`` that a notebook shows as PNG and SVG (defined on first use, so that
    importing this module loads no graphviz)."""
    import graphviz

    class InlineDigraph(graphviz.Digraph):
        """A ``graphviz.Digraph`` shown in notebooks as PNG beside SVG (:func:`_inline_bundle`)."""

        def _repr_mimebundle_(self, include: Any = None, exclude: Any = None,
                              **_: Any) -> Any:
            return _inline_bundle(self, include, exclude)

    InlineDigraph.__module__, InlineDigraph.__qualname__ = __name__, "InlineDigraph"
    return InlineDigraph


def digraph(**attrs: Any) -> Any:
    """A new ``graphviz.Digraph`` (``attrs`` as its constructor takes them) that notebooks show
    as PNG and SVG: every drawing of this module is one."""
    return _inline_digraph()(**attrs)


# ----------------------------------------------------------------------------- the layout
def _stackable(node: Node) -> bool:
    """A condition, or an inverted condition: one row of a box."""
    return isinstance(node, Condition) or (isinstance(node, Inverter)
                                           and isinstance(node.child, Condition))


def _conjunction(node: Node) -> bool:
    """A stackable node, or a Sequence of stackable nodes only (one rule)."""
    return _stackable(node) or (isinstance(node, Sequence) and bool(node.children)
                                and all(_stackable(c) for c in node.children))


@dataclass(frozen=True)
class _Row:
    indices: tuple[int, ...]  # BT nodes this row shows (an inverter and its condition)
    text: str
    status: bool | None
    deciding: bool


COMMAND_WIDTH = 32  #: characters a line of a drawn command holds before it wraps


def command_lines(text: str, width: int = COMMAND_WIDTH, dimensions: bool = True) -> list[str]:
    """A command's label one dimension a line (``main_engine := ..., side_engine := ...``;
    ``dimensions=False``: a condition's label, whose commas are its own), a long sum wrapped
    before a ``+`` or ``-`` term so boxes stay narrow."""
    import re

    lines: list[str] = []
    for part in text.split(", ") if dimensions else [text]:
        line = ""
        for term in re.split(r" (?=[+-] )", part):
            if line and len(line) + 1 + len(term) > width:
                lines.append(line)
                line = "  " + term
            else:
                line = f"{line} {term}" if line else term
        lines.append(line)
    return lines


def plain_label(text: str) -> str:
    """``text`` as a graphviz label shown literally: never an HTML label (a name such as
    ``<<TABLE>...<IMG SRC="f"/>...>>`` would make ``dot`` read a file), no ``\\N``-style
    escapes, no character that XML or UTF-8 cannot hold."""
    import graphviz

    return graphviz.escape(xml_safe(text))


class _Drawer:
    """Builds one graphviz graph; ``elements`` maps each BT node index to the graphviz node
    (``name`` or ``name:row``) that shows it."""

    def __init__(self, bt: BehaviorTree, highlight: dict[int, bool] | None,
                 deciding: int | None, precision: int, collapse: bool, stagger: int) -> None:
        self.bt, self.precision = bt, precision
        self.highlight, self.trace = dict(highlight or {}), highlight is not None
        self.deciding, self.collapse, self.stagger = deciding, collapse, max(1, stagger)
        # positions from one traversal (bt.indexed): a node object used twice has two
        self.table = indexed(bt.root)
        self.nodes = [node for node, _ in self.table]
        self.elements: dict[int, str] = {}
        self._count = 0
        self.graph = digraph(
            graph_attr={"rankdir": "TB", "nodesep": "0.2", "ranksep": "0.3", "ordering": "out",
                        "fontname": FONT, "fontsize": str(TITLE_PT), "labelloc": "t",
                        "bgcolor": "white", "pad": "0.15"},
            node_attr={"fontname": FONT, "fontsize": str(FONT_PT), "margin": "0.08,0.04"},
            edge_attr={"arrowsize": "0.6", "color": "#555555"})

    # ---- helpers
    def _name(self) -> str:
        self._count += 1
        return f"n{self._count}"

    def _status(self, index: int) -> bool | None:
        return self.highlight.get(index)

    def _text(self, node: Node) -> str:
        """A node's label as text (escape it for the kind of graphviz label it goes in)."""
        return xml_safe(self.bt.label(node, self.precision))

    def _kids(self, index: int) -> tuple[int, ...]:
        return self.table[index][1]

    def _subtree(self, index: int) -> list[int]:
        out = [index]
        for kid in self._kids(index):
            out += self._subtree(kid)
        return out

    def _row(self, index: int) -> _Row:
        node = self.nodes[index]
        indices: tuple[int, ...] = (index,)
        text = self._text(node)
        if isinstance(node, Inverter):
            text = f"¬ ({self._text(node.child)})"
            indices = (index, self._kids(index)[0])
        return _Row(indices, text, self._status(index),
                    self.deciding is not None and self.deciding in indices)

    def _line(self, status: bool | None) -> dict[str, str]:
        if status is None:
            return {"color": IDLE if self.trace else "black"}
        return {"color": OK_LINE if status else FAIL_LINE}

    def _edge(self, parent: str, child: str, index: int, minlen: int = 1) -> None:
        status = self._status(index)
        attrs: dict[str, str] = {}
        if minlen > 1:
            attrs["minlen"] = str(minlen)
        if status is not None:
            attrs.update(color=OK_LINE if status else FAIL_LINE, penwidth="2.5",
                         style="solid" if status else "dashed")
        elif self.trace:
            attrs["color"] = IDLE
        self.graph.edge(parent, child, **attrs)

    # ---- node kinds
    def _glyph(self, node: Node, index: int) -> str:
        name = self._name()
        status = self._status(index)
        fill = SEQUENCE_FILL if isinstance(node, Sequence | Inverter) else FALLBACK_FILL
        attrs = {"label": _GLYPH[node.type], "shape": "box", "width": "0.45", "height": "0.4",
                 "fontsize": str(GLYPH_PT), "style": "filled", "fillcolor": fill}
        attrs.update(self._node_status(status))
        self.graph.node(name, **attrs)
        self.elements[index] = name
        return name

    def _node_status(self, status: bool | None, base_style: str = "filled") -> dict[str, str]:
        if status is None:
            return {"color": IDLE, "fontcolor": IDLE} if self.trace else {}
        return {"color": OK_LINE if status else FAIL_LINE, "penwidth": "3",
                "fillcolor": OK_FILL if status else FAIL_FILL,
                "style": base_style + ("" if status else ",dashed")}

    def _action(self, node: Action, index: int) -> str:
        name = self._name()
        status = self._status(index)
        text = self._text(node)
        if self.bt.commands is not None:  # a command's values one per line: narrower boxes
            text = "\n".join(command_lines(text))
        attrs = {"label": plain_label(text), "shape": "box",
                 "style": "filled,rounded",
                 "fillcolor": ACTION_FILL}
        attrs.update(self._node_status(status, "filled,rounded"))
        if status:
            attrs["fillcolor"] = ACTION_FILL
        self.graph.node(name, **attrs)
        self.elements[index] = name
        return name

    def _cell_fill(self, status: bool | None, default: str = "") -> str:
        if status is None:
            return default
        return OK_FILL if status else FAIL_FILL

    def _table(self, index: int, header: tuple[str, str] | None,
               blocks: list[tuple[int | None, list[_Row]]], intro: tuple[str, ...] = ()
               ) -> str:
        """One box: an optional header glyph row, free text rows (``intro``), then blocks of
        condition rows (a block with an index is a Sequence, drawn with its own → cell)."""
        name = self._name()
        status = self._status(index)
        glyph_col = any(b is not None for b, _ in blocks)
        ncols = 1 + 2 * int(self.trace) + int(glyph_col)
        font = f'<FONT COLOR="{IDLE}">' if self.trace and status is None else "<FONT>"
        line = self._line(status)["color"]
        border = "2" if self.trace else "1"  # one width: a trace's layout never moves
        style = ' STYLE="dashed"' if status is False else ""
        out = [f'<TABLE BORDER="{border}" CELLBORDER="0" CELLSPACING="0" CELLPADDING="3" '
               f'COLOR="{line}" BGCOLOR="white"{style}>']
        if header is not None:
            glyph, fill = header
            shown = html.escape(glyph)
            if self.bt.commands is not None:  # a command's values one per line: narrower boxes
                shown = "<BR/>".join(html.escape(line) for line in command_lines(glyph))
            out.append(f'<TR><TD COLSPAN="{ncols}" BGCOLOR="{self._cell_fill(status, fill)}">'
                       f'<FONT POINT-SIZE="{GLYPH_PT}">{shown}</FONT></TD></TR>')
        for k, text in enumerate(intro):
            if k == 0 and header is not None:
                out.append("<HR/>")
            out.append(f'<TR><TD COLSPAN="{ncols}" ALIGN="LEFT">{text}</TD></TR>')
        for k, (block, rows) in enumerate(blocks):
            if k or header is not None or intro:
                out.append("<HR/>")
            for r, row in enumerate(rows):
                port = f"r{row.indices[0]}"
                for i in row.indices:
                    self.elements[i] = f"{name}:{port}"
                cells = []
                if glyph_col and r == 0:
                    fill = self._cell_fill(self._status(block) if block is not None else None,
                                           SEQUENCE_FILL if block is not None else "white")
                    glyph = (f'<FONT POINT-SIZE="{GLYPH_PT}">→</FONT>' if block is not None
                             else " ")
                    cells.append(f'<TD ROWSPAN="{len(rows)}" BGCOLOR="{fill}" VALIGN="MIDDLE">'
                                 f'{glyph}</TD>')
                    if block is not None:
                        self.elements[block] = f"{name}:{port}"
                fill = self._cell_fill(row.status, "white")
                if row.deciding:
                    fill = OK_DECIDING if row.status else FAIL_DECIDING
                fixed = 'FIXEDSIZE="TRUE" WIDTH="22" HEIGHT="22"'
                if self.trace:
                    mark = " " if row.status is None else ("✓" if row.status else "✗")
                    cells.append(f'<TD {fixed} BGCOLOR="{fill}">{mark}</TD>')
                text = '<BR ALIGN="LEFT"/>'.join(  # a long sum of terms wraps as commands do
                    html.escape(line, quote=False)
                    for line in command_lines(row.text, dimensions=False))
                if self.trace and row.status is None:
                    text = f'<FONT COLOR="{IDLE}">{text}</FONT>'
                cells.append(f'<TD PORT="{port}" ALIGN="LEFT" BGCOLOR="{fill}">{text}</TD>')
                if self.trace:  # a fixed cell for the ◆, so that marking it moves nothing
                    cells.append(f'<TD {fixed} BGCOLOR="{fill}">{"◆" if row.deciding else " "}'
                                 "</TD>")
                out.append("<TR>" + "".join(cells) + "</TR>")
        out.append("</TABLE>")
        label = "<" + font + "".join(out) + "</FONT>>"
        self.graph.node(name, label=label, shape="plain")
        self.elements.setdefault(index, name)
        return name

    def _summary(self, index: int) -> str:
        """A collapsed child of the root: its action, how many rules and conditions."""
        node = self.nodes[index]
        positions = self._subtree(index)
        nodes = [self.nodes[p] for p in positions]
        conditions = sum(isinstance(n, Condition) for n in nodes)
        children = getattr(node, "children", ())
        if isinstance(node, Sequence) and children and isinstance(children[-1], Action):
            guard = children[:-1]
            if len(guard) == 1 and isinstance(guard[0], Fallback):
                rules = len(guard[0].children)
            else:
                rules = 1
            head = f"→  {self._text(children[-1])}"  # escaped once, by _table
            facts = (f"{rules} rule{'s' * (rules != 1)}, {conditions} "
                     f"condition{'s' * (conditions != 1)}")
        else:
            acts = sorted({self._text(n) for n in nodes if isinstance(n, Action)})
            head = f"{_GLYPH.get(node.type, '')}  {', '.join(acts) or node.type}"
            facts = f"{len(nodes)} nodes, {conditions} conditions"
        status = self._status(index)
        rows: list[_Row] = []
        intro = [f"<I>{facts}</I>"]
        if status:
            # the rule that held: the successful conjunction's ticked conditions
            for pos, n in zip(positions, nodes, strict=True):
                if _conjunction(n) and not _stackable(n) and self._status(pos):
                    rows = [self._row(i) for i in self._kids(pos)]
                    break
            else:
                inverted = {self._kids(p)[0] for p, n in zip(positions, nodes, strict=True)
                            if isinstance(n, Inverter)}
                rows = [self._row(pos) for pos, n in zip(positions, nodes, strict=True)
                        if _stackable(n) and self._status(pos) and pos not in inverted]
        elif status is False:
            intro.append("✗ no rule held")
            if self.deciding is not None and self.deciding in positions:
                rows = [self._row(self.deciding)]
        name = self._table(index, (head, SEQUENCE_FILL if isinstance(node, Sequence)
                                   else FALLBACK_FILL), [(None, rows)] if rows else [],
                           tuple(intro))
        for pos in positions:
            self.elements.setdefault(pos, name)
        return name

    # ---- recursion
    def emit(self, index: int, depth: int = 0) -> str:
        node = self.nodes[index]
        if self.collapse and depth == 1 and not isinstance(node, Action):
            return self._summary(index)
        if isinstance(node, Action):
            return self._action(node, index)
        if _stackable(node):
            return self._table(index, None, [(None, [self._row(index)])])
        positions = list(self._kids(index))
        children = list(getattr(node, "children", ()))
        if isinstance(node, Fallback) and children and all(_conjunction(c) for c in children):
            blocks: list[tuple[int | None, list[_Row]]] = []
            for child, pos in zip(children, positions, strict=True):
                if _stackable(child):
                    blocks.append((None, [self._row(pos)]))
                else:
                    blocks.append((pos, [self._row(i) for i in self._kids(pos)]))
            return self._table(index, ("?", FALLBACK_FILL), blocks)
        lead = 0
        if isinstance(node, Sequence):
            while lead < len(children) and _stackable(children[lead]):
                lead += 1
        if lead:
            rows = [self._row(i) for i in positions[:lead]]
            name = self._table(index, ("→", SEQUENCE_FILL), [(None, rows)])
        else:
            name = self._glyph(node, index)
        for k, pos in enumerate(positions[lead:]):
            minlen = 1 + (k % self.stagger) if depth == 0 else 1
            self._edge(name, self.emit(pos, depth + 1), pos, minlen)
        return name


def _drawer(bt: BehaviorTree, highlight: dict[int, bool] | None = None,
            precision: int = 4, *, deciding: int | None = None, collapse: bool = False,
            stagger: int = 1, title: str | None = None, legend: bool = True) -> _Drawer:
    drawer = _Drawer(bt, highlight, deciding, precision, collapse, stagger)
    drawer.emit(0)
    lines = [html.escape(xml_safe(part)) for part in title.split("\n")] if title else []
    if highlight is not None and legend:
        lines.append(f'<FONT POINT-SIZE="{FONT_PT}">{TRACE_LEGEND}</FONT>')
    if lines:
        drawer.graph.graph_attr["label"] = "<" + "<BR/>".join(lines) + ">"
    return drawer


def to_graphviz(bt: BehaviorTree, highlight: dict[int, bool] | None = None,
                precision: int = 4, *, deciding: int | None = None, collapse: bool = False,
                stagger: int = 1, title: str | None = None, legend: bool = True):
    """A ``graphviz.Digraph`` of the tree (a notebook shows it as PNG and SVG).

    ``highlight`` maps node index (depth-first position) -> ticked status for trace views,
    ``deciding`` is the index of the condition that decided the tick (marked ◆). ``collapse``
    draws each child of the root as one summary node; ``stagger`` > 1 spreads the root's
    children over that many rows. A trace view carries a legend of its marks (``legend``).
    """
    return _drawer(bt, highlight, precision, deciding=deciding, collapse=collapse,
                   stagger=stagger, title=title, legend=legend).graph


def drawing_elements(bt: BehaviorTree, **kwargs) -> dict[int, str]:
    """Which graphviz node (or ``node:row``) shows each BT node index (for tests, tools)."""
    return _drawer(bt, **kwargs).elements


def deciding_condition(bt: BehaviorTree, trace) -> int | None:
    """The index of the last condition ticked before the tick's decision (the first action
    ticked): the test whose outcome sent control to that action. ``None`` without one."""
    nodes = list(bt.nodes())
    last = None
    for step in trace:
        node = nodes[step.index]
        if isinstance(node, Action):
            return last
        if isinstance(node, Condition):
            last = step.index
    return last


def trace_graph(bt: BehaviorTree, state, precision: int = 4, title: str | None = None):
    """The drawing of one tick: ticked nodes blue ✓ (success) or orange ✗ (failure), the
    deciding condition ◆, untouched nodes grey."""
    from ibt.bt.executors import tick

    _, trace = tick(bt, state)
    return to_graphviz(bt, highlight={step.index: step.success for step in trace},
                       precision=precision, deciding=deciding_condition(bt, trace), title=title)


def decision_tree_graphviz(tree, feature_names, action_names, precision: int = 4,
                           title: str | None = None):
    """A drawing of a fitted scikit-learn tree with the same labels as the BTs (left = true)."""
    import numpy as np

    t = tree.tree_
    classes = np.asarray(tree.classes_)
    feature_map = getattr(tree, "feature_map_", None)  # a relational tree
    if feature_map is not None:  # derived columns read as a reader writes them: x - vx
        feature_names = feature_map.names(feature_names)
    graph = digraph(graph_attr={"rankdir": "TB", "nodesep": "0.2", "ranksep": "0.3",
                                "ordering": "out", "fontname": FONT,
                                "fontsize": str(TITLE_PT), "labelloc": "t",
                                "bgcolor": "white", "pad": "0.15"},
                    node_attr={"fontname": FONT, "fontsize": str(FONT_PT)},
                    edge_attr={"fontname": FONT, "fontsize": str(FONT_PT),
                               "arrowsize": "0.6", "color": "#555555"})
    if title:
        graph.attr(label=plain_label(title))
    for node in range(t.node_count):
        left, right = t.children_left[node], t.children_right[node]
        if left == right:
            action = int(classes[int(np.argmax(t.value[node][0]))])
            graph.node(f"d{node}", plain_label(action_names[action]), shape="box",
                       style="filled,rounded",
                       fillcolor=ACTION_FILL)
            continue
        label = f"{feature_names[t.feature[node]]} <= {t.threshold[node]:.{precision}g}"
        graph.node(f"d{node}", plain_label(label), shape="box")
        graph.edge(f"d{node}", f"d{left}", label="yes")
        graph.edge(f"d{node}", f"d{right}", label="no")
    return graph
