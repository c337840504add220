"""Run a command without root's power to ignore file permissions, so that the tests of read-only
folders also run where CI runs (as root).

Root writes into a folder of mode 0o500 because of two capabilities, ``CAP_DAC_OVERRIDE`` and
``CAP_DAC_READ_SEARCH``. util-linux's ``setpriv`` starts a command with both dropped from its
inheritable and bounding sets: the command is still uid 0, owns the test's files, and meets the
permission bits as any owner does. A non-root user needs no wrapper. Where neither works (no
``setpriv``, or a container that forbids changing the bounding set) the test is skipped, saying
which.
"""

from __future__ import annotations

import functools
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]
DROPPED = "dac_override,dac_read_search"


@functools.cache
def _prefix() -> tuple[tuple[str, ...], str]:
    """The wrapper that drops the override (empty for a non-root user), or why there is none."""
    if os.geteuid() != 0:
        return (), ""
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        return (), "running as root and util-linux's setpriv is missing: cannot drop root's " \
                   "permission override (install util-linux)"
    prefix = (setpriv, f"--inh-caps=-{DROPPED.replace(',', ',-')}",
              f"--bounding-set=-{DROPPED.replace(',', ',-')}")
    with tempfile.TemporaryDirectory() as tmp:  # does it work here? a locked folder must stay shut
        locked = Path(tmp) / "locked"
        locked.mkdir(mode=0o500)
        try:
            probe = subprocess.run([*prefix, sys.executable, "-c",
                                    f"open({str(locked / 'x')!r}, 'w')"],
                                   capture_output=True, text=True, timeout=60)
        finally:
            locked.chmod(0o700)
        if "PermissionError" not in probe.stderr:
            return (), (f"running as root and setpriv cannot drop the permission override here "
                        f"(exit {probe.returncode}: {' '.join(probe.stderr.split())[-200:]})")
    return prefix, ""


def unprivileged(argv: list[str]) -> list[str]:
    """``argv`` run without the permission override; skips the test if that is impossible."""
    prefix, why_not = _prefix()
    if why_not:
        pytest.skip(why_not)
    return [*prefix, *argv]


def run_unprivileged(argv: list[str], timeout: float = 300) -> subprocess.CompletedProcess:
    """Run ``argv`` from the repository root without the permission override, importing this
    checkout's ``ibt`` (and ``tests``); its output captured as text."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])}
    return subprocess.run(unprivileged(argv), cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=timeout)
