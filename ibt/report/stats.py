"""Statistics of the result tables: per-cell intervals named for what they are, aggregates.

A *cell* is one (task, expert, method) of the grid, its runs are its seeds. With fewer than
:data:`MIN_SEEDS_FOR_CI` seeds a cell's interval is the **range** (min to max) of its seeds,
never called a confidence interval: with three seeds a percentile bootstrap of the mean is
exactly [min, max] anyway. From :data:`MIN_SEEDS_FOR_CI` seeds on it is the 95 % percentile
bootstrap CI of the mean. :func:`summarise` says which, per row, in its ``interval`` column.

Statements across cells ("Imitation-BT on the stochastic tasks") use the interquartile mean
(IQM, rliable's ``aggregate_iqm``) over every run of the cells, with a 95 % CI from a
stratified bootstrap (runs resampled within their cell, as rliable's ``StratifiedBootstrap``
does; rliable's own bootstrap needs ``arch``, which does not import beside pandas 3, and equal
run counts per cell, which highway's three seeds break).

:class:`Results` reads the committed tables of a data directory; this module never imports the
grid runner, the cache or an environment.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

MIN_SEEDS_FOR_CI = 5  # below this a cell reports the range of its seeds, not a CI
CI_LEVEL = 0.95
N_BOOT = 2000
BOOT_SEED = 0
EXPERT_STATUSES = ("ok", "excluded", "constant-action")
COUNTED = "ok"  # the only expert status whose cells count in claims and "k of n" statements
CELL = ("task", "expert", "method")


@dataclass(frozen=True)
class Interval:
    """A mean and its interval: the seeds' range, or a percentile bootstrap CI."""

    mean: float
    low: float
    high: float
    n: int
    kind: str  # "range" or "ci"

    @property
    def label(self) -> str:
        """What the interval is, in words ("range over 3 seeds", "95 % ... CI over 5 seeds")."""
        return interval_label(self.kind, self.n)


def interval_label(kind: str, n: int, unit: str = "seed") -> str:
    units = f"{n} {unit}{'s' if n != 1 else ''}"
    if kind == "ci":
        return f"{CI_LEVEL:.0%} percentile bootstrap CI over {units}".replace("%", " %")
    return f"range over {units}"


def bootstrap_ci(values: Sequence[float] | np.ndarray, n_boot: int = N_BOOT,
                 level: float = CI_LEVEL, seed: int = BOOT_SEED) -> tuple[float, float]:
    """Percentile bootstrap confidence interval of the mean."""
    x = np.asarray(values, dtype=float)
    if len(x) < 2:
        return (float(x.mean()), float(x.mean())) if len(x) else (np.nan, np.nan)
    rng = np.random.default_rng(seed)
    means = rng.choice(x, size=(n_boot, len(x)), replace=True).mean(axis=1)
    alpha = (1 - level) / 2
    return float(np.quantile(means, alpha)), float(np.quantile(means, 1 - alpha))


def interval(values: Sequence[float] | np.ndarray) -> Interval:
    """The mean with the range (n < :data:`MIN_SEEDS_FOR_CI`) or the bootstrap CI."""
    x = np.asarray(values, dtype=float)
    n = len(x)
    if n == 0:
        return Interval(np.nan, np.nan, np.nan, 0, "range")
    if n < MIN_SEEDS_FOR_CI:
        return Interval(float(x.mean()), float(x.min()), float(x.max()), n, "range")
    low, high = bootstrap_ci(x)
    return Interval(float(x.mean()), low, high, n, "ci")


def summarise(results: pd.DataFrame, value: str = "retention_norm",
              by: Sequence[str] = CELL) -> pd.DataFrame:
    """Per group: ``n`` runs, the mean of ``value``, ``interval_low``/``interval_high`` and
    ``interval`` (what they are, e.g. "range over 3 seeds"), mean ``nodes``, and the
    ``expert_status`` when the rows carry one."""
    rows = []
    for key, group in results.groupby(list(by), sort=False):
        key = key if isinstance(key, tuple) else (key,)
        iv = interval(group[value].to_numpy())
        row = {**dict(zip(by, key, strict=True)), "n": iv.n, value: iv.mean,
               "interval_low": iv.low, "interval_high": iv.high, "interval": iv.label,
               "nodes": group["nodes"].mean() if "nodes" in group else np.nan}
        if "expert_status" in group:
            row["expert_status"] = group["expert_status"].iloc[0]
        rows.append(row)
    return pd.DataFrame(rows)


def error_bar_caption(summary: pd.DataFrame, what: str = "Error bars") -> str:
    """One sentence saying what the error bars of a :func:`summarise` frame are."""
    if summary is None or summary.empty or "interval" not in summary:
        return f"{what}: none (no runs)."
    kinds = summary["interval"].value_counts()
    parts = [f"{label} ({n} bar{'s' if n != 1 else ''})" if len(kinds) > 1 else label
             for label, n in kinds.items()]
    return (f"{what}: {'; '.join(parts)}. Bars are means over seeds; a range is min to max, "
            "not a confidence interval.")


