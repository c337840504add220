"""A content-addressed cache of computed artifacts, with manifests and atomic writes.

``load_or_compute(kind, params, compute)`` hashes ``kind`` and ``params`` (canonical JSON) into
a key; a hit loads ``<cache>/<kind>/<key>/payload.*``, a miss calls ``compute()``, writes the
payload and then ``manifest.json`` (parameters, package versions, git sha, wall time), each via
a temporary file and a rename. The manifest is written last, so its presence means the entry is
complete: an interrupted run leaves no entry that a later run would trust.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from importlib import metadata
from pathlib import Path
from typing import Any

import joblib
import pandas as pd

CODECS = ("joblib", "json", "csv")
TRACKED_PACKAGES = ("numpy", "scikit-learn", "stable-baselines3", "torch", "gymnasium", "pyeda",
                    "py-trees", "highway-env")


def canonical(params: Any) -> str:
    """Canonical JSON used for hashing (sorted keys, no whitespace)."""
    return json.dumps(params, sort_keys=True, separators=(",", ":"), default=str)


def cache_key(kind: str, params: dict[str, Any]) -> str:
    return hashlib.sha256(canonical({"kind": kind, "params": params}).encode()).hexdigest()[:16]


def file_digest(path: str | Path) -> str:
    """sha256 of a file (used to key results on the exact expert checkpoint)."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()[:16]


def package_versions() -> dict[str, str]:
    out = {}
    for name in TRACKED_PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "absent"
    return out


def git_sha() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, check=True, cwd=Path(__file__).parent).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


@contextmanager
def atomic_target(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path``, renamed onto it when the block succeeds.

    Whatever writes to the yielded path (our code, joblib, SB3, matplotlib), an interrupted or
    failed write leaves ``path`` as it was and no temporary file behind.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(suffix=path.suffix, dir=path.parent, prefix=f".{path.name}.")
    os.close(fd)
    try:
        yield Path(tmp)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    with atomic_target(path) as tmp:
        tmp.write_bytes(data)


def atomic_write_text(path: str | Path, text: str) -> None:
    atomic_write_bytes(Path(path), text.encode())


def atomic_write_csv(path: str | Path, frame: pd.DataFrame) -> None:
    atomic_write_text(path, frame.to_csv(index=False, lineterminator="\n"))


def _save(path: Path, value: Any, codec: str) -> None:
    if codec == "json":
        atomic_write_text(path, json.dumps(value, indent=1, sort_keys=True, default=str))
    elif codec == "csv":
        atomic_write_csv(path, value)
    else:
        with atomic_target(path) as tmp:
            joblib.dump(value, tmp, compress=3)


def _load(path: Path, codec: str) -> Any:
    if codec == "json":
        return json.loads(path.read_text())
    if codec == "csv":
        return pd.read_csv(path)
    return joblib.load(path)


def load_or_compute(kind: str, params: dict[str, Any], compute: Callable[[], Any], *,
                    cache_dir: str | Path, codec: str = "joblib", refresh: bool = False) -> Any:
    """Return the cached value for ``(kind, params)`` or compute, store and return it.

    ``refresh=True`` recomputes and overwrites (what ``make reproduce`` does).
    """
    if codec not in CODECS:
        raise ValueError(f"unknown codec {codec!r}; expected one of {CODECS}")
    entry = Path(cache_dir) / kind / cache_key(kind, params)
    payload = entry / f"payload.{codec}"
    manifest = entry / "manifest.json"
    if manifest.exists() and payload.exists() and not refresh:
        return _load(payload, codec)
    start = time.perf_counter()
    value = compute()
    wall = time.perf_counter() - start
    _save(payload, value, codec)
    _save(manifest, {"kind": kind, "params": params, "codec": codec,
                     "wall_seconds": round(wall, 2), "versions": package_versions(),
                     "git_sha": git_sha(), "created": time.strftime("%Y-%m-%dT%H:%M:%S")},
          "json")
    return value


def is_cached(kind: str, params: dict[str, Any], *, cache_dir: str | Path) -> bool:
    entry = Path(cache_dir) / kind / cache_key(kind, params)
    return (entry / "manifest.json").exists()
