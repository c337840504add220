"""Pictures of tasks and of what policies do in them: decision regions over a 2-D state grid
(Fig. 8), the FrozenLake map with a policy's path (Fig. 7) and the package-delivery domain
with its BTs' node types (Fig. 9). Each draws the arrays and tables it is given (rendered
frames, action grids, node counts) and saves like every figure
(:func:`ibt.report.plots.save_figure`).
"""

from __future__ import annotations

from itertools import pairwise
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

from ibt.report.figure_style import FIG_WIDTH, GREY, METHOD_LABELS, OKABE_ITO, SAVE_DPI, wrap_text
from ibt.report.plots import label_package_delivery, save_figure


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
                       label=wrap_text(name, 28))
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
