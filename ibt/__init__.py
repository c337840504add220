"""Imitation-BT: distil deep-RL agents into small, readable Behavior Trees.

The data flow, one sub-package per step: ``tasks`` (the catalogue of environments) ->
``experts`` (SB3 agents) -> ``distill`` (interactive imitation into a CART tree) -> ``refine``
(by return) -> ``synth`` (rules, Espresso, the BT) -> ``bt`` (the model and its executors) ->
``evaluate`` (returns, retention) -> ``export`` (drawings, JSON, BehaviorTree.CPP) -> ``runs``
(grids and the cache) -> ``report`` (statistics, claims, figures) -> ``views`` (widgets).

``import ibt`` is cheap: the names below are imported on first use, so ``python -m ibt --help``
and ``import ibt.report.stats`` load no torch, gymnasium, scikit-learn or pandas.
"""

from __future__ import annotations

import importlib
import os
from typing import Any

# Headless rendering: pygame (used by gymnasium's and highway-env's renderers) needs no display.
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")

__version__ = "0.1.0"

#: The convenience API of notebooks: name -> the module that defines it (imported lazily).
_LAZY: dict[str, str] = {
    "BehaviorTree": "ibt.bt.model", "tick": "ibt.bt.executors",
    "config": "ibt.profiles",
    "decision_list_bt": "ibt.synth.decision_list",
    "METHODS": "ibt.distill.loop", "DistillConfig": "ibt.distill.loop",
    "load_expert": "ibt.runs.steps",
    "load_json": "ibt.bt.json_io", "save_drawing": "ibt.export.pictures",
    "save_json": "ibt.bt.json_io", "to_graphviz": "ibt.export.drawing",
    "compare_policies": "ibt.runs.steps", "distill_cached": "ibt.runs.steps",
    "iterations_frame": "ibt.runs.steps", "save_tree": "ibt.runs.steps",
    "BTPolicy": "ibt.evaluate.policies", "TreePolicy": "ibt.evaluate.policies",
    "imitation_bt": "ibt.synth.imitation", "verify": "ibt.synth.imitation",
    "get_task": "ibt.tasks.catalogue", "register_task": "ibt.tasks.catalogue",
}

__all__ = sorted(_LAZY)


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        return _submodule(__name__, name)
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later lookups skip this function
    return value


def _submodule(package: str, name: str) -> Any:
    """``package.name`` imported on first attribute access (``ibt.export.pictures.draw_bt``
    works after a bare ``import ibt``); an unknown name is an ``AttributeError``."""
    import importlib.util

    if name.startswith("_") or importlib.util.find_spec(f"{package}.{name}") is None:
        raise AttributeError(f"module {package!r} has no attribute {name!r}")
    return importlib.import_module(f"{package}.{name}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_LAZY})
