"""A rerun resumes: the same ``python -m ibt pipeline ... -o OUT`` command run again into the
folder it made reads every step from the cache there, after a run that finished, failed, was
stopped by Ctrl-C, SIGTERM or SIGKILL, or ran out of ``--time``; and the commands a
``report.md`` prints under "Reproduce" run verbatim (the first replays the run's plan).

The real command line runs in subprocesses (CartPole, ``--budget smoke``, one leaf limit). The
plain twice-run case is the fast one (two runs, the second from the cache); the others are
``slow``.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.test_hostile_files import FILES, ROOT, _set, cli

PIPELINE = ["pipeline", "CartPole-v1", "ppo", "--budget", "smoke", "--leaves", "4", "--quiet",
            "--jobs", "1"]


def _entries(cache: Path) -> dict[str, float]:
    """Every cache entry (kind/key) and its manifest's modification time."""
    return {str(m.parent.relative_to(cache)): m.stat().st_mtime_ns
            for m in cache.glob("*/*/manifest.json")}


def _reproduce(report: Path) -> list[str]:
    """The commands of a report's "Reproduce" block, verbatim."""
    text = report.read_text().split("## Reproduce", 1)[1]
    block = text.split("```bash\n", 1)[1].split("```", 1)[0]
    return [line for line in block.splitlines() if line.strip()]


def _shell(command: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """``command`` as a user types it, with ``python`` this test's interpreter."""
    path = os.pathsep.join([str(Path(sys.executable).parent), os.environ.get("PATH", "")])
    pythonpath = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    return subprocess.run(["bash", "-c", command], capture_output=True, text=True, cwd=cwd,
                          timeout=600, env={**os.environ, "PATH": path,
                                            "PYTHONPATH": pythonpath,
                                            "SDL_VIDEODRIVER": "dummy"})


def test_the_same_command_twice_resumes_and_the_reports_commands_run_verbatim(tmp_path):
    out = tmp_path / "out"
    first = cli([*PIPELINE, "-o", out])
    assert first.returncode == 0, first.stderr
    marker = json.loads((out / ".ibt-pipeline.json").read_text())
    assert marker["cache"] == "cache"  # the run's own cache, recorded by its marker
    files, entries, report = _set(out), _entries(out / "cache"), _untimed(out / "report.md")
    assert entries
    plan = (out / "plan.json").read_bytes()
    commands = _reproduce(out / "report.md")
    assert len(commands) == 4 and all(c.startswith("python -m ibt pipeline")
                                      for c in commands[:2])
    assert "--plan" in commands[0] and "--time" not in commands[0]
    for command in commands:  # the reruns first: the plan replayed, then the same command
        ran = _shell(command, ROOT)
        assert ran.returncode == 0, (command, ran.stderr)
        if command is commands[0]:  # the plan's steps, from the cache: the same set
            assert {n: h for n, h in _set(out).items() if n != "report.md"} == {
                n: h for n, h in files.items() if n != "report.md"}
    assert _entries(out / "cache") == entries  # every step read from the cache, none redone
    again = _set(out)
    assert {n: again[n] for n in FILES if n != "report.md"} == {
        n: files[n] for n in FILES if n != "report.md"}  # the same BT, drawings and front
    assert _untimed(out / "report.md") == report and (out / "plan.json").read_bytes() == plan


def _untimed(report: Path) -> list[str]:
    """The report's lines but the ladder's notes of how long a step took (wall time)."""
    return [line for line in report.read_text().splitlines()
            if not (line.startswith("Note: ") and " took " in line)]


def _stop_once_cached(argv: list, out: Path, signum: int) -> subprocess.CompletedProcess[str]:
    """Run ``argv`` and send ``signum`` as soon as its first cache entry is written (before any
    candidate is finished)."""
    path = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    proc = subprocess.Popen([sys.executable, "-m", "ibt", *map(str, argv)], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONPATH": path, "SDL_VIDEODRIVER": "dummy"},
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 300
    while not list((out / "cache").glob("*/*/manifest.json")) and proc.poll() is None:
        assert time.monotonic() < deadline, "the run wrote no cache entry in 300 s"
        time.sleep(0.05)
    if proc.poll() is None:
        proc.send_signal(signum)
    stdout, stderr = proc.communicate(timeout=300)
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr)


def _resumes(out: Path, argv: list) -> None:
    """The folder is still the pipeline's, its cache recorded, and ``argv`` finishes there."""
    marker = json.loads((out / ".ibt-pipeline.json").read_text())
    assert marker["cache"] == "cache"
    cached = _entries(out / "cache")
    again = cli([*argv, "-o", str(out)], timeout=600)
    assert again.returncode == 0, again.stderr
    assert all(_entries(out / "cache").get(k) == v for k, v in cached.items())  # reused
    assert {p.name for p in out.iterdir()} >= set(FILES)


@pytest.mark.slow
@pytest.mark.parametrize("signum, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143),
                                          (signal.SIGKILL, -9)],
                         ids=["ctrl-c", "sigterm", "kill-9"])
def test_a_stopped_run_resumes_with_the_same_command(tmp_path, signum, code):
    out = tmp_path / "out"
    stopped = _stop_once_cached([*PIPELINE, "-o", out], out, signum)
    assert stopped.returncode == code, stopped.stderr
    assert "Traceback" not in stopped.stderr
    _resumes(out, PIPELINE)


@pytest.mark.slow
def test_a_failed_run_resumes_with_the_corrected_command(tmp_path):
    out = tmp_path / "out"
    failed = cli([*PIPELINE, "-o", out, "--max-nodes", "1", "--time", "20s"],  # none so small
                 timeout=600)
    assert failed.returncode == 2 and "raise --" in failed.stderr, failed.stderr
    _resumes(out, [*PIPELINE, "--time", "3m"])  # the default 10m may all be spent polishing


@pytest.mark.slow
def test_a_run_out_of_time_resumes_with_more_time(tmp_path):
    out = tmp_path / "out"
    short = cli([*PIPELINE, "-o", out, "--time", "1s"], timeout=600)  # a grace may finish one
    assert short.returncode == 0 or (short.returncode == 2 and "raise --time" in short.stderr
                                     ), short.stderr
    assert (out / "cache").is_dir()
    _resumes(out, [*PIPELINE, "--time", "3m"])
