"""A folder ``python -m ibt pipeline`` owns, and its files written there as one set.

The marker ``.ibt-pipeline.json`` lists every file the pipeline wrote in the folder with its
SHA-256 (and the cache folder it made there). :func:`claim` reads it before any work: a file
the marker does not list, or one edited since, is the user's, so the run is refused (exit 2,
naming the files) unless ``--force`` is given, which replaces only the output names and says
which; a read-only file is never replaced, and a symbolic link is replaced as a link (never
followed) and only with ``--force``.

:func:`write_set` writes the new files into a hidden folder beside them, then commits: the
marker first lists the old and the new digests, ``report.md`` becomes a note that the folder
is being rewritten, the other files are renamed into place, then the new ``report.md``, then
the final marker. Ctrl-C and SIGTERM are held during the commit (milliseconds of renames) and
delivered after it, so an interrupted run leaves the old set or the new one; a crash inside the
commit (SIGKILL, power loss) leaves a ``report.md`` that says the set is incomplete.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
import signal
import stat
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

MARKER = ".ibt-pipeline.json"
FORMAT = "ibt-pipeline/1"
TEMP_PREFIX = ".ibt-pipeline-new-"
STALE_SECONDS = 30  # a temporary folder older than this was left by a killed run
TEST_SIGNAL_ENV = "IBT_TEST_SIGNAL_AT"  # tests only: "STEP=SIGNAME" signals this process there
SHOWN = 6  # names listed in one message


class FolderError(ValueError):
    """The output folder holds files the pipeline may not replace (one line naming them)."""


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def _names(items: list[str]) -> str:
    shown = ", ".join(items[:SHOWN])
    return shown + (f" and {len(items) - SHOWN} more" if len(items) > SHOWN else "")


def read_only(st: os.stat_result) -> bool:
    """No write permission bit at all (checked on the mode: root may write anyway)."""
    return not st.st_mode & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH)


@dataclass
class OwnedFolder:
    """An output folder checked by :func:`claim`: what may be replaced there, and what not."""

    path: Path
    option: str = "-o"
    cache: str | None = None  # the cache folder's name inside ``path`` (ours), if any
    replaceable: dict[str, str | None] = field(default_factory=dict)  # name -> digest now
    forced: list[str] = field(default_factory=list)  # the user's files --force replaces
    kept: list[str] = field(default_factory=list)  # the user's files left as they are

    def note(self) -> str | None:
        """What ``--force`` will do, in one line (None when it replaces none of the user's)."""
        if not self.forced:
            return None
        kept = f"; left as they are: {_names(self.kept)}" if self.kept else ""
        link = ("; a link is replaced, its target left alone"
                if any(f.endswith("(a symbolic link)") for f in self.forced) else "")
        return f"--force: replacing {_names(self.forced)} in {self.path}{link}{kept}"


def _marker(folder: Path) -> dict[str, Any]:
    """The marker's content, or an empty one when absent, foreign or unreadable."""
    path = folder / MARKER
    try:
        if not stat.S_ISREG(path.lstat().st_mode):
            return {}
        doc = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    if not (isinstance(doc, dict) and doc.get("format") == FORMAT
            and isinstance(doc.get("files"), dict)):
        return {}
    return doc


def _ours(marker: dict[str, Any], name: str, path: Path) -> bool:
    digests = marker.get("files", {}).get(name)
    if isinstance(digests, str):
        digests = [digests]
    return isinstance(digests, list) and sha256(path) in digests


def claim(path: str | Path, names: tuple[str, ...], *, force: bool = False,
          cache: str | Path | None = None, option: str = "-o") -> OwnedFolder:
    """Check ``path`` before any work: :class:`FolderError` (one line) unless every file in it
    is the pipeline's own (or ``force``); ``names`` are the files a run writes; ``cache``, the
    cache folder when it lies directly inside ``path``."""
    folder = OwnedFolder(Path(path), option)
    where = f"{option} {folder.path}"
    cache_name = None
    if cache is not None and Path(cache).parent.resolve() == folder.path.resolve():
        cache_name = Path(cache).name
    folder.cache = cache_name  # recorded by the first marker: a rerun resumes from it
    try:
        entries = sorted(os.scandir(folder.path), key=lambda e: e.name)
    except FileNotFoundError:
        return folder
    except OSError as err:
        raise FolderError(f"{where}: cannot list it ({err.strerror}); choose another "
                          "folder") from None
    marker = _marker(folder.path)
    made = marker.get("cache") if isinstance(marker.get("cache"), str) else None
    temporaries = _temporaries(marker)
    folder.cache = cache_name or made  # the marker keeps naming a cache a run made here
    foreign: list[str] = []
    refused: list[str] = []
    for entry in entries:
        name, st = entry.name, entry.stat(follow_symlinks=False)
        link = stat.S_ISLNK(st.st_mode)
        if name in temporaries or (name == MARKER and not link):
            if name == MARKER and read_only(st):
                refused.append(f"{name} (read-only)")
            continue
        if name == made and not link and stat.S_ISDIR(st.st_mode):
            continue
        if name in names and not link and read_only(st):
            refused.append(f"{name} (read-only: ibt never replaces it)")
            continue
        if name in names and not link and not stat.S_ISREG(st.st_mode):
            refused.append(f"{name} (not a regular file)")
            continue
        if not link and stat.S_ISREG(st.st_mode) and _ours(marker, name, Path(entry.path)):
            if name in names:
                folder.replaceable[name] = sha256(Path(entry.path))
            continue
        why = (" (a symbolic link)" if link else " (edited since ibt wrote it)"
               if name in marker.get("files", {}) else " (a folder)"
               if stat.S_ISDIR(st.st_mode) else "")
        foreign.append(name + why)
        if name in names:
            folder.forced.append(name + why)
            folder.replaceable[name] = "link" if link else sha256(Path(entry.path))
        else:
            folder.kept.append(name)
    if refused:
        others = f" (and files it did not write: {_names(foreign)})" if foreign else ""
        raise FolderError(f"{where} holds {_names(refused)}{others}; choose another folder")
    if foreign and not force:
        replace = (f" to replace {_names([f.split(' (')[0] for f in folder.forced])}"
                   if folder.forced else "")
        raise FolderError(f"{where} holds files ibt pipeline did not write: {_names(foreign)}; "
                          f"choose a new or empty folder, or pass --force{replace} (other "
                          "files are left as they are)")
    return folder


def take(folder: OwnedFolder) -> bool:
    """Make the folder (if needed) and mark it as the pipeline's, before the long work; remove
    the temporary folders killed runs left there (only those the marker records: a folder of
    the user's with a like name is left alone). True where this run wrote the first marker
    (:func:`release` takes it back when the run fails before writing anything)."""
    folder.path.mkdir(parents=True, exist_ok=True)
    marker = _marker(folder.path)
    first = not marker
    left = []
    for name in _temporaries(marker):
        temp = folder.path / name
        with contextlib.suppress(OSError):
            if temp.is_dir() and not temp.is_symlink() \
                    and time.time() - temp.stat().st_mtime > STALE_SECONDS:
                shutil.rmtree(temp)
        if os.path.lexists(temp):
            left.append(name)
    if not marker or (folder.cache and marker.get("cache") != folder.cache) \
            or left != _temporaries(marker):
        _write_marker(folder.path, {"format": FORMAT, "files": marker.get("files", {}),
                                    "cache": folder.cache,
                                    "state": marker.get("state", "empty"),
                                    "temporaries": left})
    return first


def _temporaries(marker: dict[str, Any]) -> list[str]:
    """The temporary folders the marker records (names made by :func:`_new_temporary`)."""
    names = marker.get("temporaries")
    return [n for n in names if isinstance(n, str) and n.startswith(TEMP_PREFIX)
            and "/" not in n and n not in (".", "..")] if isinstance(names, list) else []


def _record_temporary(folder: Path, name: str, add: bool) -> None:
    """Add ``name`` to (or drop it from) the temporaries the marker records."""
    marker = _marker(folder)
    names = [n for n in _temporaries(marker) if n != name] + ([name] if add else [])
    _write_marker(folder, {**marker, "temporaries": names})


def _new_temporary(folder: Path) -> Path:
    """A new hidden folder for a set's files, recorded in the marker before it is made, so a
    later run removes it after a kill and never a folder it did not make."""
    import secrets

    while True:
        name = f"{TEMP_PREFIX}{secrets.token_hex(6)}"
        if os.path.lexists(folder / name):
            continue
        _record_temporary(folder, name, add=True)
        (folder / name).mkdir()
        return folder / name


def release(folder: OwnedFolder) -> None:
    """Remove the marker :func:`take` wrote first, where no output was written since and the
    run made no cache in the folder: a run that failed on bad input before any work leaves the
    folder as it found it. Where its cache exists the marker stays, naming it, so the corrected
    rerun of the same command resumes from its whole entries."""
    marker = _marker(folder.path)
    made = marker.get("cache")
    if isinstance(made, str) and os.path.lexists(folder.path / made):
        return
    if marker and not marker.get("files"):
        with contextlib.suppress(OSError):
            (folder.path / MARKER).unlink()


def _write_marker(folder: Path, doc: dict[str, Any]) -> None:
    from ibt.files import atomic_write_text

    atomic_write_text(folder / MARKER, json.dumps(doc, indent=1, sort_keys=True) + "\n")


def _hook(step: str) -> None:
    """A point of the write phase; tests signal the process here (``IBT_TEST_SIGNAL_AT``)."""
    wanted = os.environ.get(TEST_SIGNAL_ENV)
    if wanted and wanted.partition("=")[0] == step:
        os.kill(os.getpid(), getattr(signal, wanted.partition("=")[2] or "SIGTERM"))


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """Ctrl-C and SIGTERM wait until the block ends (main thread only), then are delivered to
    whatever handled them before, so a commit of renames is never cut in the middle."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pending: list[int] = []
    held = (signal.SIGINT, signal.SIGTERM)
    previous = {s: signal.signal(s, lambda signum, frame: pending.append(signum)) for s in held}
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        for signum in dict.fromkeys(pending):
            signal.raise_signal(signum)


def _check_unchanged(folder: OwnedFolder, names: list[str]) -> None:
    """Nothing the claim allowed to replace changed during the run, nothing new appeared."""
    changed = []
    for name in names:
        path = folder.path / name
        try:
            st = path.lstat()
        except FileNotFoundError:
            if name in folder.replaceable:
                folder.replaceable.pop(name)
            continue
        was = folder.replaceable.get(name)
        link = stat.S_ISLNK(st.st_mode)
        now = "link" if link else sha256(path) if stat.S_ISREG(st.st_mode) else None
        if was is None or now != was or (not link and read_only(st)):
            changed.append(name)
    if changed:
        raise FolderError(f"{folder.option} {folder.path}: {_names(changed)} changed while the "
                          "pipeline ran, so nothing was replaced; rerun it (every step is "
                          "cached) in another folder or after moving them")


def write_set(folder: OwnedFolder, names: tuple[str, ...], write: Callable[[Path], None],
              incomplete: str, last: str = "report.md", optional: tuple[str, ...] = ()
              ) -> list[Path]:
    """Write the files ``names`` as one set: ``write(tmp)`` makes them in a hidden folder beside
    them, then the commit renames them into place (``last`` after the others, replaced by the
    text ``incomplete`` while they are renamed) and records them in the marker. ``write`` may
    leave out the names of ``optional``: an earlier set's file of such a name is then removed
    in the commit where the marker proves it the pipeline's (the folder never pairs a new
    report with an old file), and left alone otherwise. Returns the paths written."""
    take(folder)
    tmp = _new_temporary(folder.path)
    try:
        write(tmp)
        _hook("written")
        missing = [n for n in names if not (tmp / n).is_file() and n not in optional]
        if missing:
            raise RuntimeError(f"the pipeline did not make {', '.join(missing)}")
        dropped = [n for n in names if not (tmp / n).is_file()]
        names = tuple(n for n in names if n not in dropped)
        stub = tmp / f".{last}.incomplete"
        stub.write_text(incomplete)
        stub_digest = sha256(stub)
        new = {n: sha256(tmp / n) for n in names}
        with signals_held():
            _check_unchanged(folder, [*names, *dropped])
            old = _marker(folder.path).get("files", {})
            files = {n: d if isinstance(d, list) else [d] for n, d in old.items()}
            for n in names:
                listed = [*files.get(n, []), *filter(None, [folder.replaceable.get(n)]),
                          new[n]]
                files[n] = list(dict.fromkeys(d for d in listed if d != "link"))
            files[last] = [*files[last], stub_digest]
            temporaries = _temporaries(_marker(folder.path))
            _write_marker(folder.path, {"format": FORMAT, "files": files,
                                        "cache": folder.cache, "state": "writing",
                                        "temporaries": temporaries})
            _hook("commit:marker")
            os.replace(stub, folder.path / last)
            _hook("commit:incomplete")
            for n in (*[n for n in names if n != last], last):
                os.replace(tmp / n, folder.path / n)
                _hook(f"commit:{n}")
            kept = []  # a dropped name's file that is not provably ours stays, and is listed
            for n in dropped:
                path = folder.path / n
                if not os.path.lexists(path):
                    continue
                if path.is_symlink() or not path.is_file() or not _ours({"files": files}, n,
                                                                        path):
                    kept.append(n)
                    continue
                path.unlink()
            done = {n: d for n, d in files.items()
                    if n not in names and (n not in dropped or n in kept)} | {
                n: [new[n]] for n in names}
            _write_marker(folder.path, {"format": FORMAT, "files": done,
                                        "cache": folder.cache, "state": "complete",
                                        "temporaries": temporaries})
            folder.replaceable = {n: new[n] for n in names}
            folder.forced, folder.kept = [], []
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        if not os.path.lexists(tmp):
            with contextlib.suppress(OSError):
                _record_temporary(folder.path, tmp.name, add=False)
    return [folder.path / n for n in names]
