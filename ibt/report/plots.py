"""One function per figure; figures never recompute results, they draw tables.

Every function returns the matplotlib figure and, given ``path`` (without suffix), saves it as
PDF and PNG atomically (:func:`save_figure`), and every PNG records its smallest font so a test
can check it (:mod:`ibt.export.readable`). Here: saving, and the figures of the paper's grid
and of the distillation (histories, tasks, retention, beta schedules, node counts, size
sweeps); the pictures of tasks and policies are in :mod:`ibt.report.task_figures`, the
size-retention fronts in :mod:`ibt.report.front_figures`, the shared style (size, fonts,
colours, captions) in :mod:`ibt.report.figure_style`.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from matplotlib.text import Text

from ibt.export.readable import stamp_info
from ibt.files import atomic_target
from ibt.report.figure_style import (
    BASELINE_NOTE,
    FIG_WIDTH,
    GREY,
    OKABE_ITO,
    SAVE_DPI,
    flagged_experts,
    interval_caption,
    interval_columns,
    mark_status,
    method_style,
    methods_in,
    plain_log_ticks,
    wrap_text,
)


def min_font_pt(fig: plt.Figure) -> float:
    """The smallest font of the text a draw of ``fig`` puts on the page (ticks, labels,
    legends; hidden axes' ticks do not count)."""
    sizes: list[float] = []
    draw = Text.draw

    def recording(text: Text, renderer) -> None:
        if text.get_visible() and text.get_text().strip():
            sizes.append(float(text.get_fontsize()))
        return draw(text, renderer)

    Text.draw = recording  # type: ignore[method-assign,assignment]
    try:
        fig.canvas.draw()
    finally:
        Text.draw = draw  # type: ignore[method-assign]
    return min(sizes) if sizes else 10.0


def save_figure(fig: plt.Figure, path: str | Path, formats: tuple[str, ...] = ("pdf", "png"),
                dpi: float = SAVE_DPI, kind: str = "plot") -> list[Path]:
    """Save ``fig`` as ``<path>.<fmt>`` for each format, via temp files and renames; PNGs
    carry their smallest font and dpi (:mod:`ibt.export.readable`)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    written = []
    for fmt in formats:
        target = path.with_suffix(f".{fmt}")
        metadata: dict[str, str | None] | None
        if fmt == "pdf":
            metadata = {"CreationDate": None}
        elif fmt == "png":
            metadata = dict(stamp_info(min_font_pt(fig), dpi, kind))
        else:
            metadata = None
        with atomic_target(target) as tmp:
            fig.savefig(tmp, format=fmt, bbox_inches="tight", metadata=metadata, dpi=dpi)
        written.append(target)
    return written

def distillation_history(history: pd.DataFrame, title: str = "", path: str | Path | None = None
                         ) -> plt.Figure:
    """Held-out return of each iteration's tree, with beta and the chosen tree marked."""
    fig, ax = plt.subplots(figsize=(7, 3.4))
    ax.errorbar(history["iteration"], history["selection_mean"], yerr=history["selection_std"],
                fmt="o-", ms=3, lw=1, capsize=2, color=OKABE_ITO[5],
                label="tree: mean return on the held-out episodes\n(error bars: ±1 s.d. "
                      "over those episodes)")
    best = history[history["best"]]
    ax.plot(best["iteration"], best["selection_mean"], "*", color=OKABE_ITO[6], ms=15,
            label="chosen tree")
    ax.set_xlabel("iteration")
    ax.set_ylabel("mean return")
    beta_ax = ax.twinx()
    beta_ax.plot(history["iteration"], history["beta"], color="#555555", ls="--", lw=1)
    beta_ax.set_ylabel("beta (expert share, dashed)", color="#555555")
    beta_ax.set_ylim(0, 1.05)
    ax.legend(loc="lower left", fontsize=9)
    ax.set_title(title)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path)
    return fig


def label_package_delivery(ax: plt.Axes) -> None:
    """Name what a package-delivery frame shows: the four places and the battery."""
    from ibt.envs.package_delivery import render_layout

    box = {"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.85}
    for name, (x, y) in render_layout().items():
        text = name.replace("zone_", "zone ").replace(" a", " A").replace(" b", " B")
        ax.text(x, y, text, ha="center", va="center", fontsize=9, bbox=box)


def task_frames(frames: dict[str, np.ndarray], path: str | Path | None = None,
                columns: int = 3) -> plt.Figure:
    """A grid of rendered frames, one per task (``{task: rgb array}``); the package-delivery
    frame gets its places and battery named."""
    rows = -(-len(frames) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(FIG_WIDTH, 2.2 * rows + 0.2),
                             squeeze=False)
    for ax in axes.flat:
        ax.axis("off")
    for ax, (name, frame) in zip(axes.flat, frames.items(), strict=False):
        ax.imshow(frame)
        ax.set_title(name, fontsize=10)
        if name.startswith("PackageDelivery"):
            label_package_delivery(ax)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path)
    return fig


