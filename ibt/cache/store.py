"""A content-addressed cache of computed artifacts: plain data, verified on every read.

``load_or_compute(kind, params, compute, codec=...)`` hashes ``kind``, ``params`` (canonical
JSON), the kind's code version (:data:`CODE_VERSIONS`) and the versions of the packages that
change results (:data:`KEY_PACKAGES`) into a key; the entry is the folder
``<cache>/<kind>/<key>/`` holding ``payload.<suffix>`` and ``manifest.json``.

Payloads are plain data, written and read by the codecs of :mod:`ibt.cache.payloads`: ``json``,
``csv``, and for our own classes ``distillation`` and ``refinement`` (``.npz``: numeric arrays
and one JSON document; fitted scikit-learn trees rebuilt exactly from their node arrays) and
``synthesis`` (``.json``: the row and the BT in the format of ``data/trees/``). Reading one is
``np.load(allow_pickle=False)`` or ``json``: it never runs code, whoever wrote the file.

On a miss, ``compute()`` runs, then the payload and then ``manifest.json`` (parameters, codec,
the payload's SHA-256 ``payload_sha256``, code and package versions, git sha, wall time) are
written, each via a temporary file and a rename. A hit is verified before it is decoded: the
manifest must parse, name the codec asked for and the same parameters, and record a digest that
the payload's bytes match. An entry that fails any of these (an edited, truncated or swapped
payload, a manifest without digest, a payload the codec cannot read, an evaluation payload that
fails :func:`check_evaluation`) is a miss: it is recomputed and overwritten, with one
:class:`CacheWarning` naming ``kind/key``. A cache folder that cannot be written (read-only)
returns the computed values and writes nothing, with one warning per folder and process. A lookup
with another plain codec than the one the entry was written with is an error
(:class:`CodecConflict`), never an overwrite: a kind's codec changes with its code version.

A changed computation (its version bumped) or an upgraded package is a miss, never a stale hit;
``python -m ibt.cache.admin`` lists and prunes the entries left behind, verifies every
payload against its manifest, and converts the pickled payloads of the past (``migrate-plain``).

With ``IBT_CACHE_READS`` set to a folder, every lookup appends ``kind/key`` to a file there:
``make figures`` uses it to list the entries it did not read.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import math
import os
import subprocess
import time
import warnings
from collections.abc import Callable
from importlib import metadata
from pathlib import Path
from typing import Any

from ibt.cache import payloads
from ibt.files import atomic_write_bytes, atomic_write_text

CODECS = payloads.CODECS  # codec name -> payloads.Codec
TRACKED_PACKAGES = ("numpy", "scikit-learn", "stable-baselines3", "torch", "gymnasium", "pyeda",
                    "py-trees", "highway-env")
#: Packages whose upgrade can change a cached result: their versions are part of every key.
KEY_PACKAGES = ("gymnasium", "highway-env", "numpy", "scikit-learn", "stable-baselines3", "torch")

#: The code version of every cache kind, part of each key. Bump a kind's number whenever its
#: computation changes (the loop, an environment's dynamics, what the payload holds): every
#: entry of that kind then misses and is recomputed, and the old ones are listed as stale by
#: ``python -m ibt.cache.admin stale`` (removed by ``prune``). To add a kind, add a line
#: here starting at 1 and name the function that computes it; a kind not listed here is an
#: error.
CODE_VERSIONS: dict[str, int] = {
    "distill": 1,  # ibt.engine.distil.distillation: the interactive loop of ibt.distill.loop
    "expert-eval": 1,  # ibt.engine.measure.expert_evaluation
    "tree-eval": 1,  # ibt.engine.measure.evaluate_tree
    "bt-eval": 1,  # ibt.engine.measure.evaluate_bt
    "synthesis": 2,  # ibt.engine.synthesis.synthesised: synthesis, verification, the row
    "refine": 3,  # ibt.runs.front.plus_refinement: ibt.refine.by_return.refine of a distilled tree
    "front-bt": 1,  # ibt.runs.front.bt_sizes: every synthesiser's verified BT of one tree
    "executors": 1,  # ibt.runs.grid.executors_agree
    "evolve": 1,  # ibt.engine.search.evolve_one: ibt.refine.structure.evolve
    "protocol": 1,  # ibt.engine.measure.protocol_evaluation: a BT on the anchors' protocol
    "speed": 1,  # ibt.runs.grid.speed_benchmark: executors' decisions/s, per machine
    # continuous actions: ibt.engine.distil, .commands, .refine, .measure
    "box-distill": 1,  # distillation: ibt.distill.continuous.distill_box
    "box-commands": 1,  # commands: ibt.synth.commands.choose_commands
    "box-refine": 1,  # command_refinement: ibt.refine.commands.refine_commands
    "box-eval": 1,  # command_tree_evaluation: a command tree's verified BTs, return from JSON
    # relational tests: ibt.engine.distil, ibt.engine.refine, ibt.runs.front
    "distill-rel": 1,  # distillation: the loop as imitation-bt+rel (the relational learner)
    "refine-rel": 1,  # ibt.refine.relational.refine_relational of a relational tree
    # structure search with relational tests: ibt.engine.search, ibt.runs.relational_search
    "evolve-rel": 1,  # evolve_one: ibt.refine.relational_structure.evolve_relational
    "evolve-select": 1,  # evolve_rel_cached: its search chosen again on more held-out episodes
    # the pipeline: per-episode returns of a policy on a block of held-out episodes
    "returns": 1,  # ibt.engine.measure.returns_of
    # controller and oblique trees (linear commands, tests of up to four features)
    "controller-distil": 1,  # distilled: ibt.distill.controller / ibt.distill.oblique
    "controller-refine": 1,  # refined: ibt.refine.controller.refine_controller
    # learners without a kind of their own: keyed on the learner's name and version
    "learner-distil": 1,  # ibt.engine.distil.distillation_of (ibt.engine.learners.LEARNER_DISTIL)
    "learner-refine": 1,  # ibt.engine.learners.refinement_cached
}
READS_ENV = "IBT_CACHE_READS"
#: written into a cache root that ibt creates (or finds empty) at its first entry: the proof
#: that ``python -m ibt.cache.admin`` may remove entries there. Caches made before it (the
#: committed ``data/cache`` among them) are recognised by their layout instead
#: (:func:`ibt.cache.upkeep.check_cache_root`) and are not marked, so a checkout stays clean.
ROOT_MARKER = "ibt-cache.json"
ROOT_FORMAT = "ibt-cache/1"


def canonical(params: Any) -> str:
    """Canonical JSON used for hashing (sorted keys, no whitespace)."""
    return json.dumps(params, sort_keys=True, separators=(",", ":"), default=str)


def code_version(kind: str) -> int:
    """The current code version of a cache kind (:data:`CODE_VERSIONS`)."""
    try:
        return CODE_VERSIONS[kind]
    except KeyError:
        raise KeyError(f"unknown cache kind {kind!r}; add it to ibt.cache.store.CODE_VERSIONS "
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


def tree_digest(tree: Any) -> str:
    """A decision tree's identity in cache keys: the digest of its decision function
    (:func:`ibt.distill.loop.tree_signature`)."""
    from ibt.distill.loop import tree_signature

    return hashlib.sha256(tree_signature(tree)).hexdigest()[:16]


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


def payload_digest(data: bytes) -> str:
    """The SHA-256 (hex) of a payload's bytes, as its manifest records it (``payload_sha256``)."""
    return hashlib.sha256(data).hexdigest()


