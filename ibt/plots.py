"""One function per figure; figures never recompute results, they draw tables.

Every function returns the matplotlib figure and, given ``path`` (without suffix), saves it as
PDF and PNG atomically.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from ibt.artifacts import atomic_target

plt.rcParams.update({"figure.dpi": 110, "savefig.dpi": 150, "axes.spines.top": False,
                     "axes.spines.right": False, "font.size": 10})


def save_figure(fig: plt.Figure, path: str | Path, formats: tuple[str, ...] = ("pdf", "png")
                ) -> list[Path]:
    """Save ``fig`` as ``<path>.<fmt>`` for each format, via temp files and renames."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    written = []
    for fmt in formats:
        target = path.with_suffix(f".{fmt}")
        metadata = {"CreationDate": None} if fmt == "pdf" else None
        with atomic_target(target) as tmp:
            fig.savefig(tmp, format=fmt, bbox_inches="tight", metadata=metadata)
        written.append(target)
    return written


def distillation_history(history: pd.DataFrame, title: str = "", path: str | Path | None = None
                         ) -> plt.Figure:
    """Held-out return of each iteration's tree, with beta and the chosen tree marked."""
    fig, ax = plt.subplots(figsize=(7, 3.2))
    ax.errorbar(history["iteration"], history["selection_mean"], yerr=history["selection_std"],
                fmt="o-", ms=3, lw=1, capsize=2, label="tree (held-out episodes)")
    best = history[history["best"]]
    ax.plot(best["iteration"], best["selection_mean"], "r*", ms=14, label="chosen tree")
    ax.set_xlabel("iteration")
    ax.set_ylabel("mean return")
    beta_ax = ax.twinx()
    beta_ax.plot(history["iteration"], history["beta"], color="grey", ls="--", lw=1)
    beta_ax.set_ylabel("beta (expert share)", color="grey")
    beta_ax.set_ylim(0, 1.05)
    ax.legend(loc="lower left", fontsize=8)
    ax.set_title(title)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path)
    return fig


def task_frames(frames: dict[str, np.ndarray], path: str | Path | None = None,
                columns: int = 4) -> plt.Figure:
    """A grid of rendered frames, one per task (``{task: rgb array}``)."""
    rows = -(-len(frames) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(3.2 * columns, 2.6 * rows), squeeze=False)
    for ax in axes.flat:
        ax.axis("off")
    for ax, (name, frame) in zip(axes.flat, frames.items(), strict=False):
        ax.imshow(frame)
        ax.set_title(name, fontsize=9)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path)
    return fig


METHOD_ORDER = ("bc", "dagger", "viper", "imitation-bt", "bt-espresso", "re-bt-espresso")
METHOD_COLORS = {"bc": "#9e9e9e", "dagger": "#6baed6", "viper": "#3182bd",
                 "imitation-bt": "#e6550d", "bt-espresso": "#a1d99b", "re-bt-espresso": "#31a354"}


def retention_grid(summary: pd.DataFrame, value: str = "retention_norm",
                   path: str | Path | None = None) -> plt.Figure:
    """Fig. 4: mean retention (95 % bootstrap CI) per task and method, one panel per expert.

    ``summary`` is :func:`ibt.experiments.summarise` output (columns task, expert, method,
    ``value``, ci_low, ci_high).
    """
    experts = [e for e in ("dqn", "ppo", "a2c") if e in set(summary["expert"])]
    tasks = list(dict.fromkeys(summary["task"]))
    methods = [m for m in METHOD_ORDER if m in set(summary["method"])]
    fig, axes = plt.subplots(len(experts), 1, figsize=(max(7, 1.3 * len(tasks)),
                                                         2.6 * len(experts)),
                             squeeze=False, sharex=True)
    width = 0.8 / len(methods)
    for ax, expert in zip(axes[:, 0], experts, strict=True):
        part = summary[summary["expert"] == expert].set_index(["task", "method"])
        for k, method in enumerate(methods):
            xs, ys, lo, hi = [], [], [], []
            for i, task in enumerate(tasks):
                if (task, method) in part.index:
                    row = part.loc[(task, method)]
                    xs.append(i - 0.4 + width * (k + 0.5))
                    ys.append(row[value])
                    lo.append(row[value] - row["ci_low"])
                    hi.append(row["ci_high"] - row[value])
            ax.bar(xs, ys, width, yerr=[lo, hi], capsize=2, label=method,
                   color=METHOD_COLORS.get(method), edgecolor="white", linewidth=0.5)
        ax.axhline(100, color="black", lw=0.8, ls=":")
        ax.set_ylabel(f"{expert.upper()} expert\nretention (%)")
        ax.set_ylim(min(0, float(np.nanmin(summary[value])) - 5), 115)
    axes[-1, 0].set_xticks(range(len(tasks)), tasks, rotation=20, ha="right")
    axes[0, 0].legend(ncol=len(methods), fontsize=8, loc="lower center",
                      bbox_to_anchor=(0.5, 1.02), frameon=False)
    label = "random-normalised" if value == "retention_norm" else "raw"
    fig.suptitle(f"Performance retention ({label}: 0 = random policy, 100 = expert)", y=1.04,
                 fontsize=10)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path)
    return fig


