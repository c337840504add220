"""Notebook housekeeping: run a notebook in place, scrub volatile metadata after papermill runs,
time ``make figures``.

``python -m ibt.notebooks run NB...`` executes each notebook in place as ``papermill --cwd
notebooks NB NB`` does (parameters as committed, ``IBT_PROFILE`` from the environment), with the
kernel on local IPC sockets rather than TCP ports: papermill's command line has no switch for
that, and a TCP kernel warns on every run that it talks unencrypted. Then it scrubs the notebook.

``python -m ibt.notebooks scrub NB...`` removes timings, kernel ids and papermill's run records
so that a re-executed notebook differs from the committed one only where results changed. It
also drops widget state: the notebook's ``widgets`` metadata (the saved models) and, in
outputs, the ``application/vnd.jupyter.widget-view+json`` views, which point at those models and
draw as "model not found" without them; an output left with only the widget's ``text/plain``
repr (``VBox(children=...)``) goes too. The committed notebooks carry the static rendering of
their widgets (see :mod:`ibt.views.widgets`), which needs none of this.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import nbformat

VOLATILE_CELL_KEYS = ("papermill", "execution", "collapsed", "scrolled")
VOLATILE_NOTEBOOK_KEYS = ("papermill", "widgets")
WIDGET_VIEW = "application/vnd.jupyter.widget-view+json"
_ADDRESS = re.compile(r" at 0x[0-9a-f]+>")


def scrub(path: str | Path) -> None:
    """Strip volatile metadata from a notebook file in place (atomically)."""
    from ibt.files import atomic_write_text

    path = Path(path)
    nb = nbformat.read(path, as_version=4)
    for key in VOLATILE_NOTEBOOK_KEYS:
        nb.metadata.pop(key, None)
    nb.metadata.setdefault("kernelspec", {"name": "python3", "display_name": "Python 3",
                                          "language": "python"})
    for cell in nb.cells:
        for key in VOLATILE_CELL_KEYS:
            cell.metadata.pop(key, None)
        if cell.cell_type == "code":  # progress bars (stderr with carriage returns) are noise
            cell["outputs"] = [o for o in map(_without_widget_view, cell.get("outputs", []))
                               if o is not None and not (o.get("name") == "stderr"
                                                         and "\r" in o.get("text", ""))]
            for output in cell.get("outputs", []):
                output.get("metadata", {}).pop("execution", None)
                plain = output.get("data", {}).get("text/plain")
                if isinstance(plain, str):  # object reprs carry memory addresses
                    output["data"]["text/plain"] = _ADDRESS.sub(">", plain)
    atomic_write_text(path, nbformat.writes(nb) + "\n")


def run(path: str | Path, cwd: str | Path | None = None) -> None:
    """Execute the notebook at ``path`` in place with papermill (working directory ``cwd``, by
    default the notebook's folder), its kernel on IPC sockets where the OS has them; then
    :func:`scrub` it."""
    import os

    import papermill
    from traitlets.config import Config

    path = Path(path)
    transport = "ipc" if os.name == "posix" else "tcp"  # Windows has no Unix sockets
    papermill.execute_notebook(str(path), str(path), cwd=str(cwd or path.parent),
                               progress_bar=False,
                               config=Config(KernelManager={"transport": transport}))
    scrub(path)


def _without_widget_view(output: dict) -> dict | None:
    """``output`` without its widget view; ``None`` when nothing but the widget's repr is left."""
    data = output.get("data")
    if not data or WIDGET_VIEW not in data:
        return output
    data.pop(WIDGET_VIEW)
    return output if set(data) - {"text/plain"} else None


def record_time(seconds: float, data_dir: Path | None = None) -> Path:
    """Write ``data/results/make_figures.json``: how long the last ``make figures`` took here.

    The report and the README read it on the next run (they run inside ``make figures``).
    """
    import datetime
    import json
    import os
    import platform

    from ibt.files import atomic_write_text
    from ibt.paths import DATA_DIR

    target = (data_dir or DATA_DIR) / "results" / "make_figures.json"
    facts = {"seconds": float(seconds), "machine": f"{platform.machine()}, {os.cpu_count()} cores",
             "date": datetime.date.today().isoformat()}
    atomic_write_text(target, json.dumps(facts, indent=1) + "\n")
    return target


USAGE = "usage: python -m ibt.notebooks run NOTEBOOK... | scrub NOTEBOOK... | record-time SECONDS"


def main(argv: list[str]) -> int:
    if len(argv) == 2 and argv[0] == "record-time":
        print(f"make figures took {float(argv[1]):.0f} s: {record_time(float(argv[1]))}")
        return 0
    if len(argv) < 2 or argv[0] not in ("run", "scrub"):
        print(USAGE, file=sys.stderr)
        return 2
    missing = [name for name in argv[1:] if not Path(name).is_file()]
    if missing:
        print(f"no notebook at {missing[0]}; give paths such as notebooks/00_quickstart.ipynb",
              file=sys.stderr)
        return 2
    for name in argv[1:]:
        if argv[0] == "run":
            run(name)
        else:
            scrub(name)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