def manifest_text(manifest: dict[str, Any]) -> str:
    """``manifest.json``'s text (sorted keys, one space of indent)."""
    return json.dumps(manifest, indent=1, sort_keys=True, default=str)


class CacheWarning(UserWarning):
    """A cache entry that could not be used (recomputed) or stored (the value still returned)."""


class CodecConflict(ValueError):
    """An entry stored by one plain codec and looked up with another: two call sites disagree
    about a kind's format (a programming error; the entry is left as it is)."""


def read_entry(entry: str | Path, codec: str, params: dict[str, Any] | None = None) -> Any:
    """The value of the entry in folder ``entry``, verified, or :class:`LookupError` saying why not.

    The manifest must be readable, name ``codec`` (and ``params`` when given) and record the
    payload's SHA-256, which the payload's bytes must match before they are decoded (by
    ``np.load(allow_pickle=False)`` or ``json``: reading never runs code). A manifest naming
    another plain codec raises :class:`CodecConflict` instead: recomputing would overwrite the
    entry of the code that wrote it (change a kind's codec together with its code version).
    """
    entry = Path(entry)
    spec = payloads.codec(codec)
    try:
        manifest = json.loads((entry / "manifest.json").read_text())
    except FileNotFoundError:
        raise LookupError("no manifest") from None
    except (OSError, ValueError) as err:
        raise LookupError(f"unreadable manifest ({type(err).__name__})") from None
    if not isinstance(manifest, dict):
        raise LookupError("unreadable manifest (not a JSON object)")
    stored = manifest.get("codec")
    if stored != codec and stored in payloads.CODECS:
        raise CodecConflict(f"cache entry {entry.parent.name}/{entry.name} is stored as "
                            f"{stored!r} but looked up as {codec!r}: the call sites of this kind "
                            "disagree (a kind's codec changes with its CODE_VERSIONS entry)")
    if stored != codec:
        hint = (" (a pickle: run `python -m ibt.cache.admin migrate-plain --trust-pickles`)"
                if stored == "joblib" else "")
        raise LookupError(f"stored as {stored!r}, read as {codec!r}{hint}")
    if params is not None and canonical(manifest.get("params")) != canonical(params):
        raise LookupError("its manifest names other parameters")
    digest = manifest.get("payload_sha256")
    if not isinstance(digest, str):
        raise LookupError("its manifest records no payload digest")
    try:
        data = (entry / f"payload.{spec.suffix}").read_bytes()
    except OSError as err:
        raise LookupError(f"unreadable payload ({type(err).__name__})") from None
    if payload_digest(data) != digest:
        raise LookupError("the payload does not match its manifest's SHA-256")
    try:
        value = spec.loads(data)
    except Exception as err:  # a verified payload that does not decode: another schema version
        raise LookupError(f"undecodable payload ({type(err).__name__}: {err})") from None
    check_evaluation(entry.parent.name, manifest.get("params"), value)
    return value