def beta_analysis(curves: pd.DataFrame, results: pd.DataFrame, path: str | Path | None = None
                  ) -> plt.Figure:
    """Fig. 3: beta schedules (left) and the final returns of each schedule's trials (right).

    ``curves``: columns schedule, iteration, beta. ``results``: columns schedule, mean_return.
    """
    order = list(dict.fromkeys(curves["schedule"]))
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 3.8),
                                      gridspec_kw={"width_ratios": [1, 1.4]})
    cmap = plt.get_cmap("viridis")
    for k, name in enumerate(order):
        part = curves[curves["schedule"] == name]
        style = {"color": "#e6550d", "lw": 2.5} if name == "linear" else {
            "color": cmap(k / max(1, len(order) - 1)), "lw": 1}
        left.plot(part["iteration"], part["beta"], label=name, **style)
    left.set_xlabel("iteration i")
    left.set_ylabel("beta_i (probability the expert acts)")
    left.legend(fontsize=7, ncol=2)
    data = [results.loc[results["schedule"] == name, "mean_return"].to_numpy() for name in order]
    right.boxplot(data, tick_labels=order, showmeans=True)
    for k, values in enumerate(data, start=1):
        right.plot(np.full(len(values), k), values, "o", ms=3, alpha=0.6, color="black")
    right.set_ylabel("final mean return (100 episodes)")
    right.tick_params(axis="x", rotation=45)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path)
    return fig


def node_counts(frame: pd.DataFrame, path: str | Path | None = None) -> plt.Figure:
    """Fig. 5: node counts per task and method (log scale), one panel per expert.

    ``frame``: columns task, expert, method, nodes (trees for BC/DAgger/VIPER, BTs for the
    synthesis methods).
    """
    experts = [e for e in ("dqn", "ppo", "a2c") if e in set(frame["expert"])]
    tasks = list(dict.fromkeys(frame["task"]))
    methods = [m for m in METHOD_ORDER if m in set(frame["method"])]
    fig, axes = plt.subplots(1, len(experts), figsize=(4.2 * len(experts), 3.8), squeeze=False,
                             sharey=True)
    width = 0.8 / len(methods)
    for ax, expert in zip(axes[0], experts, strict=True):
        part = frame[frame["expert"] == expert].groupby(["task", "method"])["nodes"].mean()
        for k, method in enumerate(methods):
            xs = [i - 0.4 + width * (k + 0.5) for i, t in enumerate(tasks) if (t, method) in part]
            ys = [part[(t, method)] for t in tasks if (t, method) in part]
            ax.bar(xs, ys, width, label=method, color=METHOD_COLORS.get(method))
        ax.set_yscale("log")
        ax.set_title(f"{expert.upper()} expert", fontsize=10)
        ax.set_xticks(range(len(tasks)), tasks, rotation=35, ha="right", fontsize=8)
    axes[0, 0].set_ylabel("nodes (log scale)")
    axes[0, 0].legend(fontsize=7, ncol=2)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path)
    return fig


def image_panels(images: dict[str, str | Path], path: str | Path | None = None,
                 widths: list[float] | None = None) -> plt.Figure:
    """Rendered drawings side by side with titles (Figs. 6-8)."""
    arrays = {title: plt.imread(str(p)) for title, p in images.items()}
    widths = widths or [a.shape[1] / a.shape[0] for a in arrays.values()]
    fig, axes = plt.subplots(1, len(arrays), figsize=(min(4.0 * sum(widths), 22), 5),
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
                      xlabel: str = "decision-tree nodes (log)") -> plt.Figure:
    """Tree size against retention, one line per (task, expert), a point per leaf limit.

    ``frame``: :func:`ibt.experiments.summarise` output grouped by task, expert and
    max_leaf_nodes (columns nodes, ``value``, ci_low, ci_high).
    """
    tasks = list(dict.fromkeys(frame["task"]))
    fig, axes = plt.subplots(1, len(tasks), figsize=(3.6 * len(tasks), 3.4), squeeze=False,
                             sharey=True)
    for ax, task in zip(axes[0], tasks, strict=True):
        part = frame[frame["task"] == task]
        for expert, rows in part.groupby("expert", sort=False):
            rows = rows.sort_values("nodes")
            ax.errorbar(rows["nodes"], rows[value],
                        yerr=[rows[value] - rows["ci_low"], rows["ci_high"] - rows[value]],
                        fmt="o-", ms=3, capsize=2, label=expert.upper())
        ax.axhline(100, color="black", lw=0.8, ls=":")
        ax.axhline(98, color="grey", lw=0.8, ls="--")
        ax.set_xscale("log")
        ax.set_title(task, fontsize=10)
        ax.set_xlabel(xlabel)
    axes[0, 0].set_ylabel("retention (%, random-normalised)")
    axes[0, 0].legend(fontsize=8)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path)
    return fig