def retention_grid(summary: pd.DataFrame, value: str = "retention_norm",
                   path: str | Path | None = None) -> plt.Figure:
    """Fig. 4: mean retention and its interval per task and method, one panel per expert.

    ``summary``: :func:`ibt.report.stats.summarise` output (task, expert, method, ``value``,
    interval_low/high and interval; or the older ci_low/ci_high). An ``expert_status`` column
    other than ``ok`` greys the task's bars of that expert and names the status.
    """
    low_col, high_col = interval_columns(summary)
    experts = [e for e in ("dqn", "ppo", "a2c") if e in set(summary["expert"])]
    experts += sorted(set(summary["expert"]) - set(experts))
    tasks = list(dict.fromkeys(summary["task"]))
    methods = methods_in(summary)
    statuses = flagged_experts(summary)
    fig, axes = plt.subplots(len(experts), 1, figsize=(FIG_WIDTH, 2.3 * len(experts) + 0.6),
                             squeeze=False, sharex=True)
    width = 0.84 / len(methods)
    lowest = float(np.nanmin(np.minimum(summary[low_col], summary[value])))
    highest = float(np.nanmax(np.maximum(summary[high_col], summary[value])))
    span = max(highest, 100) - min(lowest, 0)
    y_low, y_high = min(0.0, lowest) - 0.05 * span, max(115.0, highest + 0.05 * span)
    for ax, expert in zip(axes[:, 0], experts, strict=True):
        part = summary[summary["expert"] == expert].set_index(["task", "method"])
        for i, task in enumerate(tasks):
            if (task, expert) in statuses:
                mark_status(ax, i, statuses[(task, expert)])
        for k, method in enumerate(methods):
            xs, ys, lo, hi = [], [], [], []
            for i, task in enumerate(tasks):
                if (task, method) in part.index:
                    row = part.loc[(task, method)]
                    xs.append(i - 0.42 + width * (k + 0.5))
                    ys.append(row[value])
                    lo.append(max(0.0, row[value] - row[low_col]))
                    hi.append(max(0.0, row[high_col] - row[value]))
            ax.bar(xs, ys, width, yerr=[lo, hi], capsize=1.5, zorder=2,
                   error_kw={"lw": 0.8, "zorder": 3}, **method_style(method, k))
        ax.axhline(100, color="black", lw=0.8, ls=":", zorder=1)
        ax.set_ylabel(f"{expert.upper()} expert\nretention (%)")
        ax.set_ylim(y_low, y_high)
    axes[-1, 0].set_xticks(range(len(tasks)), tasks, rotation=25, ha="right")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, ncol=min(4, len(methods)), loc="lower center",
               bbox_to_anchor=(0.5, 1.0), frameon=False)
    label = "random-normalised" if value == "retention_norm" else "raw"
    notes = [f"Performance retention ({label}: 0 = random policy, 100 = expert, dotted line). "
             f"Bars: means over seeds; {interval_caption(summary)}."]
    if {"bt-espresso", "re-bt-espresso"} & set(methods):
        notes.append(BASELINE_NOTE)
    fig.text(0.5, 0.0, "\n".join(wrap_text(n, 110) for n in notes), ha="center", va="top",
             fontsize=9)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path)
    return fig

