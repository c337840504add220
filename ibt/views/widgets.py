"""Interactive views for the notebooks (ipywidgets in JupyterLab), with a static fallback.

Each view has two layers:

* **callbacks**: plain functions from values to what is shown (:func:`trace_view`,
  :func:`region_figure`, :func:`schedule_panel`, ...). They need no browser and no widget, so
  pytest calls them directly;
* **a thin widget layer** (:class:`StateExplorer`, :class:`ScheduleExplorer`) that wires
  sliders and pickers to those callbacks and puts their results into HTML and Image widgets.

**Static fallback.** :func:`widget_mode` decides, and says why, in this order:

1. the notebook's parameter ``interactive`` is ``False``: static;
2. the environment variable ``IBT_STATIC`` is ``1``: static;
3. the environment variable ``IBT_PROFILE`` is set: static. Every batch run of this repository
   sets it (``make figures``, ``make reproduce`` and ``make smoke`` run papermill with it,
   ``make test`` and CI run nbval with ``IBT_PROFILE=smoke``), and none of them has a widget
   frontend: papermill would store widget views that GitHub and nbviewer cannot draw. A
   JupyterLab session (``make lab``) does not set it;
4. ``ipywidgets`` cannot be imported: static.

Otherwise the widgets are shown. The static rendering shows the same content for the default
values: the tables, the figure and the drawing that the widgets would show first.
"""

from __future__ import annotations

import html
import io
import json
import os
from collections.abc import Callable
from collections.abc import Sequence as Seq
from dataclasses import dataclass
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from ibt.bt.executors import as_features, tick
from ibt.bt.model import BehaviorTree, Condition
from ibt.tasks.catalogue import Task, get_task

ACTION_COLORS = ("#4575b4", "#fee090", "#d73027", "#91bfdb", "#fc8d59", "#1a9850", "#998ec3",
                 "#bababa")


# ------------------------------------------------------------------------------- the mode
def widget_mode(interactive: bool = True) -> tuple[bool, str]:
    """``(use_widgets, reason)`` by the rules of the module docstring."""
    if not interactive:
        return False, "the notebook parameter interactive is False"
    if os.environ.get("IBT_STATIC") == "1":
        return False, "IBT_STATIC=1"
    if os.environ.get("IBT_PROFILE"):
        return False, (f"IBT_PROFILE={os.environ['IBT_PROFILE']} is set: a batch run "
                       "(papermill or nbval), without a widget frontend")
    try:
        import ipywidgets  # noqa: F401
    except ImportError:
        return False, "ipywidgets is not installed"
    return True, "JupyterLab with ipywidgets"


def _display(*objects: Any) -> None:
    from IPython.display import display

    display(*objects)


def _static_note(reason: str) -> Any:
    from IPython.display import Markdown

    return Markdown(f"*Static rendering for the default values ({reason}); open the notebook "
                    "in JupyterLab (`make lab`) for the interactive version.*")


