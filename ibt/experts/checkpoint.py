"""An SB3 checkpoint, read with care: what is never unpickled, which algorithm saved it, and
the checks a loaded checkpoint must pass against its task (:func:`ibt.experts.expert.load_expert`
runs them).

**A checkpoint is code.** An SB3 zip's ``data`` entry holds cloudpickled objects (the spaces,
the policy class): loading one runs code, so load only checkpoints from a trusted source. The
entries inference does not need (learning-rate, clip-range and exploration schedules, the last
observations, episode buffers) are replaced by constants through SB3's ``custom_objects``
(:data:`NOT_UNPICKLED`) and never unpickled. A loaded checkpoint is checked against its task:
observation and action spaces compared whole (:func:`space_difference`: type, shape, dtype,
bounds, number of actions or states), and the normalisation sidecar
``<checkpoint>.obs_norm.json`` (:func:`read_obs_norm`) required where the task's expert was
trained with observation normalisation (:func:`needs_obs_norm`), its length checked.
"""

from __future__ import annotations

import json
import math
import os
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from ibt.files import check_regular
from ibt.tasks.task import Task


def norm_sidecar_path(path: Path) -> Path:
    """The observation-normalisation sidecar (``<ckpt>.obs_norm.json``) of a checkpoint."""
    return path.with_suffix(".obs_norm.json")


MAX_CHECKPOINT_BYTES = 2 << 30  # an SB3 zip larger than this is refused, not read
MAX_SIDECAR_BYTES = 16 << 20


def _constant(_progress: float) -> float:
    return 0.0


#: Pickled entries of an SB3 checkpoint that inference never uses: replaced by these constants
#: (SB3 ``custom_objects``), so their pickles are never loaded.
NOT_UNPICKLED: dict[str, Any] = {
    "learning_rate": 0.0, "lr_schedule": _constant, "clip_range": _constant,
    "exploration_schedule": _constant, "_last_obs": None, "_last_episode_starts": None,
    "_last_original_obs": None}


def check_regular_file(path: Path, limit: int, what: str) -> None:
    """``ValueError`` unless ``path`` is a regular file of at most ``limit`` bytes."""
    check_regular(path, os.stat(path), limit, what)


def _bounds_equal(a: Any, b: Any) -> bool:
    return bool(np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True))


def space_difference(saved: Any, expected: Any) -> str | None:
    """How a checkpoint's gymnasium space differs from the task's, or None when the same
    (type, shape, dtype, bounds; a Discrete's n and start)."""
    from gymnasium import spaces

    if type(saved) is not type(expected):
        return f"a {type(saved).__name__} space, not a {type(expected).__name__}"
    if isinstance(expected, spaces.Discrete):
        if (int(saved.n), int(saved.start)) != (int(expected.n), int(expected.start)):
            return f"{saved.n} values from {saved.start}, not {expected.n} from {expected.start}"
        return None
    if isinstance(expected, spaces.Box):
        if saved.shape != expected.shape:
            return f"shape {saved.shape}, not {expected.shape}"
        if saved.dtype != expected.dtype:
            return f"dtype {saved.dtype}, not {expected.dtype}"
        if not (_bounds_equal(saved.low, expected.low) and _bounds_equal(saved.high,
                                                                         expected.high)):
            return "other bounds (low/high)"
        return None
    return None if saved == expected else f"{saved}, not {expected}"


def read_obs_norm(path: Path, n_features: int) -> dict[str, Any]:
    """A normalisation sidecar, checked: ``mean`` and ``var`` of ``n_features`` finite numbers
    (var >= 0), finite ``epsilon`` >= 0 and ``clip`` > 0; ``ValueError`` names the file."""
    check_regular_file(path, MAX_SIDECAR_BYTES, "normalisation sidecar")
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as err:
        raise ValueError(f"{path} is not a readable normalisation sidecar ({type(err).__name__}:"
                         f" {err}); copy it again from where the checkpoint was trained") from None

    def numbers(key: str) -> list[float] | None:
        values = doc.get(key) if isinstance(doc, dict) else None
        if not isinstance(values, list) or not all(
                type(v) in (int, float) and math.isfinite(v) for v in values):
            return None
        return values

    mean, var = numbers("mean"), numbers("var")
    raw: list[Any] = [doc.get(k) if isinstance(doc, dict) else None
                      for k in ("epsilon", "clip")]
    scalars = [float(v) for v in raw if type(v) in (int, float) and math.isfinite(v)]
    if mean is None or var is None or len(scalars) != 2:
        raise ValueError(f"{path} is not a normalisation sidecar (expected finite 'mean', 'var', "
                         "'epsilon' and 'clip'); copy it again from where the checkpoint was "
                         "trained")
    if len(mean) != n_features or len(var) != n_features:
        raise ValueError(f"{path} normalises {len(mean)} means and {len(var)} variances, but the "
                         f"task observes {n_features} features; it belongs to another checkpoint")
    if min(var) < 0 or scalars[0] < 0 or scalars[1] <= 0:
        raise ValueError(f"{path} has a negative variance or epsilon, or a clip <= 0; copy it "
                         "again from where the checkpoint was trained")
    return {"mean": mean, "var": var, "epsilon": float(scalars[0]), "clip": float(scalars[1])}


def needs_obs_norm(task: Task, algo: str) -> bool:
    """Whether the task's catalogue trains its ``algo`` expert with observation normalisation
    (False for an algorithm without a catalogue row: a user's checkpoint)."""
    return algo in dict(task.experts) and task.hyperparams(algo).normalize is True

def checkpoint_algo(path: str | Path) -> str | None:
    """The algorithm an SB3 checkpoint was saved by (from its ``data`` entry), if readable."""
    try:
        with zipfile.ZipFile(path) as archive:
            data = json.loads(archive.read("data"))
    except (OSError, KeyError, ValueError, zipfile.BadZipFile):
        return None
    if "target_entropy" in data:
        return "sac"
    if "target_policy_noise" in data:
        return "td3"
    if "exploration_schedule" in data or "target_update_interval" in data:
        return "dqn"
    if "clip_range" in data:
        return "ppo"
    if "vf_coef" in data:
        return "a2c"
    return None
