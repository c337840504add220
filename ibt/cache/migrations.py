"""Cache migrations: the one-off re-keying of 2026-11 and the plain-data conversion of 2026-12
(``python -m ibt.cache.admin migrate`` and ``migrate-plain``).

Migrations: ``migrate`` is the one-off re-keying of 2026-11. ``migrate-plain --trust-pickles``
is the one of 2026-12: every ``payload.joblib`` (``distill``, ``refine``, ``synthesis`` entries,
pickles of our classes under their module paths before the sub-package reorganisation, mapped by
:data:`LEGACY_MODULES`) is unpickled, encoded by its plain codec (:data:`PLAIN_CODECS`), decoded
again and compared with the unpickled value exactly, written as ``payload.npz`` or
``payload.json``; the manifest is rewritten with the new ``codec`` and ``payload_sha256`` (nothing
else changes: keys, and so the folders, stay) and the pickle is deleted. JSON and CSV entries
whose manifest lacks a digest get one. Unpickling runs whatever code a pickle names, so without
``--trust-pickles`` the command refuses (exit 2) while any pickle is left; it is idempotent, and a
re-run finishes an interrupted one.
"""

from __future__ import annotations

import os
import time
from collections import Counter, defaultdict
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ibt.cache import payloads
from ibt.cache.store import (
    CODE_VERSIONS,
    KEY_PACKAGES,
    cache_key,
    key_packages,
    manifest_text,
    payload_digest,
)
from ibt.cache.upkeep import entries, read_manifest
from ibt.files import atomic_write_bytes, atomic_write_text

# --- the one-off migration of 2026-11 ---------------------------------------------------------

@dataclass
class Migration:
    """What :func:`migrate` did."""

    migrated: Counter = field(default_factory=Counter)  # per kind
    refused: list[tuple[str, str]] = field(default_factory=list)  # (entry, why)
    collisions: list[str] = field(default_factory=list)  # trees the old signature confused
    within_run_collisions: int = 0
    already_current: int = 0

    def summary(self) -> str:
        lines = [f"migrated {sum(self.migrated.values())} entries: "
                 + ", ".join(f"{k} {n}" for k, n in sorted(self.migrated.items())),
                 f"already current: {self.already_current}",
                 f"refused (stale or unmappable, left in place): {len(self.refused)}",
                 *[f"  {name}: {why}" for name, why in self.refused],
                 f"old tree signatures shared by trees with other classes_ within a run: "
                 f"{self.within_run_collisions}",
                 f"old tree signatures that meant two decision functions on one task: "
                 f"{len(self.collisions)}", *[f"  {c}" for c in self.collisions]]
        return "\n".join(lines)


def _old_signature(tree: Any) -> bytes:
    """The tree signature before 2026-11 (no ``classes_``): only to map old keys."""
    import numpy as np

    t = tree.tree_
    parts = [t.feature, t.threshold, t.children_left, t.children_right,
             np.argmax(t.value[:, 0, :], axis=1)]
    return b"".join(np.ascontiguousarray(p).tobytes() for p in parts)


def signature_map(cache_dir: str | Path, report: Migration) -> dict[tuple[str, str], str]:
    """(task, old signature hex) -> new tree digest, over every tree of every cached run.

    An old signature that stands for two different decision functions on one task (the
    collision the old signature allowed) is left out of the map and reported.
    """
    from ibt.cache.store import tree_digest

    found: dict[tuple[str, str], set[str]] = defaultdict(set)
    for entry in entries(cache_dir):
        if entry.kind != "distill" or entry.status in ("incomplete", "orphan"):
            continue
        manifest = read_manifest(entry.path) or {}
        if manifest.get("codec") not in payloads.CODECS:  # a pickle: migrate-plain it first
            report.refused.append((entry.name, f"codec {manifest.get('codec')!r}: its trees "
                                   "were not read (run migrate-plain first)"))
            continue
        run = payloads.CODECS[manifest["codec"]].loads(_payload_path(entry.path,
                                                                     manifest).read_bytes())
        seen: dict[bytes, str] = {}
        for tree in run.trees:
            old, new = _old_signature(tree), tree_digest(tree)
            if seen.setdefault(old, new) != new:
                report.within_run_collisions += 1
            found[(run.task, old.hex())].add(new)
    out: dict[tuple[str, str], str] = {}
    for (task, old_hex), digests in found.items():
        if len(digests) == 1:
            out[(task, old_hex)] = next(iter(digests))
        else:
            report.collisions.append(f"{task}: one old signature, digests {sorted(digests)}")
    return out