def figure_png(fig: plt.Figure) -> bytes:
    """The figure as PNG bytes (for an Image widget); the figure is closed."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", bbox_inches="tight")
    plt.close(fig)
    return buffer.getvalue()


def svg(graph: Any) -> str:
    """A graphviz graph as inline SVG text (for an HTML widget)."""
    from ibt.export.drawing import require_dot

    require_dot()
    text = graph.pipe(format="svg").decode()
    return text[text.index("<svg"):]


# ------------------------------------------------------------------- notebook 00: one tick
@dataclass(frozen=True)
class TraceView:
    """One tick of a BT on one state, as the state explorer shows it."""

    feature_names: tuple[str, ...]
    state: tuple[float, ...]
    decision: int
    action: str
    trace: pd.DataFrame  # every ticked node in order: depth, node, status
    conditions: pd.DataFrame  # every condition of the BT: value, holds, ticked

    def state_text(self) -> str:
        return ", ".join(f"{n} = {v:.4g}" for n, v in zip(self.feature_names, self.state,
                                                          strict=True))

    def text(self) -> str:
        """The trace as indented lines, then the decision."""
        lines = [f"state: {self.state_text()}"]
        lines += ["  " * (d + 1) + f"{node}: {status}" for d, node, status in
                  self.trace[["depth", "node", "status"]].itertuples(index=False)]
        lines.append(f"decision: {self.action}")
        return "\n".join(lines)

    def html(self) -> str:
        """The trace for an HTML widget: ticked nodes coloured by status, the decision last."""
        rows = []
        for d, node, status in self.trace[["depth", "node", "status"]].itertuples(index=False):
            color = "#1a9641" if status == "SUCCESS" else "#d7191c"
            rows.append(f'<div style="margin-left:{1.2 * d:.1f}em">{html.escape(node)}: '
                        f'<b style="color:{color}">{status}</b></div>')
        return (f'<div class="ibt-trace" style="font-family:monospace;font-size:12px">'
                f'<div class="ibt-state" data-state="{html.escape(json.dumps(self.state))}">'
                f'state: {html.escape(self.state_text())}</div>'
                f'{"".join(rows)}<div class="ibt-decision"><b>decision: '
                f'{html.escape(self.action)}</b></div></div>')


def trace_view(bt: BehaviorTree, state: Seq[float] | np.ndarray) -> TraceView:
    """Tick ``bt`` once on ``state``: the decision, the trace and every condition's status."""
    x = as_features(np.asarray(state, dtype=np.float64).reshape(1, -1))[0]
    decision, steps = tick(bt, x)
    ticked = {s.index: s.success for s in steps}
    trace = pd.DataFrame([{"step": k, "depth": s.depth, "node": s.label,
                           "status": "SUCCESS" if s.success else "FAILURE"}
                          for k, s in enumerate(steps)])
    rows = []
    for index, node in enumerate(bt.nodes()):
        if isinstance(node, Condition):
            value = node.value(x)  # the feature, or a relational condition's form
            holds = node.holds(x)
            rows.append({"node": index, "condition": bt.label(node),
                         "value": float(value), "holds": bool(holds),
                         "ticked": index in ticked})
    action = bt.action_names[decision] if decision >= 0 else "(no action)"
    return TraceView(tuple(bt.feature_names), tuple(float(v) for v in x), int(decision), action,
                     trace, pd.DataFrame(rows, columns=["node", "condition", "value", "holds",
                                                        "ticked"]))


def region_grid(bt: BehaviorTree, state: Seq[float] | np.ndarray, axes: tuple[int, int],
                extent: tuple[float, float, float, float], n: int = 120) -> np.ndarray:
    """The BT's actions on an n x n grid over two features; the others held at ``state``."""
    xs = np.linspace(extent[0], extent[1], n)
    ys = np.linspace(extent[2], extent[3], n)
    xx, yy = np.meshgrid(xs, ys)
    states = np.tile(np.asarray(state, dtype=np.float64), (n * n, 1))
    states[:, axes[0]] = xx.ravel()
    states[:, axes[1]] = yy.ravel()
    return bt.decide(states.astype(np.float32)).reshape(n, n)


def region_figure(bt: BehaviorTree, task: str | Task, state: Seq[float] | np.ndarray,
                  axes: tuple[str, str], n: int = 120) -> plt.Figure:
    """Decision regions over two features (the task's box), the others held at ``state``;
    the state is the star."""
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    spec = get_task(task)
    i, j = (bt.feature_names.index(a) for a in axes)
    extent = (spec.low[i], spec.high[i], spec.low[j], spec.high[j])
    grid = region_grid(bt, state, (i, j), extent, n)
    colors = list(ACTION_COLORS[: len(bt.action_names)])
    fig, ax = plt.subplots(figsize=(5.2, 3.6))
    ax.imshow(grid, origin="lower", extent=extent, aspect="auto", cmap=ListedColormap(colors),
              vmin=-0.5, vmax=len(colors) - 0.5, interpolation="nearest")
    ax.plot(state[i], state[j], marker="*", ms=16, color="black", mec="white")
    ax.set_xlabel(axes[0])
    ax.set_ylabel(axes[1])
    held = [f"{bt.feature_names[k]} = {float(state[k]):.3g}" for k in range(len(state))
            if k not in (i, j)]
    ax.set_title("the BT's actions" + (f" at {', '.join(held)}" if held else ""), fontsize=9)
    ax.legend(handles=[Patch(color=c, label=a) for c, a in zip(colors, bt.action_names,
                                                               strict=True)],
              fontsize=8, loc="upper left", bbox_to_anchor=(1, 1))
    fig.tight_layout()
    return fig


def default_state(task: str | Task) -> np.ndarray:
    """The middle of the task's box (integers rounded down)."""
    spec = get_task(task)
    mid = (np.asarray(spec.low, float) + np.asarray(spec.high, float)) / 2
    return np.floor(mid) if spec.integer_features else mid


