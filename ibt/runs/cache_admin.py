"""Cache upkeep: which entries no key can reach any more, pruning them, and key migrations.

Every entry of ``<cache>/<kind>/<key>/`` is, by its ``manifest.json``, one of:

- ``current``: written under today's code version of its kind and today's key packages, and
  stored under the key its manifest recomputes to (a lookup can hit it);
- ``stale``: written under another code version or package version (no lookup reaches it);
- ``orphan``: its folder name is not the key its manifest recomputes to, or its kind is unknown;
- ``incomplete``: no manifest or no payload (an interrupted write);
- ``legacy``: written before keys carried versions (``migrate`` re-keys these).

``python -m ibt.runs.cache_admin stale`` lists the entries that are not current, ``--reads FOLDER``
also the
current entries that the lookups logged there (``IBT_CACHE_READS``) never touched, which is what
``make figures`` prints at its end; ``prune`` removes what ``stale`` lists (``--dry-run`` to
see it first); ``migrate`` is the one-off re-keying of 2026-11.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
from collections import Counter, defaultdict
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ibt.runs.cache import (
    CODE_VERSIONS,
    KEY_PACKAGES,
    atomic_write_text,
    cache_key,
    key_packages,
    legacy_cache_key,
)

STATUSES = ("current", "stale", "orphan", "incomplete", "legacy")


@dataclass(frozen=True)
class Entry:
    """One cache entry and what its manifest says about it."""

    path: Path
    kind: str
    status: str
    reason: str = ""

    @property
    def key(self) -> str:
        return self.path.name

    @property
    def name(self) -> str:
        return f"{self.kind}/{self.key}"


def _manifest(path: Path) -> dict[str, Any] | None:
    try:
        return json.loads((path / "manifest.json").read_text())
    except (OSError, ValueError):
        return None


def classify(path: Path) -> Entry:
    """The status of the entry in folder ``path`` (see the module docstring)."""
    kind = path.parent.name
    manifest = _manifest(path)
    if manifest is None or not any(p.name.startswith("payload.") for p in path.iterdir()):
        return Entry(path, kind, "incomplete", "no manifest or no payload")
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
    return Entry(path, kind, "current")


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
    """Entries no lookup can hit; with ``reads``, also current entries that were not read."""
    out = []
    for entry in entries(cache_dir):
        if entry.status != "current":
            out.append(entry)
        elif reads is not None and entry.name not in reads:
            out.append(Entry(entry.path, entry.kind, "unread", "current, but not read"))
    return out


def prune(cache_dir: str | Path, reads: set[str] | None = None, *, dry_run: bool = False
          ) -> list[Entry]:
    """Remove the entries :func:`not_current` lists (never ``legacy`` ones: migrate those)."""
    doomed = [e for e in not_current(cache_dir, reads) if e.status != "legacy"]
    if not dry_run:
        for entry in doomed:
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
    import joblib

    from ibt.runs.grid import tree_digest

    found: dict[tuple[str, str], set[str]] = defaultdict(set)
    for entry in entries(cache_dir):
        if entry.kind != "distill" or entry.status in ("incomplete", "orphan"):
            continue
        run = joblib.load(entry.path / "payload.joblib")
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
            target = entry.path.parent / cache_key(entry.kind, params)
            if not dry_run:
                atomic_write_text(entry.path / "manifest.json",
                                  json.dumps(manifest, indent=1, sort_keys=True, default=str))
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


# --- command line -----------------------------------------------------------------------------

def _listing(found: Sequence[Entry]) -> str:
    if not found:
        return "none"
    counts = Counter(e.status for e in found)
    head = ", ".join(f"{n} {s}" for s, n in sorted(counts.items()))
    return head + "\n" + "\n".join(f"  {e.status:10s} {e.name}  {e.reason}" for e in found)


def main(argv: Sequence[str] | None = None) -> int:
    from ibt.paths import DATA_DIR

    parser = argparse.ArgumentParser(prog="python -m ibt.runs.cache_admin",
                                     description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("command", choices=("stale", "prune", "migrate", "summary"))
    parser.add_argument("--cache-dir", type=Path,
                        default=Path(os.environ.get("IBT_CACHE_DIR") or DATA_DIR / "cache"))
    parser.add_argument("--reads", type=Path, help="a folder of IBT_CACHE_READS logs: also "
                        "list (or prune) the current entries no lookup read")
    parser.add_argument("--dry-run", action="store_true", help="say what would change")
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
        print(f"cache entries in {args.cache_dir} that no lookup "
              f"{'read' if reads is not None else 'can reach'}: {_listing(found)}")
    elif args.command == "prune":
        gone = prune(args.cache_dir, reads, dry_run=args.dry_run)
        print(f"{'would remove' if args.dry_run else 'removed'}: {_listing(gone)}")
    else:
        print(migrate(args.cache_dir, dry_run=args.dry_run).summary())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
