"""Notebook housekeeping: scrub volatile metadata after papermill runs.

``python -m ibt.notebooks scrub NB...`` removes timings, kernel ids and papermill's run records
so that a re-executed notebook differs from the committed one only where results changed.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import nbformat

VOLATILE_CELL_KEYS = ("papermill", "execution", "collapsed", "scrolled")
VOLATILE_NOTEBOOK_KEYS = ("papermill", "widgets")
_ADDRESS = re.compile(r" at 0x[0-9a-f]+>")


def scrub(path: str | Path) -> None:
    """Strip volatile metadata from a notebook file in place (atomically)."""
    from ibt.artifacts import atomic_write_text

    path = Path(path)
    nb = nbformat.read(path, as_version=4)
    for key in VOLATILE_NOTEBOOK_KEYS:
        nb.metadata.pop(key, None)
    nb.metadata.setdefault("kernelspec", {"name": "python3", "display_name": "Python 3",
                                          "language": "python"})
    for cell in nb.cells:
        for key in VOLATILE_CELL_KEYS:
            cell.metadata.pop(key, None)
        if cell.cell_type == "code":
            for output in cell.get("outputs", []):
                output.get("metadata", {}).pop("execution", None)
                plain = output.get("data", {}).get("text/plain")
                if isinstance(plain, str):  # object reprs carry memory addresses
                    output["data"]["text/plain"] = _ADDRESS.sub(">", plain)
    atomic_write_text(path, nbformat.writes(nb) + "\n")


def main(argv: list[str]) -> int:
    if len(argv) < 2 or argv[0] != "scrub":
        print("usage: python -m ibt.notebooks scrub NOTEBOOK...", file=sys.stderr)
        return 2
    for name in argv[1:]:
        scrub(name)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
