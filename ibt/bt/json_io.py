"""Behavior Tree JSON files (the format of :mod:`ibt.bt.model`), written atomically and read
strictly: a regular file of at most :data:`MAX_BT_BYTES`, UTF-8, no duplicate keys, every
number finite (:meth:`ibt.bt.model.BehaviorTree.from_dict` says which field is wrong)."""

from __future__ import annotations

import os
import stat
from pathlib import Path

from ibt.bt.model import BehaviorTree
from ibt.files import atomic_write_text

MAX_BT_BYTES = 64 << 20  # the committed BTs are below 100 kB


def save_json(bt: BehaviorTree, path: str | Path) -> Path:
    """Write the tree's JSON document atomically; returns the path."""
    path = Path(path)
    atomic_write_text(path, bt.to_json() + "\n")
    return path


def load_json(path: str | Path) -> BehaviorTree:
    """The BT of a JSON file: ``FileNotFoundError`` if there is none, ``ValueError`` naming the
    file and the problem if it is not a valid BT (a device or pipe, too large, not strict JSON,
    a bad field)."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no behavior tree at {path}")
    if not stat.S_ISREG(os.stat(path).st_mode):
        raise ValueError(f"{path} is not a regular file (a device, pipe or socket); pass the "
                         "behavior tree itself")
    with open(path, "rb") as fh:  # at most the limit + 1 bytes: a file may grow while read
        data = fh.read(MAX_BT_BYTES + 1)
    if len(data) > MAX_BT_BYTES:
        raise ValueError(f"{path} is larger than a behavior tree may be ({MAX_BT_BYTES:,} "
                         "bytes); pass the right file")
    try:
        return BehaviorTree.from_json(data)
    except ValueError as err:
        raise ValueError(f"{path} is not a valid behavior tree: {err}") from None