class StateExplorer:
    """Sliders for every feature -> the live trace, the region plot and the traced drawing."""

    def __init__(self, bt: BehaviorTree, task: str | Task, state: Seq[float] | np.ndarray,
                 axes: tuple[str, str], n: int = 120, drawing: bool = True) -> None:
        import ipywidgets as w

        self.bt, self.task, self.axes, self.n, self.drawing = bt, get_task(task), axes, n, drawing
        self.sliders: dict[str, Any] = {}
        for k, name in enumerate(bt.feature_names):
            low, high = float(self.task.low[k]), float(self.task.high[k])
            step = 1.0 if self.task.integer_features else (high - low) / 200
            slider = w.FloatSlider(value=float(state[k]), min=low, max=high, step=step,
                                   description=name, continuous_update=False,
                                   readout_format=".0f" if step == 1.0 else ".3f",
                                   style={"description_width": "160px"},
                                   layout=w.Layout(width="460px"))
            slider.add_class(f"ibt-slider-{name}")
            slider.observe(self.update, names="value")
            self.sliders[name] = slider
        self.trace = w.HTML()
        self.trace.add_class("ibt-trace-widget")
        self.plot = w.Image(format="png", layout=w.Layout(width="560px"))
        self.graph = w.HTML()
        self.view: TraceView | None = None
        top = w.HBox([w.VBox(list(self.sliders.values())), self.trace])
        self.widget = w.VBox([top, self.plot, self.graph])
        self.update()

    def state(self) -> np.ndarray:
        return np.array([s.value for s in self.sliders.values()])

    def update(self, _change: Any = None) -> TraceView:
        """Recompute everything for the sliders' state (the callback of every slider)."""
        state = self.state()
        self.view = trace_view(self.bt, state)
        self.trace.value = self.view.html()
        self.plot.value = figure_png(region_figure(self.bt, self.task, state, self.axes, self.n))
        if self.drawing:
            from ibt.export.drawing import trace_graph

            self.graph.value = svg(trace_graph(self.bt, state))
        return self.view


def state_explorer(bt: BehaviorTree, task: str | Task, state: Seq[float] | np.ndarray,
                   axes: tuple[str, str], *, interactive: bool = True, n: int = 120) -> Any:
    """The state explorer widget, or (static fallback) its rendering for ``state``.

    Returns the widget to display; in static mode it displays the trace table, the conditions,
    the region plot and the traced drawing itself and returns ``None``.
    """
    use, reason = widget_mode(interactive)
    if use:
        return StateExplorer(bt, task, state, axes, n).widget
    from ibt.export.drawing import trace_graph

    view = trace_view(bt, state)
    _display(_static_note(reason))
    print(view.text())
    _display(view.conditions)
    fig = region_figure(bt, task, state, axes, n)
    _display(fig)
    plt.close(fig)
    _display(trace_graph(bt, state))
    return None


# ------------------------------------------------------- notebook 08: schedule and leaf limit
def schedule_graphs(view: Any) -> tuple[Any, Any]:
    """The drawings of one :class:`ibt.views.lesson.ScheduleView`: its decision tree and its BT."""
    from ibt.export.drawing import decision_tree_graphviz, to_graphviz

    return (decision_tree_graphviz(view.tree, view.bt.feature_names, view.bt.action_names),
            to_graphviz(view.bt))


def schedule_summary(view: Any) -> str:
    """One line of HTML: the setting, the node counts and the retention."""
    facts = view.facts
    return (f'<div class="ibt-schedule-summary" style="font-family:monospace">'
            f'{html.escape(str(facts["schedule"]))}, at most {facts["leaf limit"]} leaves: '
            f'tree <b>{facts["tree nodes"]}</b> nodes, BT <b>{facts["BT nodes"]}</b> nodes '
            f'({facts["BT conditions"]} conditions); retention '
            f'<b>{facts["retention_norm %"]:.1f} %</b> (random-normalised, '
            f'{facts["episodes"]} episodes, mean return {facts["mean return"]:.1f})</div>')


def schedule_panel(view: Any) -> dict[str, str]:
    """What the schedule explorer shows for one :class:`ibt.views.lesson.ScheduleView`: the HTML
    summary and the drawings of the tree and the BT as SVG."""
    tree, bt = schedule_graphs(view)
    return {"summary": schedule_summary(view), "tree": svg(tree), "bt": svg(bt)}


