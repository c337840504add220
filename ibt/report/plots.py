"""One function per figure; figures never recompute results, they draw tables.

Every function returns the matplotlib figure and, given ``path`` (without suffix), saves it as
PDF and PNG atomically. Figures are made to be read at README width (:mod:`ibt.export.readable`): at
most :data:`FIG_WIDTH` inches wide with text of at least 9 pt, and every PNG records its
smallest font so a test can check it. Colours come from the Okabe-Ito palette, which stays
distinguishable with the common colour-vision deficiencies; where two series share a hue they
also differ by hatch or marker. Every error bar is named in the figure's caption or legend.
"""

from __future__ import annotations

from itertools import pairwise
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
from matplotlib.text import Text

from ibt.export.readable import stamp_info
from ibt.files import atomic_target

SAVE_DPI = 150
FIG_WIDTH = 8.5  #: inches; at SAVE_DPI and README width, 9 pt text stays above 9 pt
plt.rcParams.update({"figure.dpi": 110, "savefig.dpi": SAVE_DPI, "axes.spines.top": False,
                     "axes.spines.right": False, "font.size": 10, "axes.titlesize": 10,
                     "axes.labelsize": 10, "xtick.labelsize": 9, "ytick.labelsize": 9,
                     "legend.fontsize": 9, "legend.title_fontsize": 9})

#: Okabe & Ito (2008), "Color universal design": black, orange, sky blue, bluish green, yellow,
#: blue, vermillion, reddish purple
OKABE_ITO = ("#000000", "#E69F00", "#56B4E9", "#009E73", "#F0E442", "#0072B2", "#D55E00",
             "#CC79A7")
GREY = "#999999"

METHOD_ORDER = ("bc", "dagger", "viper", "imitation-bt", "imitation-bt+", "imitation-bt+s",
                "imitation-bt+rel+", "imitation-bt+sr", "decision-list", "bt-espresso",
                "re-bt-espresso")
METHOD_COLORS = {"bc": GREY, "dagger": "#56B4E9", "viper": "#0072B2",
                 "imitation-bt": "#D55E00", "imitation-bt+": "#E69F00",
                 "imitation-bt+s": "#000000", "decision-list": "#CC79A7", "bt-espresso": "#F0E442",
                 "re-bt-espresso": "#009E73",
                 # relational tests: never on a panel with the two synthesisers above
                 "imitation-bt+rel+": "#CC79A7", "imitation-bt+sr": "#009E73",
                 "imitation-bt+sr*": "#56B4E9"}
#: the two baselines are synthesised from the BC tree: hatched like it is their source
METHOD_HATCHES = {"bt-espresso": "//", "re-bt-espresso": "\\\\"}
METHOD_LABELS = {"bc": "BC", "dagger": "DAgger", "viper": "VIPER", "imitation-bt": "Imitation-BT",
                 "imitation-bt+": "Imitation-BT+", "imitation-bt+s": "Imitation-BT+S",
                 "imitation-bt+rel+": "Imitation-BT+rel",
                 "imitation-bt+sr": "Imitation-BT+SR",
                 "imitation-bt+sr*": "Imitation-BT+SR*",
                 "decision-list": "decision list",
                 "bt-espresso": "BT-Espresso", "re-bt-espresso": "RE:BT-Espresso"}
BASELINE_NOTE = ("BT-Espresso and RE:BT-Espresso are synthesised from the BC tree and decide "
                 "exactly as it does, so their retention repeats BC's.")
#: the grey band's label: short lines, so labels of neighbouring tasks never overlap
STATUS_NOTE = {"excluded": "expert\nexcluded", "constant-action": "constant-\naction\nexpert"}


def methods_in(frame: pd.DataFrame) -> list[str]:
    """The frame's methods in :data:`METHOD_ORDER`, unknown ones after them (sorted)."""
    present = set(frame["method"])
    return ([m for m in METHOD_ORDER if m in present]
            + sorted(present - set(METHOD_ORDER)))


def method_style(method: str, k: int = 0) -> dict[str, object]:
    """Bar colour, hatch and label of a method (an unknown method gets a palette colour)."""
    color = METHOD_COLORS.get(method, OKABE_ITO[k % len(OKABE_ITO)])
    return {"color": color, "hatch": METHOD_HATCHES.get(method),
            "label": METHOD_LABELS.get(method, method), "edgecolor": "#333333",
            "linewidth": 0.4}


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