def beta_analysis(curves: pd.DataFrame, results: pd.DataFrame, path: str | Path | None = None,
                  task: str | None = None, expert: str | None = None) -> plt.Figure:
    """Fig. 3: beta schedules (left) and the final returns of each schedule's trials (right),
    with the expert's and the random policy's returns drawn as levels.

    ``curves``: columns schedule, iteration, beta. ``results``: columns schedule, mean_return
    and, when present, task, expert, expert_return, random_return (the levels and the title).
    """
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    order = list(dict.fromkeys(curves["schedule"]))
    task = task or (results["task"].iloc[0] if "task" in results else "")
    expert = expert or (results["expert"].iloc[0] if "expert" in results else "")
    trials = results.groupby("schedule").size()
    n_trials = (f"{trials.min()}" if trials.min() == trials.max()
                else f"{trials.min()} to {trials.max()}")
    fig, (left, right) = plt.subplots(1, 2, figsize=(FIG_WIDTH, 4.2),
                                      gridspec_kw={"width_ratios": [1, 1.45]})
    cmap = plt.get_cmap("viridis")
    exponential = [name for name in order if name != "linear"]
    for name in order:
        part = curves[curves["schedule"] == name]
        if name == "linear":
            style = {"color": OKABE_ITO[6], "lw": 2.5}
        else:
            style = {"color": cmap(exponential.index(name) / max(1, len(exponential) - 1)),
                     "lw": 1}
        left.plot(part["iteration"], part["beta"], label=_schedule_label(name), **style)
    left.set_xlabel("iteration i")
    left.set_ylabel("beta_i (probability the expert acts)")
    left.legend(fontsize=9, ncol=2, title="schedule", handlelength=1.2, columnspacing=0.8)
    data = [results.loc[results["schedule"] == name, "mean_return"].to_numpy() for name in order]
    right.boxplot(data, tick_labels=[_schedule_label(n) for n in order], showmeans=True,
                  medianprops={"color": "black", "lw": 1.5},
                  meanprops={"marker": "^", "markerfacecolor": OKABE_ITO[5],
                             "markeredgecolor": OKABE_ITO[5], "markersize": 7},
                  flierprops={"marker": "o", "markerfacecolor": "none",
                              "markeredgecolor": OKABE_ITO[6], "markersize": 8})
    for k, values in enumerate(data, start=1):
        right.plot(np.full(len(values), k), values, "o", ms=3, alpha=0.7, color="black")
    levels = []
    for column, name, color, ls in (("expert_return", "expert", OKABE_ITO[3], "-"),
                                    ("random_return", "random policy", GREY, "--")):
        if column in results and results[column].notna().any():
            level = float(results[column].iloc[0])
            right.axhline(level, lw=1.2, color=color, ls=ls)
            levels.append(Line2D([], [], lw=1.2, color=color, ls=ls,
                                 label=f"{name}: {level:.0f}"))
    right.set_ylabel("final mean return (100 episodes)")
    right.set_xlabel("schedule (exponential: beta_i = p^i)")
    right.tick_params(axis="x", rotation=45)
    legend = [Patch(fc="white", ec="black", label="box: quartiles, line: median"),
              Line2D([], [], marker="^", ls="", color=OKABE_ITO[5], label="mean"),
              Line2D([], [], marker="o", ls="", color="black", ms=3, label="one trial"),
              Line2D([], [], marker="o", ls="", mfc="none", mec=OKABE_ITO[6], ms=7,
                     label="beyond 1.5 IQR"),
              Line2D([], [], color="black", lw=1, label="whiskers: within 1.5 IQR"), *levels]
    right.legend(handles=legend, fontsize=9, loc="upper left", bbox_to_anchor=(1.0, 1.0),
                 frameon=False)
    who = ", ".join(filter(None, [task, f"{expert.upper()} expert" if expert else ""]))
    fig.suptitle(f"beta schedules on {who}: {n_trials} trials (seeds) per schedule", fontsize=10)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path)
    return fig


def _schedule_label(name: str) -> str:
    return name.removeprefix("exponential ") if name.startswith("exponential") else name