def _migrated_params(kind: str, params: dict[str, Any],
                     signatures: dict[tuple[str, str], str]) -> dict[str, Any]:
    """The params of a legacy entry under today's keys (raises ``LookupError`` if unmappable)."""
    params = dict(params)
    if kind == "synthesis":  # SYNTHESIS_VERSION moved into CODE_VERSIONS["synthesis"]
        version = params.pop("version", None)
        if version != CODE_VERSIONS["synthesis"]:
            raise LookupError(f"synthesis version {version} (now {CODE_VERSIONS['synthesis']})")
    if "tree" in params:
        old = (params["task"], params["tree"])
        if old not in signatures:
            raise LookupError("its tree is in no cached run (or its old signature is ambiguous)")
        params["tree"] = signatures[old]
    return params


def migrate(cache_dir: str | Path, *, dry_run: bool = False) -> Migration:
    """Re-key every legacy entry to today's keys, in place (idempotent; safe to re-run).

    An entry moves only when the key packages its manifest recorded equal the installed ones
    (else it is stale and reported). Entries keyed on a tree get the new ``classes_``-aware
    tree digest, mapped from the trees of every cached distillation run. The manifest is
    rewritten first (with ``migrated_from``), then the folder renamed: an interruption leaves
    an entry that a re-run finishes moving.
    """
    report = Migration()
    signatures = signature_map(cache_dir, report)
    now = key_packages()
    for entry in list(entries(cache_dir)):
        manifest = read_manifest(entry.path)
        if entry.status == "current":
            report.already_current += 1
            continue
        if entry.status == "orphan" and manifest and "code_version" in manifest \
                and manifest["code_version"] == CODE_VERSIONS.get(entry.kind) \
                and manifest.get("key_packages") == now:
            target = entry.path.parent / cache_key(entry.kind, manifest["params"])
        elif entry.status == "stale" and manifest and "params" in manifest \
                and manifest.get("code_version") == CODE_VERSIONS.get(entry.kind) \
                and {p: manifest.get("versions", {}).get(p) for p in KEY_PACKAGES} == now:
            # written by today's code under the installed versions of today's key packages,
            # keyed before the key packages grew (numpy and torch joined them): re-key it
            manifest.update(key_packages=now, rekeyed_from=entry.key)
            target = entry.path.parent / cache_key(entry.kind, manifest["params"])
            if not dry_run:
                atomic_write_text(entry.path / "manifest.json", manifest_text(manifest))
        elif entry.status == "legacy":
            assert manifest is not None  # a legacy entry's status was read off its manifest
            recorded = {p: manifest.get("versions", {}).get(p) for p in KEY_PACKAGES}
            if recorded != now:
                report.refused.append((entry.name, f"written with {recorded}, now {now}"))
                continue
            try:
                params = _migrated_params(entry.kind, manifest["params"], signatures)
            except LookupError as err:
                report.refused.append((entry.name, str(err)))
                continue
            manifest.update(params=params, code_version=CODE_VERSIONS[entry.kind],
                            key_packages=now, migrated_from=entry.key)
            if "payload_sha256" not in manifest and _payload_path(entry.path, manifest).exists():
                manifest["payload_sha256"] = payload_digest(
                    _payload_path(entry.path, manifest).read_bytes())
            target = entry.path.parent / cache_key(entry.kind, params)
            if not dry_run:
                atomic_write_text(entry.path / "manifest.json", manifest_text(manifest))
        else:
            report.refused.append((entry.name, f"{entry.status}: {entry.reason}"))
            continue
        if target.exists() and target != entry.path:
            report.refused.append((entry.name, f"its new key {target.name} is taken"))
            continue
        if not dry_run:
            os.rename(entry.path, target)
        report.migrated[entry.kind] += 1
    return report


def _payload_path(path: Path, manifest: dict[str, Any]) -> Path:
    """The payload file a manifest's codec names (``payload.joblib`` for a pickle)."""
    codec = manifest.get("codec")
    suffix = payloads.CODECS[codec].suffix if codec in payloads.CODECS else str(codec)
    return path / f"payload.{suffix}"


# --- the plain-data migration of 2026-12 ------------------------------------------------------

#: The codec that replaces each pickled kind's joblib payload.
PLAIN_CODECS = {"distill": "distillation", "refine": "refinement", "synthesis": "synthesis"}
#: Module paths that the pickles name, before the sub-package reorganisation, and where those
#: classes live now (only :func:`unpickle_legacy` uses this).
LEGACY_MODULES = {"ibt.distill": "ibt.distill.loop", "ibt.refine": "ibt.refine.by_return",
                  "ibt.trees": "ibt.refine.tree_arrays", "ibt.bt": "ibt.bt.model"}


