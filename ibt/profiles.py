"""Run profiles for notebooks and the command line.

``paper`` is the configuration behind the committed results: heavy steps are read from the
cache in ``data/cache`` (a hit when nothing changed) and artifacts are written to ``data/``,
``figures/`` and ``paper/``. ``smoke`` shrinks every budget so a notebook runs in seconds and
writes only to a temporary directory; CI selects it with ``IBT_PROFILE=smoke`` because nbval
cannot inject parameters. ``IBT_CACHE_DIR`` points the cache elsewhere (``make reproduce``
starts from an empty one, so an interrupted reproduction resumes); ``IBT_REFRESH=1`` recomputes
cached steps instead of loading them. ``config`` rejects unknown parameter names.
"""

from __future__ import annotations

import atexit
import dataclasses
import difflib
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ibt.paths import DATA_DIR, FIGURES_DIR, PAPER_DIR

PROFILES = ("paper", "smoke")


@dataclass(frozen=True)
class Config:
    """Budgets and output places of one run."""

    profile: str
    cache_dir: Path
    data_dir: Path
    experts_dir: Path  # the expert checkpoints, their manifest and random.csv
    figures_dir: Path
    paper_dir: Path
    n_iterations: int
    labels_scale: float  # multiplies each task's labels per iteration
    selection_episodes: int
    final_episodes: int
    n_seeds: int
    n_jobs: int
    refresh: bool
    progress: bool

    @property
    def writes_committed_outputs(self) -> bool:
        return self.profile == "paper"


def paper_settings(**kw: Any) -> dict[str, Any]:
    """The ``paper`` profile's settings (committed folders, full budgets), ``kw`` overriding."""
    return {"cache_dir": DATA_DIR / "cache", "data_dir": DATA_DIR,
            "experts_dir": DATA_DIR / "experts", "figures_dir": FIGURES_DIR,
            "paper_dir": PAPER_DIR, "n_iterations": 50, "labels_scale": 1.0,
            "selection_episodes": 20, "final_episodes": 100, "n_seeds": 3, "n_jobs": 2,
            "refresh": False, "progress": True, **kw}


_SMOKE_SCRATCH: list[Path] = []


def _smoke_scratch() -> Path:
    """``IBT_SMOKE_DIR``, or one scratch folder per process, removed when the process exits."""
    if os.environ.get("IBT_SMOKE_DIR"):
        return Path(os.environ["IBT_SMOKE_DIR"])
    if not _SMOKE_SCRATCH:
        _SMOKE_SCRATCH.append(Path(tempfile.mkdtemp(prefix="ibt-smoke-")))
        atexit.register(shutil.rmtree, _SMOKE_SCRATCH[0], True)
    return _SMOKE_SCRATCH[0]


def _smoke(**kw: Any) -> dict[str, Any]:
    scratch = _smoke_scratch()
    return {"cache_dir": scratch / "cache", "data_dir": scratch / "data",
            "experts_dir": DATA_DIR / "experts",  # the committed experts, read only
            "figures_dir": scratch / "figures", "paper_dir": scratch / "paper",
            "n_iterations": 4, "labels_scale": 0.3, "selection_episodes": 3,
            "final_episodes": 5, "n_seeds": 1, "n_jobs": 1, "refresh": False,
            "progress": False, **kw}


def config(profile: str | None = None, **overrides: Any) -> Config:
    """The run configuration of ``profile`` (``IBT_PROFILE`` wins when set) with overrides."""
    profile = os.environ.get("IBT_PROFILE") or profile or "paper"
    if profile not in PROFILES:
        raise ValueError(f"unknown profile {profile!r}; expected one of {', '.join(PROFILES)}")
    names = {f.name for f in dataclasses.fields(Config)} - {"profile"}
    unknown = sorted(set(overrides) - names)
    if unknown:
        hints = [difflib.get_close_matches(u, names, n=1) for u in unknown]
        detail = "; ".join(f"{u!r}" + (f" (did you mean {h[0]!r}?)" if h else "")
                           for u, h in zip(unknown, hints, strict=True))
        raise TypeError(f"unknown parameter {detail}; known parameters: "
                        f"{', '.join(sorted(names))}")
    values = (paper_settings if profile == "paper" else _smoke)()
    values["refresh"] = os.environ.get("IBT_REFRESH", "") == "1"
    if os.environ.get("IBT_CACHE_DIR"):  # `make reproduce`: a fresh cache, resumable
        values["cache_dir"] = os.environ["IBT_CACHE_DIR"]
    values.update(overrides)
    for key in ("cache_dir", "data_dir", "experts_dir", "figures_dir", "paper_dir"):
        values[key] = Path(values[key])
    return Config(profile=profile, **values)