def node_counts(frame: pd.DataFrame, path: str | Path | None = None) -> plt.Figure:
    """Fig. 5: node counts per task and method (log scale), one panel per expert.

    ``frame``: columns task, expert, method, nodes (trees for BC/DAgger/VIPER, BTs for the
    synthesis methods) and, optionally, expert_status (non-``ok`` experts are greyed).
    """
    experts = [e for e in ("dqn", "ppo", "a2c") if e in set(frame["expert"])]
    experts += sorted(set(frame["expert"]) - set(experts))
    tasks = list(dict.fromkeys(frame["task"]))
    methods = methods_in(frame)
    statuses = flagged_experts(frame)
    fig, axes = plt.subplots(len(experts), 1, figsize=(FIG_WIDTH, 2.2 * len(experts) + 0.6),
                             squeeze=False, sharex=True, sharey=True)
    width = 0.84 / len(methods)
    for ax, expert in zip(axes[:, 0], experts, strict=True):
        part = frame[frame["expert"] == expert].groupby(["task", "method"])["nodes"].mean()
        for i, task in enumerate(tasks):
            if (task, expert) in statuses:
                mark_status(ax, i, statuses[(task, expert)])
        for k, method in enumerate(methods):
            xs = [i - 0.42 + width * (k + 0.5) for i, t in enumerate(tasks) if (t, method) in part]
            ys = [part[(t, method)] for t in tasks if (t, method) in part]
            ax.bar(xs, ys, width, zorder=2, **method_style(method, k))
        ax.set_yscale("log")
        ax.set_ylabel(f"{expert.upper()} expert\nnodes (log)")
    axes[-1, 0].set_xticks(range(len(tasks)), tasks, rotation=25, ha="right")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, ncol=min(4, len(methods)), loc="lower center",
               bbox_to_anchor=(0.5, 1.0), frameon=False)
    fig.text(0.5, 0.0, wrap_text("Mean over seeds: decision-tree nodes for BC, DAgger and VIPER; "
                                 "BT nodes (every node of the BT as its method's authors write "
                                 "it: BT-Espresso negates inside a condition, RE:BT-Espresso by "
                                 "an inverter) for the BT methods. BT-Espresso and "
                                 "RE:BT-Espresso are built from the BC tree.", 110),
             ha="center", va="top", fontsize=9)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path)
    return fig


def image_panels(images: dict[str, str | Path], path: str | Path | None = None,
                 widths: list[float] | None = None) -> plt.Figure:
    """Rendered drawings side by side with titles. Each is rescaled to a common height, so
    prefer :func:`ibt.export.pictures.compose`, which keeps every panel at one scale."""
    arrays = {title: plt.imread(str(p)) for title, p in images.items()}
    widths = widths or [a.shape[1] / a.shape[0] for a in arrays.values()]
    fig, axes = plt.subplots(1, len(arrays), figsize=(FIG_WIDTH, 4),
                             gridspec_kw={"width_ratios": widths}, squeeze=False)
    for ax, (title, image) in zip(axes[0], arrays.items(), strict=True):
        ax.imshow(image)
        ax.set_title(title, fontsize=10)
        ax.axis("off")
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path)
    return fig

def size_vs_retention(frame: pd.DataFrame, value: str = "retention_norm",
                      path: str | Path | None = None,
                      xlabel: str = "decision-tree nodes (log)", columns: int = 2
                      ) -> plt.Figure:
    """Tree size against retention, one line per (task, expert), a point per leaf limit.

    ``frame``: :func:`ibt.report.stats.summarise` output grouped by task, expert and max_leaf_nodes
    (columns nodes, ``value`` and the interval columns).
    """
    low_col, high_col = interval_columns(frame)
    tasks = list(dict.fromkeys(frame["task"]))
    columns = min(columns, len(tasks))
    rows = -(-len(tasks) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(min(FIG_WIDTH, 4.2 * columns),
                                                     2.9 * rows + 0.7),
                             squeeze=False, sharey=True)
    colors = {"dqn": OKABE_ITO[5], "ppo": OKABE_ITO[6], "a2c": OKABE_ITO[3]}
    markers = {"dqn": "o", "ppo": "s", "a2c": "^"}
    for ax in axes.flat[len(tasks):]:
        ax.axis("off")
    for ax, task in zip(axes.flat, tasks, strict=False):
        part = frame[frame["task"] == task]
        for expert, group in part.groupby("expert", sort=False):
            group = group.sort_values("nodes")
            ax.errorbar(group["nodes"], group[value],
                        yerr=[(group[value] - group[low_col]).clip(lower=0),
                              (group[high_col] - group[value]).clip(lower=0)],
                        fmt=f"{markers.get(expert, 'o')}-", ms=4, capsize=2,
                        color=colors.get(expert), label=f"{expert.upper()} expert")
        ax.axhline(100, color="black", lw=0.8, ls=":")
        ax.axhline(98, color=GREY, lw=0.8, ls="--")
        ax.set_xscale("log")
        plain_log_ticks(ax)
        ax.set_title(task)
        ax.set_xlabel(xlabel)
    for ax in axes[:, 0]:
        ax.set_ylabel("retention (%, random-norm.)")
    axes[0, 0].legend(loc="lower right")
    fig.text(0.5, 0.0, wrap_text(f"A point per leaf limit: mean over seeds; "
                                 f"{interval_caption(frame)}. Dotted: the expert (100 %); "
                                 "dashed: 98 %.", 100), ha="center", va="top", fontsize=9)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path)
    return fig
