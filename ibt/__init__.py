"""Imitation-BT: distil deep-RL agents into small, readable Behavior Trees.

The data flow, one module per step: ``tasks`` (environments) -> ``experts`` (SB3 agents) ->
``distill`` (interactive imitation into a CART tree) -> ``rules`` / ``logic`` / ``synthesis``
(Action Template Library, Espresso, the BT) -> ``evaluate`` (returns, retention) -> ``plots``.
Importing ``ibt`` registers the package-delivery environment with gymnasium.
"""

import os

# Headless rendering: pygame (used by gymnasium's and highway-env's renderers) needs no display.
os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")

from ibt import envs  # noqa: F401  (registers PackageDelivery-v0)
from ibt.bt import BehaviorTree, tick
from ibt.config import config
from ibt.decision_list import decision_list_bt
from ibt.distill import METHODS, DistillConfig, distill
from ibt.experts import load_expert
from ibt.export import load_json, save_drawing, save_json, to_graphviz
from ibt.pipeline import compare_policies, distill_cached, iterations_frame, save_tree
from ibt.policies import BTPolicy, TreePolicy
from ibt.synthesis import imitation_bt, verify
from ibt.tasks import get_task, register_task

__version__ = "0.1.0"

__all__ = [
    "METHODS", "BTPolicy", "BehaviorTree", "DistillConfig", "TreePolicy", "compare_policies",
    "config", "decision_list_bt", "distill", "distill_cached", "get_task", "imitation_bt",
    "iterations_frame", "load_expert", "load_json", "register_task", "save_drawing", "save_json",
    "save_tree", "tick", "to_graphviz", "verify",
]
