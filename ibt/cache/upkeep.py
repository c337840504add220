"""Cache upkeep: the status of every entry, what no lookup can reach, pruning it, and
verification (``python -m ibt.cache.admin``, :mod:`ibt.cache.admin`, is their command line).

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

Upkeep works only in a folder it can prove is an ibt cache (:func:`check_cache_root`): one
whose root marker ibt wrote when it created it (:data:`ibt.cache.store.ROOT_MARKER`), or, for
caches made before the marker (the committed ``data/cache``), one whose layout is a cache's
(every folder a cache kind of entry folders, no other file than ``code_hashes.json``); a
pipeline's output folder (which holds its cache one level down) is named as such. ``prune``
removes only folders that look like an entry ibt wrote (a 16-hex-digit key holding only
``manifest.json``, ``payload.*`` and their temporary files) and those temporary files.

Beside them, ``temporary`` files (``.payload.*``, ``.manifest.*``) are what an atomic write
killed mid-way leaves; those younger than :data:`TEMP_GRACE_SECONDS` may be a write in progress
and are left alone.
"""

from __future__ import annotations

import json
import re
import shutil
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ibt.cache import payloads
from ibt.cache.store import (
    CODE_VERSIONS,
    KEY_PACKAGES,
    ROOT_FORMAT,
    ROOT_MARKER,
    cache_key,
    key_packages,
    legacy_cache_key,
)

STATUSES = ("current", "stale", "orphan", "incomplete", "legacy", "unmigrated", "temporary")
#: Temporary files younger than this may belong to a write in progress: neither listed nor pruned.
TEMP_GRACE_SECONDS = 60.0
#: the files a cache root may hold beside its kinds' folders
ROOT_FILES = ("code_hashes.json", ROOT_MARKER)
KEY_NAME = re.compile(r"[0-9a-f]{16}")
ENTRY_FILE = re.compile(r"manifest\.json|payload\.\w+|\.(payload|manifest)\..+")
PIPELINE_MARKER = ".ibt-pipeline.json"  # ibt.pipeline.owned_folder.MARKER (a higher layer)


class NotACache(ValueError):
    """A folder upkeep may not touch: not an ibt cache (one line naming it)."""


def _marked(root: Path) -> bool:
    try:
        doc = json.loads((root / ROOT_MARKER).read_text())
    except (OSError, ValueError):
        return False
    return isinstance(doc, dict) and doc.get("format") == ROOT_FORMAT


def check_cache_root(root: str | Path) -> None:
    """:class:`NotACache` unless ``root`` is an ibt cache (see the module docstring)."""
    root = Path(root)
    if (root / PIPELINE_MARKER).exists():
        try:
            made = json.loads((root / PIPELINE_MARKER).read_text()).get("cache") or "cache"
        except (OSError, ValueError, AttributeError):
            made = "cache"
        raise NotACache(f"{root} is an output folder of `python -m ibt pipeline`, not a cache: "
                        f"nothing was done; its cache is {root / str(made)} (pass "
                        f"--cache-dir {root / str(made)})")
    if _marked(root):
        return
    foreign = []
    for child in sorted(root.iterdir()):
        if child.is_symlink() or not ((child.is_dir() and child.name in CODE_VERSIONS)
                                      or (child.is_file() and child.name in ROOT_FILES)):
            foreign.append(child.name)
    if foreign:
        shown = ", ".join(foreign[:4]) + (f" and {len(foreign) - 4} more"
                                          if len(foreign) > 4 else "")
        raise NotACache(f"{root} is not an ibt cache (it holds {shown}, which ibt does not "
                        "write there): nothing was done; pass --cache-dir the folder ibt "
                        "wrote its cache to")


def _ibt_entry(path: Path) -> bool:
    """Whether ``path`` looks like an entry folder ibt wrote (what prune may remove)."""
    if path.is_symlink() or not path.is_dir() or not KEY_NAME.fullmatch(path.name):
        return False
    return all(ENTRY_FILE.fullmatch(f.name) and f.is_file() and not f.is_symlink()
               for f in path.iterdir())

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


def read_manifest(path: Path) -> dict[str, Any] | None:
    """The entry folder's ``manifest.json`` as a dict; None if missing, unreadable or no object."""
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
    manifest = read_manifest(path)
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
    check_cache_root(cache_dir)
    doomed = [e for e in not_current(cache_dir, reads) if prunable(e, incomplete=incomplete)
              and (_ibt_entry(e.path) if e.status != "temporary"
                   else e.path.is_file() and not e.path.is_symlink())]
    if not dry_run:
        for entry in doomed:
            if entry.status == "temporary":
                entry.path.unlink(missing_ok=True)
            else:
                shutil.rmtree(entry.path)
    return doomed

def verify(cache_dir: str | Path) -> list[Entry]:
    """Entries whose payload does not verify against its manifest (what a lookup would
    recompute), as ``Entry(status="unverified")``; entries without a manifest are left out."""
    from ibt.cache.store import read_entry

    out = []
    for entry in entries(cache_dir):
        manifest = read_manifest(entry.path)
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
