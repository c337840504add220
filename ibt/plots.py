"""One function per figure; figures never recompute results, they draw tables.

Every function returns the matplotlib figure and, given ``path`` (without suffix), saves it as
PDF and PNG atomically.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

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
        fd, tmp = tempfile.mkstemp(suffix=f".{fmt}", dir=path.parent, prefix=f".{path.name}.")
        os.close(fd)
        try:
            metadata = {"CreationDate": None} if fmt == "pdf" else {}
            fig.savefig(tmp, format=fmt, bbox_inches="tight", metadata=metadata or None)
            os.chmod(tmp, 0o644)
            os.replace(tmp, target)
        finally:
            if os.path.exists(tmp):
                os.unlink(tmp)
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