class ScheduleExplorer:
    """A beta-schedule picker and a leaf-limit slider -> tree, BT, node counts, retention."""

    def __init__(self, compute: Callable[[str, int], Any], schedules: Seq[str],
                 leaf_limits: Seq[int], schedule: str, leaves: int) -> None:
        import ipywidgets as w

        self.compute = compute
        self.schedule = w.Dropdown(options=list(schedules), value=schedule,
                                   description="beta schedule",
                                   style={"description_width": "110px"})
        self.leaves = w.SelectionSlider(options=[int(n) for n in leaf_limits], value=int(leaves),
                                        description="leaf limit", continuous_update=False,
                                        style={"description_width": "110px"})
        self.summary, self.tree, self.bt = w.HTML(), w.HTML(), w.HTML()
        for control in (self.schedule, self.leaves):
            control.observe(self.update, names="value")
        columns = w.HBox([w.VBox([w.HTML("<b>decision tree</b>"), self.tree]),
                          w.VBox([w.HTML("<b>Behavior Tree</b>"), self.bt])])
        self.widget = w.VBox([w.HBox([self.schedule, self.leaves]), self.summary, columns])
        self.update()

    def update(self, _change: Any = None) -> dict[str, str]:
        panel = schedule_panel(self.compute(self.schedule.value, int(self.leaves.value)))
        self.summary.value, self.tree.value, self.bt.value = (
            panel["summary"], panel["tree"], panel["bt"])
        return panel


def schedule_explorer(compute: Callable[[str, int], Any], schedules: Seq[str],
                      leaf_limits: Seq[int], schedule: str, leaves: int, *,
                      interactive: bool = True) -> Any:
    """The schedule explorer widget, or (static fallback) the summary and the drawings of the
    default setting (``compute(schedule, leaves)`` returns an
    :class:`ibt.views.lesson.ScheduleView`).
    """
    use, reason = widget_mode(interactive)
    if use:
        return ScheduleExplorer(compute, schedules, leaf_limits, schedule, leaves).widget
    from IPython.display import HTML

    view = compute(schedule, int(leaves))
    _display(_static_note(reason), HTML(schedule_summary(view)), *schedule_graphs(view))
    return None


# ---------------------------------------------------------------- notebook 08: the lesson's figures
def _action_colors(n: int) -> list[str]:
    return list(ACTION_COLORS[:n])


