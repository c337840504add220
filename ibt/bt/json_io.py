"""Behavior Tree JSON files (the format of :mod:`ibt.bt.model`), written atomically."""

from __future__ import annotations

from pathlib import Path

from ibt.bt.model import BehaviorTree
from ibt.files import atomic_write_text


def save_json(bt: BehaviorTree, path: str | Path) -> Path:
    """Write the tree's JSON document atomically; returns the path."""
    path = Path(path)
    atomic_write_text(path, bt.to_json() + "\n")
    return path


def load_json(path: str | Path) -> BehaviorTree:
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no behavior tree at {path}")
    return BehaviorTree.from_json(path.read_text())
