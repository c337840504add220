"""The size-retention fronts: return or retention against BT nodes, a line per method through
its leaf limits, beside the published trees (notebook 07's front of every method, notebook
10's continuous-action front). Each draws the tables it is given and saves like every figure
(:func:`ibt.report.plots.save_figure`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import pandas as pd

from ibt.report.figure_style import (
    FIG_WIDTH,
    GREY,
    method_style,
    methods_in,
    plain_log_ticks,
    wrap_text,
)
from ibt.report.plots import save_figure


def _anchor_label(source: str) -> str:
    """An anchor's legend entry: published numbers, unless its source says it was run here."""
    return source if source.endswith("run here") else f"{source} (published)"


def size_retention_front(points: pd.DataFrame, means: pd.DataFrame, anchors: pd.DataFrame,
                         path: str | Path | None = None, columns: int = 2,
                         notes: str = "") -> plt.Figure:
    """Retention against BT nodes, every method, one panel per task and expert (the front,
    notebook 07).

    ``points``: one row per run (columns task, expert, method, bt_nodes, retention_norm);
    ``means``: :func:`ibt.runs.front.front_means` (a line per method through its leaf limits,
    error bars on both axes); ``anchors``: published trees on our scale, per task and expert
    (:func:`ibt.runs.front.anchor_table`). ``notes`` ends the caption: what the legend's names
    mean beyond the method names (a reader of the figure alone needs it).
    """
    panels = _task_expert_panels(means)
    columns = min(columns, len(panels))
    rows = -(-len(panels) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(FIG_WIDTH, 2.7 * rows + 0.9),
                             squeeze=False)
    for ax in axes.flat[len(panels):]:
        ax.axis("off")
    handles: dict[str, Any] = {}  # errorbar containers and scatter collections
    sources = list(dict.fromkeys(anchors["source"]))
    for ax, (task, expert) in zip(axes.flat, panels, strict=False):
        here_means, here_points, here_anchors = (_panel_rows(frame, task, expert)
                                                 for frame in (means, points, anchors))
        for k, method in enumerate(methods_in(here_means)):
            style = method_style(method, k)
            seeds = here_points[here_points["method"] == method]
            ax.scatter(seeds["bt_nodes"], seeds["retention_norm"], s=9, alpha=0.35,
                       color=style["color"], lw=0)
            line = here_means[here_means["method"] == method].sort_values("bt_nodes")
            handle = ax.errorbar(line["bt_nodes"], line["retention_norm"],
                                 yerr=[(line["retention_norm"] - line["low"]).clip(lower=0),
                                       (line["high"] - line["retention_norm"]).clip(lower=0)],
                                 fmt={"imitation-bt+": "D-", "imitation-bt+s": "s-",
                                      "imitation-bt+rel+": "v-", "imitation-bt+sr": "^-"}.get(
                                     method, "o-"), ms=4,
                                 capsize=2, lw=1.2, color=style["color"],
                                 label=style["label"])
            handles.setdefault(str(style["label"]), handle)
        for anchor in here_anchors.drop_duplicates(["source", "tree_nodes"]).itertuples():
            marker = ("*", "X", "P", "s")[sources.index(anchor.source) % 4]
            handle = ax.scatter([anchor.tree_nodes], [anchor.retention_norm], marker=marker,
                                s=110 if marker == "*" else 60, color="black", zorder=5,
                                label=_anchor_label(anchor.source))
            handles.setdefault(_anchor_label(anchor.source), handle)
        ax.axhline(100, color="black", lw=0.8, ls=":")
        ax.axhline(98, color=GREY, lw=0.8, ls="--")
        ax.set_xscale("log")
        plain_log_ticks(ax)
        values = pd.concat([here_points["retention_norm"], here_means["low"]])
        ax.set_ylim(min(0.0, float(values.min()) - 5) if len(values) else 0, 110)
        ax.set_title(f"{task}, {str(expert).upper()} expert" if expert is not None else task)
        ax.set_xlabel("BT nodes (log)")
    for ax in axes[:, 0]:
        ax.set_ylabel("retention (%, random-norm.)")
    fig.legend(list(handles.values()), list(handles.keys()), loc="upper center",
               ncol=min(4, len(handles)), bbox_to_anchor=(0.5, 1.0), frameon=False)
    caption = " ".join(filter(None, [
        "A line per method through its leaf limits: mean over seeds, error bars the range (min "
        "to max) over seeds; faint dots are single seeds. BT nodes: the smallest verified BT of "
        "each tree. Black marks: published trees, or trees run here (node counts of trees, not "
        "BTs), on our scale. Dotted: the expert; dashed: 98 %.", notes]))
    fig.tight_layout(rect=(0, 0.0, 1, 0.94))
    fig.text(0.5, 0.0, wrap_text(caption, 110, break_on_hyphens=False), ha="center", va="top",
             fontsize=9)  # method names such as Imitation-BT+SR stay whole
    if path is not None:
        save_figure(fig, path)
    return fig