#: kinds whose JSON payload holds evaluation numbers (checked by :func:`check_evaluation`)
EVALUATION_KINDS = ("expert-eval", "tree-eval", "bt-eval", "box-eval", "protocol")


def _finite_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def check_evaluation(kind: str, params: Any, value: Any) -> None:
    """A cheap sanity check of an evaluation payload (a digest proves only that the manifest
    and the payload agree, not that neither was forged): ``returns`` hold one finite number per
    episode the key names, means and deviations are finite, deviations and rates not negative,
    rates at most 1. :class:`LookupError` (a miss, recomputed) says which rule failed."""
    if kind not in EVALUATION_KINDS or not isinstance(value, dict):
        return
    episodes = params.get("episodes") if isinstance(params, dict) else None
    returns = value.get("returns")
    if returns is not None:
        if not isinstance(returns, list) or not all(_finite_number(r) for r in returns):
            raise LookupError("implausible payload: its returns are not all finite numbers")
        if isinstance(episodes, int) and len(returns) != episodes:
            raise LookupError(f"implausible payload: {len(returns)} returns for {episodes} "
                              "episodes")
    for name, number in value.items():
        if name in ("mean_return", "std_return") or name.endswith("_rate"):
            if not _finite_number(number):
                raise LookupError(f"implausible payload: {name} is {number!r}")
            if ((name == "std_return" or name.endswith("_rate")) and number < 0) \
                    or (name.endswith("_rate") and number > 1):
                raise LookupError(f"implausible payload: {name} is {number!r}")