def decision_regions(grids: dict[str, np.ndarray], extent: tuple[float, float, float, float],
                     action_names: tuple[str, ...], axis_names: tuple[str, str],
                     path: str | Path | None = None) -> plt.Figure:
    """Actions over a 2-D state grid, one panel per policy (Fig. 8's right-hand side).

    ``grids[name]`` holds action indices with shape (n_y, n_x) over ``extent`` =
    (x_min, x_max, y_min, y_max).
    """
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    colors = ["#4575b4", "#ffffbf", "#d73027", "#91bfdb", "#fc8d59"][: len(action_names)]
    cmap = ListedColormap(colors)
    fig, axes = plt.subplots(1, len(grids), figsize=(4.2 * len(grids), 3.4), squeeze=False,
                             sharey=True)
    for ax, (name, grid) in zip(axes[0], grids.items(), strict=True):
        ax.imshow(grid, origin="lower", extent=extent, aspect="auto", cmap=cmap,
                  vmin=-0.5, vmax=len(action_names) - 0.5, interpolation="nearest")
        ax.set_title(name, fontsize=10)
        ax.set_xlabel(axis_names[0])
    axes[0, 0].set_ylabel(axis_names[1])
    handles = [Patch(color=c, label=a) for c, a in zip(colors, action_names, strict=True)]
    axes[0, -1].legend(handles=handles, fontsize=8, loc="upper left", bbox_to_anchor=(1, 1))
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path)
    return fig


def package_delivery(frame: np.ndarray, node_types: pd.DataFrame, performance: pd.DataFrame,
                     path: str | Path | None = None) -> plt.Figure:
    """Fig. 9: the domain (left), BT node distribution by type per experiment and method
    (middle), and task performance (right).

    ``node_types``: columns experiment, method and one per node type; ``performance``:
    columns experiment, policy, delivered, battery_failure_rate.
    """
    from ibt.bt import NODE_TYPES

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8),
                             gridspec_kw={"width_ratios": [1.1, 1.6, 1.3]})
    axes[0].imshow(frame)
    axes[0].set_axis_off()
    axes[0].set_title("package delivery (zones, depot, charger)", fontsize=9)
    groups = list(node_types[["experiment", "method"]].itertuples(index=False, name=None))
    bottom = np.zeros(len(groups))
    colors = plt.get_cmap("tab10")
    for k, kind in enumerate(NODE_TYPES):
        values = node_types[kind].to_numpy(dtype=float)
        axes[1].bar(range(len(groups)), values, bottom=bottom, label=kind, color=colors(k))
        bottom += values
    for i, total in enumerate(bottom):
        axes[1].text(i, total, f"{int(total)}", ha="center", va="bottom", fontsize=8)
    axes[1].set_xticks(range(len(groups)), [f"{m}\n({e.upper()} expert)" for e, m in groups],
                       fontsize=7)
    axes[1].set_ylabel("BT nodes")
    axes[1].set_title("node distribution by type", fontsize=9)
    axes[1].legend(fontsize=7, ncol=2)
    perf = performance.set_index(["experiment", "policy"])
    labels = [f"{p}\n({e.upper()})" for e, p in perf.index]
    axes[2].barh(range(len(perf)), perf["delivered"], color="#3182bd")
    for i, (delivered, failures) in enumerate(zip(perf["delivered"],
                                                  perf["battery_failure_rate"], strict=True)):
        axes[2].text(delivered, i, f" {delivered:.1f} ({100 * failures:.0f}% empty battery)",
                     va="center", fontsize=7)
    axes[2].set_yticks(range(len(perf)), labels, fontsize=7)
    axes[2].invert_yaxis()
    axes[2].set_xlabel("materials delivered per episode")
    axes[2].set_title("task performance", fontsize=9)
    axes[2].set_xlim(0, perf["delivered"].max() * 1.6)
    fig.tight_layout()
    if path is not None:
        save_figure(fig, path)
    return fig