def iteration_figure(it: Any, axes: tuple[str, str] | None = None, n: int = 200,
                     max_points: int = 6000) -> plt.Figure:
    """One laid-open iteration (:class:`ibt.views.lesson.OpenIteration`) in three panels: who drove
    the rollout, the expert's labels with their Q-gap weights, the resampled data over the
    fitted tree's decision regions (at most about ``max_points`` states drawn per panel)."""
    from matplotlib.colors import ListedColormap
    from matplotlib.lines import Line2D

    from ibt.evaluate.policies import CompiledTree

    names = it.task.feature_names
    axes = tuple(axes or names[:2])
    i, j = names.index(axes[0]), names.index(axes[1])
    colors = _action_colors(len(it.task.action_names))
    steps = it.steps
    stride = -(-len(it.data) // max_points)  # every k-th state: a lighter picture, same shape
    data = it.data.iloc[::stride]
    shown = "" if stride == 1 else f", 1 in {stride} shown"
    fig, panels = plt.subplots(1, 3, figsize=(13.5, 3.8), sharex=True, sharey=True)
    for actor, color in (("expert", "#222222"), ("tree", "#f46d43")):
        part = steps[steps.actor == actor]
        panels[0].scatter(part[axes[0]], part[axes[1]], s=4, color=color,
                          label=f"{actor} drove ({len(part)} steps)")
    panels[0].set_title(f"iteration {it.iteration}: the mixed rollout\nbeta = {it.beta:.2f}",
                        fontsize=9)
    panels[0].legend(fontsize=7, loc="lower right", markerscale=3)
    size = 1 + 12 * data.weight / it.data.weight.max()
    panels[1].scatter(data[axes[0]], data[axes[1]], s=size, alpha=0.35, linewidths=0,
                      c=[colors[a] for a in data.expert_action])
    panels[1].set_title(f"the expert's labels, iterations 0..{it.iteration}\n"
                        f"({len(it.data):,} states{shown}; size: Q-gap weight)", fontsize=9)
    panels[1].legend(handles=[Line2D([], [], ls="", marker="o", color=c, label=a)
                              for c, a in zip(colors, it.task.action_names, strict=True)],
                     fontsize=7, loc="lower right")
    x0, x1 = it.data[axes[0]].min(), it.data[axes[0]].max()
    y0, y1 = it.data[axes[1]].min(), it.data[axes[1]].max()
    xx, yy = np.meshgrid(np.linspace(x0, x1, n), np.linspace(y0, y1, n))
    grid = np.tile(it.data[list(names)].median().to_numpy(), (n * n, 1))
    grid[:, i], grid[:, j] = xx.ravel(), yy.ravel()
    regions = CompiledTree(it.tree).predict(grid.astype(np.float32)).reshape(n, n)
    panels[2].imshow(regions, origin="lower", extent=(x0, x1, y0, y1), aspect="auto",
                     cmap=ListedColormap(colors), vmin=-0.5, vmax=len(colors) - 0.5, alpha=0.55,
                     interpolation="nearest")
    drawn = data[data.draws > 0]
    panels[2].scatter(drawn[axes[0]], drawn[axes[1]], s=2 * drawn.draws, color="black",
                      alpha=0.3, linewidths=0)
    panels[2].set_title(f"resampled: {int((it.data.draws > 0).sum()):,} states drawn{shown}"
                        f"\n(size: times drawn) over the fitted tree's regions", fontsize=9)
    for ax in panels:
        ax.set_xlabel(axes[0])
    panels[0].set_ylabel(axes[1])
    fig.tight_layout()
    return fig


def shift_figure(states: pd.DataFrame, axes: tuple[str, str], reference: str = "expert",
                 quantile: float = 0.005) -> plt.Figure:
    """Where each driver's states lie (one panel per driver, shared axes); the dashed box is
    the reference driver's central region (see :func:`ibt.views.lesson.outside_support`)."""
    from matplotlib.patches import Rectangle

    drivers = list(dict.fromkeys(states.driver))
    ref = states[states.driver == reference]
    (bx0, by0), (bx1, by1) = (ref[list(axes)].quantile(q) for q in (quantile, 1 - quantile))
    extent = (states[axes[0]].min(), states[axes[0]].max(),
              states[axes[1]].min(), states[axes[1]].max())
    fig, panels = plt.subplots(1, len(drivers), figsize=(4.3 * len(drivers), 3.4), sharex=True,
                               sharey=True, squeeze=False)
    for ax, name in zip(panels[0], drivers, strict=True):
        part = states[states.driver == name]
        ax.hexbin(part[axes[0]], part[axes[1]], gridsize=40, extent=extent, mincnt=1,
                  cmap="viridis", bins="log")
        ax.add_patch(Rectangle((bx0, by0), bx1 - bx0, by1 - by0, fill=False, ls="--",
                               color="#d7191c", lw=1.2))
        ax.set_title(f"{name} drives ({len(part):,} states)", fontsize=9)
        ax.set_xlabel(axes[0])
    panels[0, 0].set_ylabel(axes[1])
    fig.tight_layout()
    return fig


def diff_figure(diff: pd.DataFrame, task: str | Task, rows: str, columns: str) -> plt.Figure:
    """A region diff over two features of a discrete task: in each cell, how many of its states
    changed decision (:func:`ibt.views.lesson_edits.decision_diff`), out of how many."""
    from ibt.views.lesson_edits import all_states

    spec = get_task(task)
    labels = dict(spec.value_labels)
    everything = pd.DataFrame(all_states(spec), columns=list(spec.feature_names))

    def values(feature: str) -> list[Any]:
        f = spec.feature_names.index(feature)
        if f in labels:
            everything[feature] = [labels[f][int(v)] for v in everything[feature]]
            return list(labels[f])
        return list(range(int(spec.low[f]), int(spec.high[f]) + 1))

    row_values, col_values = values(rows), values(columns)
    total = everything.groupby([rows, columns]).size().unstack(fill_value=0)
    counts = diff.groupby([rows, columns]).size().unstack(fill_value=0)
    total = total.reindex(index=row_values, columns=col_values, fill_value=0)
    counts = counts.reindex(index=row_values, columns=col_values, fill_value=0).to_numpy()
    fig, ax = plt.subplots(figsize=(1.5 + 0.55 * len(col_values), 0.8 + 0.5 * len(row_values)))
    ax.imshow(counts / np.maximum(total.to_numpy(), 1), cmap="Reds", vmin=0, vmax=1,
              aspect="auto")
    for (r, c), value in np.ndenumerate(counts):
        if value:
            ax.text(c, r, str(value), ha="center", va="center", fontsize=8,
                    color="white" if value > 0.6 * total.iloc[r, c] else "black")
    ax.set_xticks(range(len(col_values)), [str(v) for v in col_values])
    ax.set_yticks(range(len(row_values)), [str(v) for v in row_values])
    ax.set_xlabel(columns)
    ax.set_ylabel(rows)
    per_cell = sorted(set(total.to_numpy().ravel().tolist()))
    ax.set_title(f"states whose decision changed: {len(diff)} of {len(everything)} "
                 f"({'/'.join(map(str, per_cell))} per cell)", fontsize=9)
    fig.tight_layout()
    return fig
