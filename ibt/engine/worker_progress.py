"""What the work in worker processes is doing, shown under the caller's progress bar.

With more than one job the ladder distils, refines and searches in worker processes (joblib's
loky), and each item draws its own progress bars there (a distillation's iterations and
labels, a refinement's episodes) where no terminal shows them: the caller's bar would stand
still for minutes. So a worker's bars are written to a status file of its item instead (the
latest line, replaced atomically), and the caller draws one line per running item under its
own bar, redrawn every :data:`POLL` seconds; other text a worker writes to stderr (a warning)
goes on to its stderr. Workers of a Dask cluster, on other machines, show nothing.

The status folder is made by :class:`WorkerBars` with :func:`tempfile.mkdtemp`, so it is new
and its own: it is removed whole when the items end.
"""

from __future__ import annotations

import os
import re
import shutil
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import Any, TextIO

from tqdm import tqdm

POLL = 0.5  #: seconds between the caller's redraws of its workers' lines
SAVE_EVERY = 0.2  #: seconds between a worker's writes of its status file
_ESCAPE = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")  # tqdm's cursor moves for nested bars


class StatusStream:
    """A file for a worker's progress bars: keeps the latest bar line in ``path`` (written
    atomically, at most every :data:`SAVE_EVERY` seconds; ``None``: nowhere) and passes
    other text (a line without a carriage return or cursor move) on to ``passthrough``."""

    encoding = "utf-8"

    def __init__(self, path: Path | None, passthrough: TextIO) -> None:
        self.path, self.passthrough = path, passthrough
        self.latest, self.saved_at = "", 0.0

    def write(self, text: str) -> int:
        if "\r" not in text and "\x1b" not in text:
            return self.passthrough.write(text)
        shown = [part.strip() for part in re.split(r"[\r\n]", _ESCAPE.sub("", text))]
        line = next((part for part in reversed(shown) if part), "")
        if line and line != self.latest:
            self.latest = line
            if time.monotonic() - self.saved_at >= SAVE_EVERY:
                self.save()
        return len(text)

    def save(self) -> None:
        if self.path is None:
            return
        part = self.path.with_suffix(".part")
        part.write_text(self.latest, encoding="utf-8")
        os.replace(part, self.path)
        self.saved_at = time.monotonic()

    def flush(self) -> None:
        self.passthrough.flush()

    def isatty(self) -> bool:
        return False


def reporting(path: str | None, fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(*args)`` in a worker, its progress bars written to the status file ``path``
    (``None``: shown nowhere); the file is gone when it returns."""
    status = Path(path) if path else None
    saved = sys.stderr
    sys.stderr = StatusStream(status, saved)  # tqdm's default file
    try:
        return fn(*args)
    finally:
        sys.stderr = saved
        if status is not None:
            status.unlink(missing_ok=True)
            status.with_suffix(".part").unlink(missing_ok=True)


class WorkerBars:
    """The caller's side: a status folder for ``items`` items, and while it is open one line
    under the caller's bar for each item running (at most ``lines``), each the latest line
    of that item's bars."""

    def __init__(self, items: int, lines: int) -> None:
        self.items, self.lines = items, max(1, lines)
        self.folder = Path(tempfile.mkdtemp(prefix="ibt-workers-"))
        self.bars: list[Any] = []
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name="ibt-worker-bars", daemon=True)

    def path(self, item: int) -> str:
        """The status file of item ``item`` (its index among the items)."""
        return str(self.folder / f"{item:06d}.txt")

    def running(self) -> list[str]:
        """The latest line of each item with a status file, in item order."""
        lines = []
        for status in sorted(self.folder.glob("*.txt")):
            try:
                text = status.read_text(encoding="utf-8").strip()
            except OSError:  # its item ended between the listing and the read
                continue
            if text:
                lines.append(text)
        return lines[:self.lines]

    def draw(self) -> None:
        """Redraw the lines: one per running item, blank where fewer run."""
        lines = self.running()
        while len(self.bars) < len(lines):
            self.bars.append(tqdm(total=0, bar_format="{desc}", leave=False,
                                  file=sys.stderr))
        for bar, line in zip(self.bars, [*lines, *[""] * len(self.bars)], strict=False):
            bar.set_description_str(f"  {line}" if line else "", refresh=True)

    def _run(self) -> None:
        while not self.stop.wait(POLL):
            self.draw()

    def __enter__(self) -> WorkerBars:
        self.thread.start()
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 trace: TracebackType | None) -> None:
        self.stop.set()
        self.thread.join()
        for bar in reversed(self.bars):
            bar.close()
        shutil.rmtree(self.folder, ignore_errors=True)  # made by mkdtemp above: ours whole