def load_or_compute(kind: str, params: dict[str, Any], compute: Callable[[], Any], *,
                    cache_dir: str | Path, codec: str = "json", refresh: bool = False) -> Any:
    """Return the cached value for ``(kind, params)`` or compute, store and return it.

    ``codec`` names the payload's format (:data:`ibt.cache.payloads.CODECS`). An entry whose
    manifest exists but that does not verify (see :func:`read_entry`) is a miss, recomputed and
    overwritten, with one :class:`CacheWarning` naming ``kind/key``; a cache folder that cannot
    be written returns the computed value with one warning. ``refresh=True`` recomputes and
    overwrites (what ``make reproduce`` does).
    """
    spec = payloads.codec(codec)
    key = cache_key(kind, params)
    entry = Path(cache_dir) / kind / key
    _log_read(kind, key)
    if not refresh and (entry / "manifest.json").exists():
        try:
            return read_entry(entry, codec, params)
        except LookupError as miss:
            warnings.warn(f"cache entry {kind}/{key}: {miss}; recomputing it", CacheWarning,
                          stacklevel=2)
    start = time.perf_counter()
    value = compute()
    wall = time.perf_counter() - start
    data = spec.dumps(value)
    manifest = entry_manifest(kind, params, codec, wall_seconds=round(wall, 2),
                              payload_sha256=payload_digest(data))
    created = not entry.exists()
    try:
        mark_new_root(Path(cache_dir))
        write_entry(entry, spec.suffix, data, manifest)
    except OSError as err:
        if created:  # leave no empty folder behind
            with contextlib.suppress(OSError):
                entry.rmdir()
        root = str(Path(cache_dir).resolve())
        if root not in _UNWRITABLE:  # one warning per cache folder, not one per entry
            _UNWRITABLE.add(root)
            warnings.warn(f"cache entry {kind}/{key} not stored ({type(err).__name__}: {err}); "
                          f"returning the computed value (the cache folder {cache_dir} cannot "
                          "be written: later entries are computed and not stored, without "
                          "more warnings)", CacheWarning, stacklevel=2)
    return value


_UNWRITABLE: set[str] = set()  # cache folders already reported as not writable
_CHECKED_ROOTS: set[str] = set()  # cache roots this process has looked at for a marker


def mark_new_root(root: Path) -> None:
    """Make ``root`` with its :data:`ROOT_MARKER` where it does not exist or is empty (once per
    root and process); a root that holds anything already is left as it is."""
    if str(root) in _CHECKED_ROOTS:
        return
    _CHECKED_ROOTS.add(str(root))
    try:
        with os.scandir(root) as found:
            if next(found, None) is not None:
                return
    except FileNotFoundError:
        pass
    root.mkdir(parents=True, exist_ok=True)
    atomic_write_text(root / ROOT_MARKER, json.dumps({"format": ROOT_FORMAT}) + "\n")


def write_entry(entry: Path, suffix: str, data: bytes, manifest: dict[str, Any]) -> None:
    """Write ``payload.<suffix>``, then ``manifest.json`` (each atomically), then remove any
    other ``payload.*``: a manifest on disk always describes the payload beside it, or its
    digest tells that it does not."""
    atomic_write_bytes(entry / f"payload.{suffix}", data)
    atomic_write_text(entry / "manifest.json", manifest_text(manifest))
    for other in entry.glob("payload.*"):
        if other.name != f"payload.{suffix}":
            other.unlink()


def entry_manifest(kind: str, params: dict[str, Any], codec: str, **facts: Any
                   ) -> dict[str, Any]:
    """What ``manifest.json`` records: enough to recompute the key and to tell a stale entry."""
    return {"kind": kind, "params": params, "codec": codec, "code_version": code_version(kind),
            "key_packages": key_packages(), "versions": package_versions(),
            "git_sha": git_sha(), "created": time.strftime("%Y-%m-%dT%H:%M:%S"), **facts}


def is_cached(kind: str, params: dict[str, Any], *, cache_dir: str | Path) -> bool:
    """Whether the entry of ``(kind, params)`` exists with a manifest recording a payload digest
    (a hit for ``load_or_compute`` unless its payload was damaged since: not read here)."""
    key = cache_key(kind, params)
    _log_read(kind, key)
    try:
        manifest = json.loads((Path(cache_dir) / kind / key / "manifest.json").read_text())
    except (OSError, ValueError):
        return False
    return isinstance(manifest, dict) and isinstance(manifest.get("payload_sha256"), str)


def _log_read(kind: str, key: str) -> None:
    """Append ``kind/key`` to this process's file under ``IBT_CACHE_READS`` (when set)."""
    folder = os.environ.get(READS_ENV)
    if not folder:
        return
    Path(folder).mkdir(parents=True, exist_ok=True)
    with open(Path(folder) / f"reads-{os.getpid()}.txt", "a") as fh:
        fh.write(f"{kind}/{key}\n")