def _interval_columns(frame: pd.DataFrame) -> tuple[str, str]:
    """The interval's columns: ``interval_low/high`` (:mod:`ibt.report.stats`) or
    ``ci_low/high``."""
    if "interval_low" in frame:
        return "interval_low", "interval_high"
    return "ci_low", "ci_high"


def interval_caption(frame: pd.DataFrame, what: str = "error bars") -> str:
    """What the frame's intervals are, from its ``interval`` column when it has one."""
    if "interval" in frame and frame["interval"].notna().any():
        labels = list(dict.fromkeys(frame["interval"].dropna()))
        return f"{what}: " + "; ".join(labels) + " (a range is min to max)"
    return f"{what}: 95 % percentile-bootstrap CI of the mean over seeds"


def _statuses(frame: pd.DataFrame) -> dict[tuple[str, str], str]:
    """``(task, expert) -> status`` for experts that are not ``ok`` (when the column exists)."""
    if "expert_status" not in frame:
        return {}
    rows = frame.dropna(subset=["expert_status"])
    return {(t, e): s for t, e, s in zip(rows["task"], rows["expert"], rows["expert_status"],
                                         strict=True) if s != "ok"}


def _mark_status(ax: plt.Axes, i: int, status: str) -> None:
    """Grey band and a label behind task ``i``'s bars: its expert is not a valid one."""
    ax.axvspan(i - 0.48, i + 0.48, color="#dddddd", zorder=0, lw=0)
    ax.text(i, 0.98, STATUS_NOTE.get(status, status), transform=ax.get_xaxis_transform(),
            ha="center", va="top", fontsize=9, style="italic", color="#444444")


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
    low_col, high_col = _interval_columns(summary)
    experts = [e for e in ("dqn", "ppo", "a2c") if e in set(summary["expert"])]
    experts += sorted(set(summary["expert"]) - set(experts))
    tasks = list(dict.fromkeys(summary["task"]))
    methods = methods_in(summary)
    statuses = _statuses(summary)
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
                _mark_status(ax, i, statuses[(task, expert)])
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
    fig.text(0.5, 0.0, "\n".join(_wrap(n, 110) for n in notes), ha="center", va="top",
             fontsize=9)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path)
    return fig