def _task_expert_panels(means: pd.DataFrame) -> list[tuple[str, str | None]]:
    """One panel per (task, expert) of ``means``, in order of appearance (per task without an
    expert column)."""
    if "expert" not in means:
        return [(task, None) for task in dict.fromkeys(means["task"])]
    return list(dict.fromkeys(zip(means["task"], means["expert"], strict=True)))


def _panel_rows(frame: pd.DataFrame, task: str, expert: str | None) -> pd.DataFrame:
    """The rows of ``frame`` one panel shows: its task's, and its expert's where both say."""
    rows = frame[frame["task"] == task]
    if expert is not None and "expert" in rows:
        rows = rows[rows["expert"] == expert]
    return rows


def continuous_front(points: pd.DataFrame, anchors: pd.DataFrame, targets: pd.DataFrame,
                     path: str | Path | None = None) -> plt.Figure:
    """Return against BT nodes for the continuous-action tasks (notebook 10).

    ``points``: one row per run (task, refined, leaf_limit, bt_nodes, mean_return,
    expert_return, algo); a line per kind (distilled, refined) through its leaf limits, mean
    over seeds with the range over seeds as error bars, faint dots for single seeds;
    ``anchors``: published or run-here trees (task, source, tree_nodes, mean_return);
    ``targets``: the bars set before the runs (task, min_return; ``ibt.runs.continuous``).
    """
    tasks = list(dict.fromkeys(points["task"]))
    fig, axes = plt.subplots(1, len(tasks), figsize=(FIG_WIDTH - 0.7, 3.2), squeeze=False)
    handles: dict[str, Any] = {}
    kinds = {False: ("distilled (regression tree, named commands)", "#56B4E9", "o-"),
             True: ("refined by return (Imitation-BT+)", "#E69F00", "D-")}
    sources = list(dict.fromkeys(anchors["source"])) if len(anchors) else []
    for ax, task in zip(axes.flat, tasks, strict=True):
        rows = points[points["task"] == task]
        for refined, (label, color, fmt) in kinds.items():
            runs = rows[rows["refined"] == refined]
            if runs.empty:
                continue
            ax.scatter(runs["bt_nodes"], runs["mean_return"], s=9, alpha=0.35, color=color,
                       lw=0)
            line = runs.groupby("leaf_limit").agg(x=("bt_nodes", "mean"),
                                                  y=("mean_return", "mean"),
                                                  lo=("mean_return", "min"),
                                                  hi=("mean_return", "max")).sort_values("x")
            handle = ax.errorbar(line["x"], line["y"], yerr=[line["y"] - line["lo"],
                                                             line["hi"] - line["y"]],
                                 fmt=fmt, ms=4, capsize=2, lw=1.2, color=color, label=label)
            handles.setdefault(label, handle)
        for anchor in anchors[anchors["task"] == task].itertuples():
            marker = ("*", "X", "P", "s")[sources.index(anchor.source) % 4]
            handle = ax.scatter([anchor.tree_nodes], [anchor.mean_return], marker=marker,
                                s=90 if marker == "*" else 50, color="black", zorder=5,
                                label=anchor.source)
            handles.setdefault(str(anchor.source), handle)
        ax.axhline(float(rows["expert_return"].iloc[0]), color="black", lw=0.8, ls=":")
        bar = targets.loc[targets["task"] == task, "min_return"]
        if len(bar):
            ax.axhline(float(bar.iloc[0]), color=GREY, lw=0.8, ls="--")
        ax.set_xscale("log")
        plain_log_ticks(ax)
        ax.set_title(f"{task}, {str(rows['algo'].iloc[0]).upper()} expert")
        ax.set_xlabel("BT nodes (log)")
    axes[0, 0].set_ylabel("mean return")
    fig.legend(list(handles.values()), list(handles.keys()), loc="upper center",
               ncol=min(3, len(handles)), bbox_to_anchor=(0.5, 1.08), frameon=False)
    caption = ("Mean over seeds at each leaf limit, error bars the range (min to max) over "
               "seeds; faint dots are single seeds; 100 final episodes each, every BT rolled "
               "out from its JSON document. Black marks: trees published or run here (their "
               "tree nodes, 2 x leaves - 1, not BT nodes). Dotted: the expert; dashed: the "
               "target return, fixed before the runs (the targets table of notebook 10).")
    fig.tight_layout(rect=(0, 0.0, 1, 0.97))
    fig.text(0.5, 0.0, wrap_text(caption, 110), ha="center", va="top", fontsize=9)
    if path is not None:
        save_figure(fig, path)
    return fig
