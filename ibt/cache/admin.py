"""Cache upkeep: what no lookup can reach, pruning it, verification, and migrations.

Every entry of ``<cache>/<kind>/<key>/`` is, by its ``manifest.json``, one of:

- ``current``: written under today's code version of its kind and today's key packages, stored
  under the key its manifest recomputes to, with a plain payload and its SHA-256 (a lookup can
  hit it; ``verify`` checks the payload against the digest);
- ``stale``: written under another code version or package version (no lookup reaches it);
- ``orphan``: its folder name is not the key its manifest recomputes to, or its kind is unknown;
- ``incomplete``: no payload, or a missing, empty or unparsable manifest (an interrupted write);
- ``legacy``: written before keys carried versions (``migrate`` re-keys these);
- ``unmigrated``: current, but its payload is a pickle or its manifest records no digest (a
  lookup recomputes it; ``migrate-plain`` converts it in place).

Beside them, ``temporary`` files (``.payload.*``, ``.manifest.*``) are what an atomic write
killed mid-way leaves; those younger than :data:`TEMP_GRACE_SECONDS` may be a write in progress
and are left alone.

``python -m ibt.cache.admin stale`` lists what is not current (and the temporary files),
``--reads FOLDER`` also the current entries that the lookups logged there (``IBT_CACHE_READS``)
never touched, which is what ``make figures`` counts at its end (``--count``: one line, and none
when there is nothing to count: the committed cache holds only what ``make figures`` reads, so
a line there means runs were superseded, by a retrained expert or a changed budget or setting,
and their entries can be pruned). ``prune`` removes what ``stale``
lists (``--dry-run`` to see it first), except ``legacy`` and ``unmigrated`` entries (migrate
those) and ``incomplete`` entries that still hold a payload: those only with ``--incomplete``
(the payload may be all that is left of hours of computing; a later lookup overwrites it
anyway). ``verify`` reads every entry as a lookup would and lists those that do not verify
(exit 1 if any). ``summary`` counts entries per kind and status.

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

import argparse
import json
import os
import shutil
import sys
import time
from collections import Counter, defaultdict
from collections.abc import Iterator, Sequence
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
    legacy_cache_key,
    manifest_text,
    payload_digest,
)
from ibt.files import atomic_write_bytes, atomic_write_text

STATUSES = ("current", "stale", "orphan", "incomplete", "legacy", "unmigrated", "temporary")
#: Temporary files younger than this may belong to a write in progress: neither listed nor pruned.
TEMP_GRACE_SECONDS = 60.0


@dataclass(frozen=True)
class Entry:
    """One cache entry and what its manifest says about it."""

    path: Path
    kind: str
    status: str
    reason: str = ""

    @property
    def key(self) -> str:
        return self.path.parent.name if self.status == "temporary" else self.path.name

    @property
    def name(self) -> str:
        if self.status == "temporary":
            return f"{self.kind}/{self.key}/{self.path.name}"
        return f"{self.kind}/{self.key}"


def _manifest(path: Path) -> dict[str, Any] | None:
    try:
        manifest = json.loads((path / "manifest.json").read_text())
    except (OSError, ValueError):
        return None
    return manifest if isinstance(manifest, dict) else None


def _payloads(path: Path) -> list[Path]:
    return sorted(p for p in path.iterdir() if p.name.startswith("payload."))


def classify(path: Path) -> Entry:
    """The status of the entry in folder ``path`` (see the module docstring)."""
    kind = path.parent.name
    manifest = _manifest(path)
    if not _payloads(path):
        return Entry(path, kind, "incomplete", "no payload")
    if manifest is None:
        what = ("unreadable or empty manifest" if (path / "manifest.json").exists()
                else "no manifest")
        return Entry(path, kind, "incomplete", what)
    if not isinstance(manifest.get("params"), dict):
        return Entry(path, kind, "incomplete", "its manifest records no params")
    if kind not in CODE_VERSIONS:
        return Entry(path, kind, "orphan", f"unknown kind {kind!r}")
    if "code_version" not in manifest:
        if legacy_cache_key(kind, manifest["params"]) != path.name:
            return Entry(path, kind, "orphan", "folder name is not its manifest's key")
        return Entry(path, kind, "legacy", "written before keys carried versions")
    reasons = []
    if manifest["code_version"] != CODE_VERSIONS[kind]:
        reasons.append(f"code version {manifest['code_version']} (now {CODE_VERSIONS[kind]})")
    now = key_packages()
    was = manifest.get("key_packages", {})
    reasons += [f"{p} {was.get(p, '?')} (now {now[p]})" for p in KEY_PACKAGES
                if was.get(p) != now[p]]
    if reasons:
        return Entry(path, kind, "stale", ", ".join(reasons))
    if cache_key(kind, manifest["params"]) != path.name:
        return Entry(path, kind, "orphan", "folder name is not its manifest's key")
    if manifest.get("codec") == "joblib":
        return Entry(path, kind, "unmigrated", "a pickle: run migrate-plain --trust-pickles")
    if not isinstance(manifest.get("payload_sha256"), str):
        return Entry(path, kind, "unmigrated", "no payload digest: run migrate-plain")
    return Entry(path, kind, "current")


def temporaries(cache_dir: str | Path, grace: float = TEMP_GRACE_SECONDS) -> Iterator[Entry]:
    """Temporary files that atomic writes leave when killed (``.payload.*``, ``.manifest.*``),
    older than ``grace`` seconds (a younger one may be a write in progress)."""
    root = Path(cache_dir)
    if not root.is_dir():
        return
    now = time.time()
    for kind_dir in sorted(p for p in root.iterdir() if p.is_dir()):
        for folder in sorted(p for p in kind_dir.iterdir() if p.is_dir()):
            for file in sorted(folder.iterdir()):
                if not file.name.startswith((".payload.", ".manifest.")):
                    continue
                try:
                    young = now - file.stat().st_mtime < grace
                except OSError:  # removed meanwhile: its write finished
                    continue
                if not young:
                    yield Entry(file, kind_dir.name, "temporary",
                                "left by an interrupted write")


def entries(cache_dir: str | Path) -> Iterator[Entry]:
    """Every entry folder of the cache, classified, in a stable order."""
    root = Path(cache_dir)
    if not root.is_dir():
        return
    for kind_dir in sorted(p for p in root.iterdir() if p.is_dir()):
        for path in sorted(p for p in kind_dir.iterdir() if p.is_dir()):
            yield classify(path)


def read_log(folder: str | Path) -> set[str]:
    """``kind/key`` of every lookup logged under ``IBT_CACHE_READS``."""
    out: set[str] = set()
    for file in Path(folder).glob("reads-*.txt"):
        out.update(line.strip() for line in file.read_text().splitlines() if line.strip())
    return out


def not_current(cache_dir: str | Path, reads: set[str] | None = None) -> list[Entry]:
    """Entries no lookup can hit and stray temporary files; with ``reads``, also current
    entries that were not read."""
    out = []
    for entry in entries(cache_dir):
        if entry.status != "current":
            out.append(entry)
        elif reads is not None and entry.name not in reads:
            out.append(Entry(entry.path, entry.kind, "unread", "current, but not read"))
    return out + list(temporaries(cache_dir))


def prunable(entry: Entry, *, incomplete: bool = False) -> bool:
    """Whether :func:`prune` removes ``entry``: never a ``legacy`` or ``unmigrated`` one
    (migrate those); an ``incomplete`` one only when it has no payload, or with ``incomplete``."""
    if entry.status in ("legacy", "unmigrated"):
        return False
    if entry.status == "incomplete" and not incomplete:
        return not _payloads(entry.path)
    return True


def prune(cache_dir: str | Path, reads: set[str] | None = None, *, dry_run: bool = False,
          incomplete: bool = False) -> list[Entry]:
    """Remove what :func:`not_current` lists and :func:`prunable` allows; return it."""
    doomed = [e for e in not_current(cache_dir, reads) if prunable(e, incomplete=incomplete)]
    if not dry_run:
        for entry in doomed:
            if entry.status == "temporary":
                entry.path.unlink(missing_ok=True)
            else:
                shutil.rmtree(entry.path)
    return doomed


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
        manifest = _manifest(entry.path) or {}
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
        manifest = _manifest(entry.path)
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
        manifest = _manifest(path)
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


def verify(cache_dir: str | Path) -> list[Entry]:
    """Entries whose payload does not verify against its manifest (what a lookup would
    recompute), as ``Entry(status="unverified")``; entries without a manifest are left out."""
    from ibt.cache.store import read_entry

    out = []
    for entry in entries(cache_dir):
        manifest = _manifest(entry.path)
        if manifest is None or entry.status == "incomplete":
            continue
        if manifest.get("codec") not in payloads.CODECS:
            out.append(Entry(entry.path, entry.kind, "unverified",
                             f"codec {manifest.get('codec')!r} (a pickle: run migrate-plain)"))
            continue
        try:
            read_entry(entry.path, manifest["codec"])
        except LookupError as err:
            out.append(Entry(entry.path, entry.kind, "unverified", str(err)))
    return out


# --- command line -----------------------------------------------------------------------------

def _listing(found: Sequence[Entry]) -> str:
    if not found:
        return "none"
    counts = Counter(e.status for e in found)
    head = ", ".join(f"{n} {s}" for s, n in sorted(counts.items()))
    return head + "\n" + "\n".join(f"  {e.status:10s} {e.name}  {e.reason}" for e in found)


def main(argv: Sequence[str] | None = None) -> int:
    from ibt.paths import DATA_DIR

    parser = argparse.ArgumentParser(prog="python -m ibt.cache.admin",
                                     description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("command", choices=("stale", "prune", "verify", "summary", "migrate",
                                            "migrate-plain"))
    parser.add_argument("--cache-dir", type=Path,
                        default=Path(os.environ.get("IBT_CACHE_DIR") or DATA_DIR / "cache"))
    parser.add_argument("--reads", type=Path, help="a folder of IBT_CACHE_READS logs: also "
                        "list (or prune) the current entries no lookup read")
    parser.add_argument("--dry-run", action="store_true", help="say what would change")
    parser.add_argument("--count", action="store_true", help="stale: one summary line with the "
                        "command that lists them, instead of the list")
    parser.add_argument("--incomplete", action="store_true", help="prune: also remove "
                        "incomplete entries that still hold a payload")
    parser.add_argument("--trust-pickles", action="store_true", help="migrate-plain: unpickle "
                        "the payload.joblib files (a pickle runs code when loaded)")
    args = parser.parse_args(argv)
    if not args.cache_dir.is_dir():
        print(f"error: no cache at {args.cache_dir}; pass --cache-dir", file=sys.stderr)
        return 2
    if args.reads is not None and not args.reads.is_dir():
        print(f"error: no reads log at {args.reads}; run with IBT_CACHE_READS={args.reads} "
              "first (make figures does)", file=sys.stderr)
        return 2
    reads = read_log(args.reads) if args.reads is not None else None
    if args.command == "summary":
        counts = Counter((e.kind, e.status) for e in entries(args.cache_dir))
        for (kind, status), n in sorted(counts.items()):
            print(f"{kind:12s} {status:10s} {n}")
    elif args.command == "stale":
        found = not_current(args.cache_dir, reads)
        what = f"cache entries in {args.cache_dir} that no lookup " + (
            "read" if reads is not None else "can reach")
        if args.count and found:  # `make figures`: one line, not a list that reads like an error
            again = [a for a in (argv if argv is not None else sys.argv[1:]) if a != "--count"]
            why = (" (results of runs nothing asks for any more: a retrained expert, a changed "
                   "budget or setting; harmless)" if reads is not None else " (harmless)")
            print(f"{what}: {_listing(found).splitlines()[0]}{why}; list them with "
                  f"`python -m ibt.cache.admin {' '.join(again)}`, remove them with "
                  "`prune`")
        elif args.count:  # nothing to say: every entry is current (and was read)
            pass
        else:
            print(f"{what}: {_listing(found)}")
    elif args.command == "prune":
        gone = prune(args.cache_dir, reads, dry_run=args.dry_run, incomplete=args.incomplete)
        print(f"{'would remove' if args.dry_run else 'removed'}: {_listing(gone)}")
    elif args.command == "verify":
        bad = verify(args.cache_dir)
        print(f"cache entries in {args.cache_dir} that do not verify: {_listing(bad)}")
        return 1 if bad else 0
    elif args.command == "migrate-plain":
        pickles = pickled_entries(args.cache_dir)
        if pickles and not args.trust_pickles:
            print(f"error: refusing to unpickle {len(pickles)} payload.joblib file(s) under "
                  f"{args.cache_dir}: loading a pickle runs whatever code it names; if they are "
                  "this repository's own (e.g. the committed data/cache), re-run with "
                  "--trust-pickles, else delete those entries and let the next run recompute "
                  "them", file=sys.stderr)
            return 2
        report = migrate_plain(args.cache_dir, dry_run=args.dry_run, progress=True)
        print(("dry run: " if args.dry_run else "") + report.summary())
        return 1 if report.refused else 0
    else:
        print(migrate(args.cache_dir, dry_run=args.dry_run).summary())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