def _wrap(text: str, width: int, break_on_hyphens: bool = True) -> str:
    import textwrap

    return "\n".join(textwrap.wrap(text, width, break_on_hyphens=break_on_hyphens))


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
    statuses = _statuses(frame)
    fig, axes = plt.subplots(len(experts), 1, figsize=(FIG_WIDTH, 2.2 * len(experts) + 0.6),
                             squeeze=False, sharex=True, sharey=True)
    width = 0.84 / len(methods)
    for ax, expert in zip(axes[:, 0], experts, strict=True):
        part = frame[frame["expert"] == expert].groupby(["task", "method"])["nodes"].mean()
        for i, task in enumerate(tasks):
            if (task, expert) in statuses:
                _mark_status(ax, i, statuses[(task, expert)])
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
    fig.text(0.5, 0.0, _wrap("Mean over seeds: decision-tree nodes for BC, DAgger and VIPER; "
                             "BT nodes (every node) for the BT methods. BT-Espresso and "
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


_NICE_TICKS = (1, 2, 3, 4, 5, 6, 8, 10, 12, 15, 20, 25, 30, 40, 50, 60, 80, 100, 120, 150, 200,
               250, 300, 400, 500, 600, 800, 1000)


def _plain_log_ticks(ax: plt.Axes, most: int = 6) -> None:
    """Plain-number ticks (``20``, not ``2 x 10^1``) on a log x axis, at most ``most`` of them
    and roughly even in log space, so that neighbouring labels never overlap."""
    from matplotlib.ticker import FixedLocator, NullFormatter, StrMethodFormatter

    low, high = ax.get_xlim()
    inside = [t for t in _NICE_TICKS if low <= t <= high]
    if len(inside) > most:
        targets = np.geomspace(inside[0], inside[-1], most)
        inside = sorted({min(inside, key=lambda t: abs(np.log(t / goal))) for goal in targets})
    if len(inside) < 3:  # a narrow range: whole numbers spread over it
        inside = sorted({round(float(t)) for t in np.geomspace(low, high, 5)[1:-1]})
    ax.xaxis.set_major_locator(FixedLocator(inside))
    ax.xaxis.set_major_formatter(StrMethodFormatter("{x:g}"))
    ax.xaxis.set_minor_formatter(NullFormatter())


def size_vs_retention(frame: pd.DataFrame, value: str = "retention_norm",
                      path: str | Path | None = None,
                      xlabel: str = "decision-tree nodes (log)", columns: int = 2
                      ) -> plt.Figure:
    """Tree size against retention, one line per (task, expert), a point per leaf limit.

    ``frame``: :func:`ibt.report.stats.summarise` output grouped by task, expert and max_leaf_nodes
    (columns nodes, ``value`` and the interval columns).
    """
    low_col, high_col = _interval_columns(frame)
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
        _plain_log_ticks(ax)
        ax.set_title(task)
        ax.set_xlabel(xlabel)
    for ax in axes[:, 0]:
        ax.set_ylabel("retention (%, random-norm.)")
    axes[0, 0].legend(loc="lower right")
    fig.text(0.5, 0.0, _wrap(f"A point per leaf limit: mean over seeds; "
                             f"{interval_caption(frame)}. Dotted: the expert (100 %); "
                             "dashed: 98 %.", 100), ha="center", va="top", fontsize=9)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path)
    return fig


def action_colors(n: int) -> list[str]:
    """Colour-blind-safe colours for ``n`` actions (blue, yellow, vermillion, ...)."""
    base = [OKABE_ITO[5], OKABE_ITO[4], OKABE_ITO[6], OKABE_ITO[2], OKABE_ITO[3], OKABE_ITO[7],
            OKABE_ITO[1], GREY]
    return [base[k % len(base)] for k in range(n)]


def decision_regions(grids: dict[str, np.ndarray], extent: tuple[float, float, float, float],
                     action_names: tuple[str, ...], axis_names: tuple[str, str],
                     path: str | Path | None = None,
                     overlays: dict[str, np.ndarray] | None = None,
                     dpi: float = SAVE_DPI) -> plt.Figure:
    """Actions over a 2-D state grid, one panel per policy (Fig. 8's right-hand side).

    ``grids[name]`` holds action indices with shape (n_y, n_x) over ``extent`` =
    (x_min, x_max, y_min, y_max). Each of ``overlays`` (name -> action grid, e.g. the paper's
    rule) is drawn on every panel as the black dashed boundary between its actions.
    """
    from matplotlib.artist import Artist
    from matplotlib.colors import ListedColormap
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    colors = action_colors(len(action_names))
    cmap = ListedColormap(colors)
    fig, axes = plt.subplots(1, len(grids), figsize=(min(FIG_WIDTH, 3.2 * len(grids) + 1.8), 3.5),
                             squeeze=False, sharey=True)
    styles = ["--", ":", "-."]
    for ax, (name, grid) in zip(axes[0], grids.items(), strict=True):
        ax.imshow(grid, origin="lower", extent=extent, aspect="auto", cmap=cmap,
                  vmin=-0.5, vmax=len(action_names) - 0.5, interpolation="nearest")
        for k, overlay in enumerate((overlays or {}).values()):
            ny, nx = overlay.shape
            xs = np.linspace(extent[0], extent[1], nx)
            ys = np.linspace(extent[2], extent[3], ny)
            levels = np.arange(len(action_names) - 1) + 0.5
            ax.contour(xs, ys, overlay, levels=levels, colors="black",
                       linestyles=styles[k % len(styles)], linewidths=1.6)
        ax.set_title(name)
        ax.set_xlabel(axis_names[0])
    axes[0, 0].set_ylabel(axis_names[1])
    handles: list[Artist] = [Patch(color=c, label=a)
                             for c, a in zip(colors, action_names, strict=True)]
    handles += [Line2D([], [], color="black", ls=styles[k % len(styles)], lw=1.6,
                       label=_wrap(name, 28))
                for k, name in enumerate(overlays or {})]
    axes[0, -1].legend(handles=handles, loc="upper left", bbox_to_anchor=(1.02, 1),
                       frameon=False)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path, dpi=dpi)
    return fig


