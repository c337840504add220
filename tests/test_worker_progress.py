"""Progress of work in worker processes: a worker's bars reach the caller's stderr as one line
per running item, other text passes through, and the status folder is gone afterwards."""

from __future__ import annotations

import io
import time
from pathlib import Path

from hypothesis import given
from hypothesis import strategies as st
from tqdm import tqdm

from ibt.engine import worker_progress
from ibt.engine.parallel import parallel_map
from ibt.engine.worker_progress import StatusStream, WorkerBars, reporting


def _counting(name: str, steps: int, pause: float) -> str:
    """An item whose bar counts ``steps`` steps, ``pause`` seconds each (as a worker's
    distillation draws its iterations)."""
    for _ in tqdm(range(steps), desc=f"counting {name}", leave=False, mininterval=0.0):
        time.sleep(pause)
    return name


def test_a_bar_line_is_kept_and_plain_text_passes_through(tmp_path):
    passthrough = io.StringIO()
    stream = StatusStream(tmp_path / "0.txt", passthrough)
    stream.write("\rdistil 1/10 [00:01]   ")
    stream.save()
    assert (tmp_path / "0.txt").read_text() == "distil 1/10 [00:01]"
    stream.write("\n\x1b[A\rdistil 2/10 [00:02]\r")
    stream.save()
    assert (tmp_path / "0.txt").read_text() == "distil 2/10 [00:02]"
    stream.write("\r" + " " * 20 + "\r")  # a closed bar's blank keeps the last line
    assert stream.latest == "distil 2/10 [00:02]"
    stream.write("UserWarning: something\n")
    assert passthrough.getvalue() == "UserWarning: something\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["0.txt"]  # no part file left


@given(st.lists(st.text(alphabet=st.characters(blacklist_categories=("Cs",)), max_size=30),
                max_size=8))
def test_the_kept_line_is_the_last_non_blank_part_drawn(parts):
    stream = StatusStream(None, io.StringIO())
    for part in parts:
        stream.write("\r" + part)
    shown = [p.strip() for text in parts for p in text.replace("\n", "\r").split("\r")]
    drawn = [p for p in shown if p and "\x1b" not in p]
    if drawn and "\x1b" not in "".join(parts):
        assert stream.latest == drawn[-1]


def test_reporting_removes_its_status_file_and_restores_stderr(tmp_path):
    import sys

    before = sys.stderr
    status = tmp_path / "000001.txt"
    assert reporting(str(status), _counting, "x", 2, 0.0) == "x"
    assert sys.stderr is before and not status.exists()


def test_the_callers_stderr_shows_each_workers_bar(capfd, monkeypatch):
    monkeypatch.setattr(worker_progress, "POLL", 0.05)
    folders_before = set(Path(worker_progress.tempfile.gettempdir()).glob("ibt-workers-*"))
    got = parallel_map(_counting, [("first", 6, 0.4), ("second", 6, 0.4)], n_jobs=2,
                       progress=True)
    assert got == ["first", "second"]
    err = capfd.readouterr().err
    assert "counting first" in err and "counting second" in err  # drawn by the caller
    assert set(Path(worker_progress.tempfile.gettempdir()).glob("ibt-workers-*")) == \
        folders_before  # the status folder is gone


def test_the_lines_follow_the_running_items_in_order(monkeypatch, capfd):
    monkeypatch.setattr(worker_progress, "POLL", 3600.0)  # drawn here only, not by its thread
    with WorkerBars(items=3, lines=2) as bars:
        Path(bars.path(2)).write_text("third 1/4")
        Path(bars.path(0)).write_text("first 3/4")
        Path(bars.path(1)).write_text("")  # started, nothing drawn yet
        assert bars.running() == ["first 3/4", "third 1/4"]
        bars.draw()
        assert [b.desc for b in bars.bars] == ["  first 3/4", "  third 1/4"]
        Path(bars.path(0)).unlink()
        bars.draw()
        assert [b.desc for b in bars.bars] == ["  third 1/4", ""]
    assert not bars.folder.exists()


def test_a_worker_writes_its_status_at_most_every_save_every_seconds(tmp_path, monkeypatch):
    clock = [100.0]
    monkeypatch.setattr(worker_progress.time, "monotonic", lambda: clock[0])
    status = tmp_path / "0.txt"
    stream = StatusStream(status, io.StringIO())
    stream.write("\rstep 1")  # the first line is written at once
    assert status.read_text() == "step 1"
    clock[0] += worker_progress.SAVE_EVERY / 2
    stream.write("\rstep 2")  # too soon: kept, not written
    assert status.read_text() == "step 1" and stream.latest == "step 2"
    clock[0] = 100.0 + worker_progress.SAVE_EVERY
    stream.write("\rstep 3")
    assert status.read_text() == "step 3"
    assert worker_progress.SAVE_EVERY == 0.2  # a few writes a second, never a flood


def test_at_least_one_line_is_drawn_whatever_lines_is_asked(monkeypatch):
    monkeypatch.setattr(worker_progress, "POLL", 3600.0)
    for lines in (0, -3, 1):
        with WorkerBars(items=3, lines=lines) as bars:
            for item in range(3):
                Path(bars.path(item)).write_text(f"item {item}")
            assert bars.running() == ["item 0"]
    with WorkerBars(items=3, lines=2) as bars:
        for item in range(3):
            Path(bars.path(item)).write_text(f"item {item}")
        assert bars.running() == ["item 0", "item 1"]


def test_an_item_that_draws_no_bar_leaves_no_status_file_to_remove(tmp_path):
    status = tmp_path / "000002.txt"
    assert reporting(str(status), sum, (1, 2)) == 3
    assert not status.exists() and list(tmp_path.iterdir()) == []


def test_the_drawing_thread_never_keeps_the_process_alive(tmp_path):
    """A caller that ends inside the block (its ``__exit__`` never ran) still exits: the
    thread redrawing the lines is a daemon."""
    import subprocess
    import sys

    script = ("from ibt.engine import worker_progress\n"
              "worker_progress.POLL = 0.01\n"
              "worker_progress.WorkerBars(items=1, lines=1).__enter__()\n")
    done = subprocess.run([sys.executable, "-c", script], timeout=60, capture_output=True,
                          cwd=Path(worker_progress.__file__).parents[2])
    assert done.returncode == 0, done.stderr.decode()
