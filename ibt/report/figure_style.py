"""The house style every figure shares: size, fonts, colours, method names, captions.

Figures are made to be read at README width (:mod:`ibt.export.readable`): at most
:data:`FIG_WIDTH` inches wide with text of at least 9 pt. Colours come from the Okabe-Ito
palette, which stays distinguishable with the common colour-vision deficiencies; where two
series share a hue they also differ by hatch or marker. Every error bar is named in the figure's
caption or legend (:func:`interval_caption`). Importing this module sets matplotlib's defaults
(``plt.rcParams``) for every figure of :mod:`ibt.report.plots`, :mod:`ibt.report.task_figures`
and :mod:`ibt.report.front_figures`.
"""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

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

def interval_columns(frame: pd.DataFrame) -> tuple[str, str]:
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


def flagged_experts(frame: pd.DataFrame) -> dict[tuple[str, str], str]:
    """``(task, expert) -> status`` for experts that are not ``ok`` (when the column exists)."""
    if "expert_status" not in frame:
        return {}
    rows = frame.dropna(subset=["expert_status"])
    return {(t, e): s for t, e, s in zip(rows["task"], rows["expert"], rows["expert_status"],
                                         strict=True) if s != "ok"}


def mark_status(ax: plt.Axes, i: int, status: str) -> None:
    """Grey band and a label behind task ``i``'s bars: its expert is not a valid one."""
    ax.axvspan(i - 0.48, i + 0.48, color="#dddddd", zorder=0, lw=0)
    ax.text(i, 0.98, STATUS_NOTE.get(status, status), transform=ax.get_xaxis_transform(),
            ha="center", va="top", fontsize=9, style="italic", color="#444444")

def wrap_text(text: str, width: int, break_on_hyphens: bool = True) -> str:
    """``text`` wrapped at ``width`` characters, lines joined by newlines (figure captions)."""
    import textwrap

    return "\n".join(textwrap.wrap(text, width, break_on_hyphens=break_on_hyphens))

_NICE_TICKS = (1, 2, 3, 4, 5, 6, 8, 10, 12, 15, 20, 25, 30, 40, 50, 60, 80, 100, 120, 150, 200,
               250, 300, 400, 500, 600, 800, 1000)


def plain_log_ticks(ax: plt.Axes, most: int = 6) -> None:
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