def frozenlake_map(frame: np.ndarray, path_cells: list[int], size: int = 4,
                   title: str = "", path: str | Path | None = None,
                   dpi: float = SAVE_DPI) -> plt.Figure:
    """The rendered lake with every cell's state number (what ``state <= 6`` refers to) and
    the cells a policy walks (``path_cells``, arrows from the start)."""
    height, width = frame.shape[:2]
    cell_w, cell_h = width / size, height / size
    fig, ax = plt.subplots(figsize=(3.6, 3.9))
    ax.imshow(frame)
    for state in range(size * size):
        row, col = divmod(state, size)
        ax.text(col * cell_w + 0.93 * cell_w, row * cell_h + 0.9 * cell_h, str(state),
                ha="right", va="bottom", fontsize=11, weight="bold", color="black",
                bbox={"boxstyle": "round,pad=0.12", "fc": "white", "ec": "none", "alpha": 0.8})

    def centre(s: int) -> tuple[float, float]:
        row, col = divmod(s, size)
        return (col + 0.5) * cell_w, (row + 0.5) * cell_h

    for here, nxt in pairwise(path_cells):
        (x0, y0), (x1, y1) = centre(here), centre(nxt)
        ax.annotate("", xy=(x1, y1), xytext=(x0, y0),
                    arrowprops={"arrowstyle": "-|>", "color": OKABE_ITO[6], "lw": 2.5,
                                "mutation_scale": 16, "shrinkA": 4, "shrinkB": 4})
    ax.set_axis_off()
    ax.set_title(title or "state numbers; arrows: the path walked", fontsize=10)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path, dpi=dpi)
    return fig


NODE_TYPE_COLORS = {"selector": OKABE_ITO[0], "sequence": OKABE_ITO[5], "fallback": OKABE_ITO[2],
                    "inverter": OKABE_ITO[1], "condition": OKABE_ITO[3], "action": OKABE_ITO[7]}


def package_delivery(frame: np.ndarray, node_types: pd.DataFrame, performance: pd.DataFrame,
                     path: str | Path | None = None) -> plt.Figure:
    """Fig. 9: the domain (labelled), task performance, and the BTs' node distribution by
    type per experiment and method.

    ``node_types``: columns experiment, method and one per node type; ``performance``:
    columns experiment, policy, delivered, battery_failure_rate.
    """
    from ibt.bt.model import NODE_TYPES

    fig = plt.figure(figsize=(FIG_WIDTH, 6.6))
    grid = fig.add_gridspec(2, 2, width_ratios=[1.3, 1], height_ratios=[1, 1.15])
    domain, perf_ax, types_ax = (fig.add_subplot(grid[0, 0]), fig.add_subplot(grid[0, 1]),
                                 fig.add_subplot(grid[1, :]))
    domain.imshow(frame)
    domain.set_axis_off()
    label_package_delivery(domain)
    domain.set_title("the domain (robot: red disc)")
    groups = list(node_types[["experiment", "method"]].itertuples(index=False, name=None))
    bottom = np.zeros(len(groups))
    for kind in NODE_TYPES:
        values = node_types[kind].to_numpy(dtype=float)
        types_ax.bar(range(len(groups)), values, bottom=bottom, label=kind,
                     color=NODE_TYPE_COLORS[kind], edgecolor="white", linewidth=0.5)
        bottom += values
    for i, total in enumerate(bottom):
        types_ax.text(i, total, f"{int(total)}", ha="center", va="bottom", fontsize=9)
    types_ax.set_xticks(range(len(groups)),
                        [f"{METHOD_LABELS.get(m, m)}\n({e.upper()} expert)" for e, m in groups])
    types_ax.set_ylabel("BT nodes")
    types_ax.set_ylim(0, bottom.max() * 1.12)
    types_ax.set_title("node distribution by type")
    types_ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), frameon=False)
    perf = performance.set_index(["experiment", "policy"])
    labels = [f"{METHOD_LABELS.get(p, p)} ({e.upper()})" for e, p in perf.index]
    perf_ax.barh(range(len(perf)), perf["delivered"], color=OKABE_ITO[5])
    for i, (delivered, failures) in enumerate(zip(perf["delivered"],
                                                  perf["battery_failure_rate"], strict=True)):
        perf_ax.text(delivered, i, f" {delivered:.1f}\n {100 * failures:.0f} % empty battery",
                     va="center", fontsize=9)
    perf_ax.set_yticks(range(len(perf)), labels)
    perf_ax.invert_yaxis()
    perf_ax.set_xlabel("materials delivered per episode\n(mean over the evaluation episodes)")
    perf_ax.set_title("task performance")
    perf_ax.set_xlim(0, perf["delivered"].max() * 1.8)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path)
    return fig


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
        _plain_log_ticks(ax)
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
    fig.text(0.5, 0.0, _wrap(caption, 110, break_on_hyphens=False), ha="center", va="top",
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
        _plain_log_ticks(ax)
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
    fig.text(0.5, 0.0, _wrap(caption, 110), ha="center", va="top", fontsize=9)
    if path is not None:
        save_figure(fig, path)
    return fig
