"""Notebook housekeeping: run a notebook in place, scrub volatile metadata after papermill runs,
record how long ``make figures`` takes.

``python -m ibt.notebooks run NB...`` executes each notebook in place as ``papermill --cwd
notebooks NB NB`` does (parameters as committed, ``IBT_PROFILE`` from the environment), with the
kernel on local IPC sockets rather than TCP ports: papermill's command line has no switch for
that, and a TCP kernel warns on every run that it talks unencrypted. Then it scrubs the notebook.

``python -m ibt.notebooks record-time SECONDS`` keeps ``data/results/make_figures.json``
(see :func:`record_time`).

``python -m ibt.notebooks scrub NB...`` removes timings, kernel ids and papermill's run records
so that a re-executed notebook differs from the committed one only where results changed:
progress bars go, and the stdout and stderr pieces of a cell are joined in a fixed order (the
kernel's interleaving of the two varies between runs). It also drops widget state: the
notebook's ``widgets`` metadata (the saved models) and, in outputs, the
``application/vnd.jupyter.widget-view+json`` views, which point at those models and draw as
"model not found" without them; an output left with only the widget's ``text/plain`` repr
(``VBox(children=...)``) goes too. The committed notebooks carry the static rendering of
their widgets (see :mod:`ibt.views.widgets`), which needs none of this.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import nbformat

from ibt.paths import DATA_DIR

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
        if cell.cell_type == "code":
            cell["outputs"] = _streams_in_order(
                [o for o in map(_without_widget_view, cell.get("outputs", []))
                 if o is not None and not _progress_noise(o)])
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


def _progress_noise(output: dict) -> bool:
    """Whether an output is a progress bar's: stderr with carriage returns (the bar), or
    stderr of whitespace only (the newline a bar writes when it closes)."""
    if output.get("output_type") != "stream" or output.get("name") != "stderr":
        return False
    text = output.get("text", "")
    text = "".join(text) if isinstance(text, list) else text
    return "\r" in text or not text.strip()


def _streams_in_order(outputs: list) -> list:
    """Each run of consecutive stream outputs as at most one ``stdout`` then one ``stderr``.

    The kernel sends stdout and stderr on separate channels, so how their pieces interleave
    (and into how many outputs they are cut) varies between runs; joined per stream in a fixed
    order, the same text gives the same notebook."""
    import nbformat

    result: list = []
    run: dict[str, list[str]] = {}

    def flush() -> None:
        for name in ("stdout", "stderr"):
            if name in run:
                result.append(nbformat.v4.new_output("stream", name=name,
                                                     text="".join(run[name])))
        run.clear()

    for output in outputs:
        if output.get("output_type") == "stream":
            text = output.get("text", "")
            run.setdefault(output.get("name", "stdout"), []).append(
                "".join(text) if isinstance(text, list) else text)
        else:
            flush()
            result.append(output)
    flush()
    return result


def _without_widget_view(output: dict) -> dict | None:
    """``output`` without its widget view; ``None`` when nothing but the widget's repr is left."""
    data = output.get("data")
    if not data or WIDGET_VIEW not in data:
        return output
    data.pop(WIDGET_VIEW)
    return output if set(data) - {"text/plain"} else None


#: a new wall time replaces the record only outside this factor of it (or on another machine)
RECORD_TOLERANCE = 1.5


def _record_path(data_dir: Path | None) -> Path:
    return (data_dir or DATA_DIR) / "results" / "make_figures.json"


def _machine() -> str:
    import os
    import platform

    return f"{platform.machine()}, {os.cpu_count()} cores"


def record_stands(seconds: float, data_dir: Path | None = None) -> bool:
    """Whether ``data/results/make_figures.json`` already describes a run of ``seconds`` here:
    the same machine (architecture, cores) and a recorded time within :data:`RECORD_TOLERANCE`
    of it either way."""
    import json

    try:
        old = json.loads(_record_path(data_dir).read_text())
        recorded = float(old["seconds"])
    except (OSError, ValueError, KeyError, TypeError):
        return False  # no record, or one that cannot be read
    return (old.get("machine") == _machine() and recorded > 0
            and 1 / RECORD_TOLERANCE <= seconds / recorded <= RECORD_TOLERANCE)


def record_time(seconds: float, data_dir: Path | None = None) -> Path:
    """Record in ``data/results/make_figures.json`` how long ``make figures`` took here.

    The record (time, machine, date) describes this kind of machine, not the last run: it is
    rewritten only when it does not stand (:func:`record_stands`), so rerunning ``make figures``
    leaves the committed file, and the tree, as they were. The report and the README name the
    file; ``make reproduce`` prints its time.
    """
    import datetime
    import json

    from ibt.files import atomic_write_text

    target = _record_path(data_dir)
    if not record_stands(seconds, data_dir):
        facts = {"seconds": float(seconds), "machine": _machine(),
                 "date": datetime.date.today().isoformat()}
        atomic_write_text(target, json.dumps(facts, indent=1) + "\n")
    return target


USAGE = "usage: python -m ibt.notebooks run NOTEBOOK... | scrub NOTEBOOK... | record-time SECONDS"


def main(argv: list[str]) -> int:
    if len(argv) == 2 and argv[0] == "record-time":
        try:
            seconds = float(argv[1])
        except ValueError:
            print(f"record-time takes the wall time in seconds, got {argv[1]!r}", file=sys.stderr)
            return 2
        stands = record_stands(seconds)
        path = record_time(seconds)
        print(f"make figures took {seconds:.0f} s: " + (
            f"within {RECORD_TOLERANCE}x of the record in {path}, which stands" if stands
            else f"recorded in {path}"))
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
