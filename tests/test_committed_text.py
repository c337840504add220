"""No committed text carries one machine's absolute paths or a tool's log.

A path such as ``/home/me/...`` or a pip index folder in a committed file means nothing on a
reader's machine and tells them of ours; an install log at the top of the repository reads as a
failed set-up. :func:`leaks` reads files and returns one line per offending line; the test runs
it on every file ``git ls-files`` lists (binary files skipped) less :data:`ALLOWED`, and a
planted file shows that each kind is caught.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

#: a machine's absolute paths: home and work folders, scratch space, local package indexes
MACHINE_PATH = re.compile(r"(?<![\w./-])/(?:work|home|tmp|Users|root)/|/opt/pypi|/opt/wheels")
#: lines that only a tool's log holds (pip's install output and warnings)
TOOL_LOG = re.compile(r"WARNING: Location '|Requirement already satisfied: |Successfully installed "
                      r"|ERROR: pip's dependency resolver|Looking in (?:indexes|links): "
                      r"|DEPRECATION: .* pip ")

#: file -> the one reason it may name such a path (kept small: each entry is explained)
ALLOWED = {
    # the patterns themselves, and the planted examples that prove them
    "tests/test_committed_text.py": "defines and tests the patterns",
    # an experiment's script defaults its scratch output to the system's temporary folder;
    # its RESULTS.md gives every command with an explicit --out under build/
    "experiments/optimal_trees/run.py": "a scratch --out default",
}
#: text that names a path on purpose wherever it appears: SB3's own default log folder
#: (``/tmp/SB3-<date>``), named where the code explains why it silences SB3's logger
ALLOWED_TEXT = re.compile(r"/tmp/SB3-<date>")


def leaks(paths: list[Path], root: Path = ROOT) -> list[str]:
    """``<file>:<line>: <kind>: <text>`` for every line naming a machine's path or a tool log."""
    found = []
    for path in paths:
        data = path.read_bytes()
        if b"\0" in data[:8192]:
            continue  # binary: checkpoints, images, archives
        name = path.relative_to(root).as_posix()
        if path.suffix == ".log":
            found.append(f"{name}:1: a log file")
        text = ALLOWED_TEXT.sub("", data.decode("utf-8", errors="replace"))
        if not (MACHINE_PATH.search(text) or TOOL_LOG.search(text)):
            continue  # the common case, without splitting lines
        for number, line in enumerate(text.splitlines(), 1):
            for kind, pattern in (("machine path", MACHINE_PATH), ("tool log", TOOL_LOG)):
                if pattern.search(line):
                    found.append(f"{name}:{number}: {kind}: {line.strip()[:120]}")
    return found


def _committed() -> list[Path]:
    listed = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True)
    return [ROOT / name for name in listed.stdout.decode().split("\0")
            if name and name not in ALLOWED and (ROOT / name).is_file()]


@pytest.mark.skipif(shutil.which("git") is None or not (ROOT / ".git").exists(),
                    reason="needs the git checkout")
def test_no_committed_text_names_a_machines_path_or_a_tool_log():
    assert leaks(_committed()) == []


def test_the_allowed_files_are_committed():
    # Expect: the allow-list names only files that exist (it cannot hide a removed one)
    assert all((ROOT / name).is_file() for name in ALLOWED)


def test_a_planted_leak_is_named_line_by_line(tmp_path):
    # Expect: each kind is found, with its file and line; plain URLs and relative paths are not
    planted = tmp_path / "notes.md"
    planted.write_text(
        "Run `.venv/bin/python -m ibt` from the root; see https://example.org/home/page.\n"
        "PY=/work/main/.venv/bin/python\n"
        "export PYTHONPATH=$PWD:/tmp/contree_pkgs\n"
        "pip: WARNING: Location 'file:///opt/pypi/simple/x/' is ignored\n"
        "Requirement already satisfied: numpy in ./site-packages\n"
        "SB3 would log to /tmp/SB3-<date> otherwise\n")
    (tmp_path / "setup.log").write_text("done\n")
    (tmp_path / "weights.bin").write_bytes(b"\0/home/x/")
    found = leaks(sorted(tmp_path.iterdir()), tmp_path)
    assert [line.split(": ", 2)[:2] for line in found] == [
        ["notes.md:2", "machine path"], ["notes.md:3", "machine path"],
        ["notes.md:4", "machine path"], ["notes.md:4", "tool log"], ["notes.md:5", "tool log"],
        ["setup.log:1", "a log file"]], found