class MigrationError(Exception):
    """An entry that could not be converted exactly (left in place)."""


@contextmanager
def _legacy_names() -> Iterator[None]:
    """While active, joblib's unpickler finds :data:`LEGACY_MODULES`' classes at their new paths.

    joblib builds its ``NumpyUnpickler`` afresh for each load; a subclass with a translating
    ``find_class`` stands in for it (nothing else is changed, and it is restored on exit).
    """
    import joblib.numpy_pickle as numpy_pickle

    original = numpy_pickle.NumpyUnpickler

    class LegacyUnpickler(original):  # type: ignore[misc, valid-type]
        def find_class(self, module: str, name: str) -> Any:
            return super().find_class(LEGACY_MODULES.get(module, module), name)

    numpy_pickle.NumpyUnpickler = LegacyUnpickler
    try:
        yield
    finally:
        numpy_pickle.NumpyUnpickler = original


def unpickle_legacy(path: Path) -> Any:
    """Load a joblib pickle of this repository, old module paths mapped. RUNS ITS CODE: only for
    files one trusts (``migrate-plain --trust-pickles``)."""
    import joblib

    with _legacy_names():
        return joblib.load(path)


def _expected_type(kind: str, value: Any) -> None:
    from ibt.bt.model import BehaviorTree
    from ibt.distill.loop import Distillation
    from ibt.refine.by_return import Refinement

    ok = {"distill": lambda v: type(v) is Distillation,
          "refine": lambda v: type(v) is Refinement,
          "synthesis": lambda v: type(v) is dict and list(v) == ["row", "bt"]
          and type(v["bt"]) is BehaviorTree}[kind](value)
    if not ok:
        raise MigrationError(f"a {type(value).__qualname__}, not what {kind} entries hold")


def _same_trees(old: Any, new: Any) -> None:
    """The tree signatures and predictions of two runs' trees agree (beyond :func:`difference`)."""
    import numpy as np

    from ibt.distill.loop import tree_signature

    rng = np.random.default_rng(0)
    for i, (a, b) in enumerate(zip(old.trees, new.trees, strict=True)):
        if tree_signature(a) != tree_signature(b):
            raise MigrationError(f"tree {i}: signatures differ")
        x = rng.normal(scale=10.0, size=(64, int(a.n_features_in_))).astype(np.float32)
        if not np.array_equal(a.predict(x), b.predict(x)):
            raise MigrationError(f"tree {i}: predictions differ")


def convert_pickle(path: Path, kind: str) -> tuple[str, bytes]:
    """``(codec, payload bytes)`` of the pickled entry in ``path``, its round trip verified."""
    if kind not in PLAIN_CODECS:
        raise MigrationError(f"no plain codec for kind {kind!r}")
    spec = payloads.CODECS[PLAIN_CODECS[kind]]
    try:
        old = unpickle_legacy(path / "payload.joblib")
    except Exception as err:  # whatever a broken pickle raises
        raise MigrationError(f"the pickle does not load ({type(err).__name__}: {err})") from None
    _expected_type(kind, old)
    try:
        data = spec.dumps(old)
    except TypeError as err:
        raise MigrationError(str(err)) from None
    new = spec.loads(data)
    found = payloads.difference(old, new)
    if found:
        raise MigrationError(f"the round trip changes it: {found}")
    if kind == "distill":
        _same_trees(old, new)
    return spec.name, data


@dataclass
class PlainMigration:
    """What :func:`migrate_plain` did."""

    converted: Counter = field(default_factory=Counter)  # per kind: pickle -> plain payload
    digested: Counter = field(default_factory=Counter)  # per kind: digest added to a manifest
    verified: Counter = field(default_factory=Counter)  # per kind: already plain, digest good
    refused: list[tuple[str, str]] = field(default_factory=list)  # (entry, why): left in place
    bytes_before: int = 0  # payload bytes of the converted entries
    bytes_after: int = 0
    seconds: float = 0.0

    def summary(self) -> str:
        def counts(c: Counter) -> str:
            return f"{sum(c.values())}" + (" (" + ", ".join(f"{k} {n}" for k, n in
                                                            sorted(c.items())) + ")" if c else "")
        return "\n".join([
            f"converted pickles to plain payloads: {counts(self.converted)}, "
            f"{self.bytes_before / 2**20:.1f} MiB -> {self.bytes_after / 2**20:.1f} MiB",
            f"payload digests added: {counts(self.digested)}",
            f"already plain and verified: {counts(self.verified)}",
            f"refused (left in place): {len(self.refused)}",
            *[f"  {name}: {why}" for name, why in self.refused],
            f"time: {self.seconds:.0f} s"])