def iqm(scores: np.ndarray) -> float:
    """Interquartile mean (rliable's ``aggregate_iqm``) of a flat array of scores."""
    from rliable.metrics import aggregate_iqm

    return float(aggregate_iqm(np.asarray(scores, dtype=float).reshape(1, -1)))


def stratified_iqm(cells: Sequence[Sequence[float] | np.ndarray], reps: int = N_BOOT,
                   level: float = CI_LEVEL, seed: int = BOOT_SEED) -> tuple[float, float, float]:
    """IQM over every run of ``cells`` and its stratified-bootstrap percentile CI.

    Each bootstrap sample redraws every cell's runs with replacement, within the cell.
    """
    runs = [np.asarray(c, dtype=float) for c in cells if len(c)]
    if not runs:
        return np.nan, np.nan, np.nan
    point = iqm(np.concatenate(runs))
    rng = np.random.default_rng(seed)
    draws = np.empty(reps)
    for b in range(reps):
        draws[b] = iqm(np.concatenate([c[rng.integers(0, len(c), len(c))] for c in runs]))
    alpha = (1 - level) / 2
    return point, float(np.quantile(draws, alpha)), float(np.quantile(draws, 1 - alpha))


def aggregate(rows: pd.DataFrame, value: str = "retention_norm",
              cell: Sequence[str] = ("task", "expert"), method: str = "method") -> pd.DataFrame:
    """Per method: IQM of ``value`` over all runs of its cells, with the stratified CI."""
    out = []
    for name, part in rows.groupby(method, sort=False):
        groups = [g[value].to_numpy() for _, g in part.groupby(list(cell), sort=False)]
        point, low, high = stratified_iqm(groups)
        out.append({method: name, "cells": len(groups), "runs": int(sum(map(len, groups))),
                    "iqm": point, "iqm_low": low, "iqm_high": high})
    return pd.DataFrame(out)


# --- the committed tables --------------------------------------------------------------------

class Results:
    """The committed result tables of one data directory (missing ones are ``None``)."""

    def __init__(self, data_dir: str | Path) -> None:
        self.data_dir = Path(data_dir)
        self.results_dir = self.data_dir / "results"

    def table(self, name: str) -> pd.DataFrame | None:
        path = self.results_dir / f"{name}.csv"
        return pd.read_csv(path) if path.exists() else None

    def manifest(self, name: str) -> dict[str, Any]:
        path = self.results_dir / f"{name}.manifest.json"
        return json.loads(path.read_text()) if path.exists() else {}

    def experts(self) -> pd.DataFrame | None:
        path = self.data_dir / "experts" / "manifest.csv"
        return pd.read_csv(path) if path.exists() else None

    def expert_status(self) -> dict[tuple[str, str], tuple[str, str]]:
        """``(task, algo) -> (status, evidence)`` from the experts' manifest."""
        experts = self.experts()
        if experts is None:
            return {}
        # an expert without a recorded status counts unless it missed its bar
        fallback = pd.Series(np.where(experts.get("meets_bar", True) == False,  # noqa: E712
                                      "excluded", "ok"), index=experts.index)
        status = experts.get("status", fallback).fillna(fallback)
        evidence = experts.get("status_evidence",
                               pd.Series("", index=experts.index)).fillna("")
        return {(t, a): (s, e) for t, a, s, e in
                zip(experts["task"], experts["algo"], status, evidence, strict=True)}


def with_expert_status(frame: pd.DataFrame, statuses: dict[tuple[str, str], tuple[str, str]]
                       ) -> pd.DataFrame:
    """``frame`` with an ``expert_status`` column (from the manifest; ``ok`` if unknown)."""
    out = frame.copy()
    out["expert_status"] = [statuses.get((t, e), ("ok", ""))[0]
                            for t, e in zip(out["task"], out["expert"], strict=True)]
    return out


def counted(frame: pd.DataFrame) -> pd.DataFrame:
    """The rows whose expert counts (status ``ok``); those without a status count."""
    if "expert_status" not in frame:
        return frame
    return frame[frame["expert_status"].fillna(COUNTED) == COUNTED]


def retention_table(results: pd.DataFrame, synthesis: pd.DataFrame | None = None
                    ) -> pd.DataFrame:
    """Fig. 4's rows: the tree methods of the grid plus the two BT baselines (per seed)."""
    if synthesis is None or synthesis.empty:
        return results
    baselines = synthesis[synthesis.method.isin(["bt-espresso", "re-bt-espresso"])]
    return pd.concat([results, baselines[[c for c in results.columns if c in baselines]]],
                     ignore_index=True)


def node_table(results: pd.DataFrame, synthesis: pd.DataFrame) -> pd.DataFrame:
    """Fig. 5's rows: decision-tree nodes for BC/DAgger/VIPER, BT nodes for the BT methods."""
    trees = results[results.method.isin(["bc", "dagger", "viper"])]
    cols = ["task", "expert", "method", "seed", "nodes"]
    cols += [c for c in ("expert_status",) if c in trees and c in synthesis]
    return pd.concat([trees[cols], synthesis[cols]], ignore_index=True)
