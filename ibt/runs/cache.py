"""A content-addressed cache of computed artifacts, with manifests and atomic writes.

``load_or_compute(kind, params, compute)`` hashes ``kind``, ``params`` (canonical JSON), the
kind's code version (:data:`CODE_VERSIONS`) and the versions of the packages that change
results (:data:`KEY_PACKAGES`) into a key; a hit loads ``<cache>/<kind>/<key>/payload.*``, a
miss calls ``compute()``, writes the payload and then ``manifest.json`` (parameters, code and
package versions, git sha, wall time), each via a temporary file and a rename. The manifest is
written last, so its presence means the entry is complete: an interrupted run leaves no entry
that a later run would trust. A changed computation (its version bumped) or an upgraded package
is a miss, never a stale hit; ``python -m ibt.runs.cache_admin`` lists and prunes the entries left
behind.

With ``IBT_CACHE_READS`` set to a folder, every lookup appends ``kind/key`` to a file there:
``make figures`` uses it to list the entries it did not read.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import subprocess
import time
from collections.abc import Callable
from importlib import metadata
from pathlib import Path
from typing import Any

import joblib
import pandas as pd

from ibt.files import atomic_target, atomic_write_csv, atomic_write_text

CODECS = ("joblib", "json", "csv")
TRACKED_PACKAGES = ("numpy", "scikit-learn", "stable-baselines3", "torch", "gymnasium", "pyeda",
                    "py-trees", "highway-env")
#: Packages whose upgrade can change a cached result: their versions are part of every key.
KEY_PACKAGES = ("gymnasium", "highway-env", "scikit-learn", "stable-baselines3")

#: The code version of every cache kind, part of each key. Bump a kind's number whenever its
#: computation changes (the loop, an environment's dynamics, what the payload holds): every
#: entry of that kind then misses and is recomputed, and the old ones are listed as stale by
#: ``python -m ibt.runs.cache_admin stale`` (removed by ``prune``). To add a kind, add a line here
#: starting
#: at 1 and name the function that computes it; a kind not listed here is an error.
CODE_VERSIONS: dict[str, int] = {
    "distill": 1,  # ibt.runs.pipeline.distill_cached: the interactive loop of ibt.distill.loop
    "expert-eval": 1,  # ibt.runs.grid.expert_evaluation
    "tree-eval": 1,  # ibt.runs.grid.evaluate_tree
    "bt-eval": 1,  # ibt.runs.grid.evaluate_bt
    "synthesis": 1,  # ibt.runs.grid.synthesize_run: synthesis, verification, the row
    "refine": 3,  # ibt.runs.front.refine_cached: ibt.refine.by_return.refine of a distilled tree
    "front-bt": 1,  # ibt.runs.front.bt_sizes: every synthesiser's verified BT of one tree
    "executors": 1,  # ibt.runs.grid.executors_agree
}
READS_ENV = "IBT_CACHE_READS"


def canonical(params: Any) -> str:
    """Canonical JSON used for hashing (sorted keys, no whitespace)."""
    return json.dumps(params, sort_keys=True, separators=(",", ":"), default=str)


def code_version(kind: str) -> int:
    """The current code version of a cache kind (:data:`CODE_VERSIONS`)."""
    try:
        return CODE_VERSIONS[kind]
    except KeyError:
        raise KeyError(f"unknown cache kind {kind!r}; add it to ibt.runs.cache.CODE_VERSIONS "
                       f"(known: {', '.join(sorted(CODE_VERSIONS))})") from None


def cache_key(kind: str, params: dict[str, Any], *, version: int | None = None,
              packages: dict[str, str] | None = None) -> str:
    """The entry's key: ``kind``, ``params``, the code version and :data:`KEY_PACKAGES`.

    ``version`` and ``packages`` default to the current ones (given: the key of an entry that
    was written under other versions, e.g. to check a manifest).
    """
    doc = {"kind": kind, "params": params,
           "code_version": code_version(kind) if version is None else version,
           "packages": key_packages() if packages is None else packages}
    return hashlib.sha256(canonical(doc).encode()).hexdigest()[:16]


def legacy_cache_key(kind: str, params: dict[str, Any]) -> str:
    """The key of entries written before keys carried versions (for the one-off migration)."""
    return hashlib.sha256(canonical({"kind": kind, "params": params}).encode()).hexdigest()[:16]



@functools.cache
def _version(name: str) -> str:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return "absent"


def package_versions() -> dict[str, str]:
    """The installed versions of :data:`TRACKED_PACKAGES` (recorded in manifests)."""
    return {name: _version(name) for name in TRACKED_PACKAGES}


def key_packages() -> dict[str, str]:
    """The installed versions of :data:`KEY_PACKAGES` (part of every cache key)."""
    return {name: _version(name) for name in KEY_PACKAGES}


def git_sha() -> str:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, check=True, cwd=Path(__file__).parent).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"






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
    key = cache_key(kind, params)
    entry = Path(cache_dir) / kind / key
    payload = entry / f"payload.{codec}"
    manifest = entry / "manifest.json"
    _log_read(kind, key)
    if manifest.exists() and payload.exists() and not refresh:
        return _load(payload, codec)
    start = time.perf_counter()
    value = compute()
    wall = time.perf_counter() - start
    _save(payload, value, codec)
    _save(manifest, entry_manifest(kind, params, codec, wall_seconds=round(wall, 2)), "json")
    return value


def entry_manifest(kind: str, params: dict[str, Any], codec: str, **facts: Any
                   ) -> dict[str, Any]:
    """What ``manifest.json`` records: enough to recompute the key and to tell a stale entry."""
    return {"kind": kind, "params": params, "codec": codec, "code_version": code_version(kind),
            "key_packages": key_packages(), "versions": package_versions(),
            "git_sha": git_sha(), "created": time.strftime("%Y-%m-%dT%H:%M:%S"), **facts}


def is_cached(kind: str, params: dict[str, Any], *, cache_dir: str | Path) -> bool:
    """Whether ``load_or_compute`` would be a hit (with the current versions)."""
    key = cache_key(kind, params)
    _log_read(kind, key)
    return (Path(cache_dir) / kind / key / "manifest.json").exists()


def _log_read(kind: str, key: str) -> None:
    """Append ``kind/key`` to this process's file under ``IBT_CACHE_READS`` (when set)."""
    folder = os.environ.get(READS_ENV)
    if not folder:
        return
    Path(folder).mkdir(parents=True, exist_ok=True)
    with open(Path(folder) / f"reads-{os.getpid()}.txt", "a") as fh:
        fh.write(f"{kind}/{key}\n")