def pickled_entries(cache_dir: str | Path) -> list[Path]:
    """The entry folders under ``cache_dir`` that still hold a ``payload.joblib``."""
    root = Path(cache_dir)
    return sorted(p.parent for p in root.glob("*/*/payload.joblib")) if root.is_dir() else []


def migrate_plain(cache_dir: str | Path, *, dry_run: bool = False, progress: bool = False
                  ) -> PlainMigration:
    """Convert every pickled payload to its plain codec and give every manifest its digest.

    For a ``payload.joblib`` (unpickled by :func:`unpickle_legacy`: call this only on trusted
    files): the plain payload is encoded, decoded again and compared with the unpickled value
    exactly (:func:`ibt.cache.payloads.difference`; distillations' tree signatures and
    predictions too), written, the manifest rewritten (``codec`` and ``payload_sha256``,
    everything else unchanged), and only then the pickle removed; each write is atomic, so an
    interrupted migration leaves entries that a re-run finishes. A JSON or CSV entry whose
    manifest lacks ``payload_sha256`` gets it once its payload is shown to decode. Keys do not
    change: entries stay in their folders. Idempotent.
    """
    from tqdm import tqdm

    report = PlainMigration()
    started = time.perf_counter()
    folders = [p for kind in sorted(Path(cache_dir).iterdir()) if kind.is_dir()
               for p in sorted(kind.iterdir()) if p.is_dir()]
    for path in tqdm(folders, desc="migrate-plain", unit="entry", disable=not progress):
        kind, name = path.parent.name, f"{path.parent.name}/{path.name}"
        manifest = read_manifest(path)
        if manifest is None:
            report.refused.append((name, "no readable manifest"))
            continue
        pickle = path / "payload.joblib"
        try:
            if pickle.exists():
                _finish_or_convert(path, kind, manifest, pickle, report, dry_run)
            else:
                _digest(path, kind, manifest, report, dry_run)
        except MigrationError as err:
            report.refused.append((name, str(err)))
    report.seconds = time.perf_counter() - started
    return report


def _finish_or_convert(path: Path, kind: str, manifest: dict[str, Any], pickle: Path,
                       report: PlainMigration, dry_run: bool) -> None:
    codec = manifest.get("codec")
    if codec in payloads.CODECS and isinstance(manifest.get("payload_sha256"), str):
        plain = _payload_path(path, manifest)  # an interrupted run: converted, pickle left
        if plain.exists() and payload_digest(plain.read_bytes()) == manifest["payload_sha256"]:
            if not dry_run:
                pickle.unlink()
            report.converted[kind] += 1
            return
    before = pickle.stat().st_size
    codec, data = convert_pickle(path, kind)
    manifest = {**manifest, "codec": codec, "payload_sha256": payload_digest(data)}
    if not dry_run:
        atomic_write_bytes(_payload_path(path, manifest), data)
        atomic_write_text(path / "manifest.json", manifest_text(manifest))
        pickle.unlink()
    report.converted[kind] += 1
    report.bytes_before += before
    report.bytes_after += len(data)


def _digest(path: Path, kind: str, manifest: dict[str, Any], report: PlainMigration,
            dry_run: bool) -> None:
    codec = manifest.get("codec")
    if codec not in payloads.CODECS:
        raise MigrationError(f"unknown codec {codec!r}")
    try:
        data = _payload_path(path, manifest).read_bytes()
    except OSError as err:
        raise MigrationError(f"unreadable payload ({type(err).__name__})") from None
    recorded = manifest.get("payload_sha256")
    if isinstance(recorded, str):
        if recorded != payload_digest(data):
            raise MigrationError("the payload does not match its manifest's SHA-256 "
                                 "(a lookup recomputes it)")
        report.verified[kind] += 1
        return
    try:
        payloads.CODECS[codec].loads(data)
    except Exception as err:  # a payload that does not decode gets no digest
        raise MigrationError(f"undecodable payload ({type(err).__name__}: {err})") from None
    if not dry_run:
        atomic_write_text(path / "manifest.json",
                          manifest_text({**manifest, "payload_sha256": payload_digest(data)}))
    report.digested[kind] += 1
