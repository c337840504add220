"""A hostile tester's files: the user's files are safe, every input is checked before work, the
engine XML is what ibt wrote. The real command line runs in subprocesses (``python -m ibt``).

:data:`CASES` are commands that must be refused before any work: exit code 2, one line on
stderr naming the culprit, no traceback, every file of the user's folder as it was (bytes,
modes, link targets). They run in parallel (each is a second of imports). Then the write phase
of ``pipeline`` is interrupted: SIGTERM before its commit leaves the old set, SIGINT inside it
the new one (signals wait for the renames); in-process, a signal or a crash at every point of
:func:`ibt.pipeline.owned_folder.write_set` leaves the old set, the new one, or a ``report.md``
that says the set is incomplete. ``python -m tests.test_hostile_files`` prints the table of
``docs/hostile-files.md``.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import signal
import stat
import subprocess
import sys
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SMOKE = ["--budget", "smoke", "--leaves", "4", "--quiet"]
PIPELINE = ["pipeline", "CartPole-v1", "ppo", *SMOKE]
BT = ROOT / "data" / "trees" / "CartPole-v1" / "ppo" / "imitation-bt.json"


def _users_folder(folder: Path) -> None:
    """The tester's folder: the user's report, a read-only bt.json, bt.xml a link to their
    own file."""
    (folder / "report.md").write_text("# my own notes\n")
    (folder / "bt.json").write_text('{"mine": true}\n')
    (folder / "bt.json").chmod(0o444)
    (folder / "mine.xml").write_text("<mine/>\n")
    (folder / "bt.xml").symlink_to("mine.xml")


def _notes_and_link(folder: Path) -> None:
    (folder / "notes.txt").write_text("keep me\n")
    (folder / "report.md").write_text("# my own notes\n")
    (folder / "mine.xml").write_text("<mine/>\n")
    (folder / "bt.xml").symlink_to("mine.xml")


def _inputs(folder: Path) -> None:
    """A tree file, a BT, its XML and the XML edited past what ibt writes; two link loops."""
    from ibt.bt.json_io import load_json
    from ibt.export.btcpp import to_btcpp_xml

    shutil.copy(ROOT / "data" / "trees" / "CartPole-v1" / "ppo" / "imitation-bt.json",
                folder / "bt.json")
    xml = to_btcpp_xml(load_json(BT))
    (folder / "skip.xml").write_text(xml.replace("<Sequence>", '<Sequence _skipIf="true">', 1))
    (folder / "post.xml").write_text(xml.replace("<ScriptCondition ",
                                                 '<ScriptCondition _post="x := 1" ', 1))
    (folder / "subtree.xml").write_text(xml.replace("<Sequence>",
                                                    '<SubTree ID="Other"/><Sequence>', 1))
    (folder / "latin1.xml").write_bytes(xml.encode().replace(b"<root", b"<root \xe9", 1))
    (folder / "loop").symlink_to("loop2")
    (folder / "loop2").symlink_to("loop")
    (folder / "link.json").symlink_to("bt.json")
    _tree(folder / "tree.json")


def _tree(path: Path) -> None:
    import numpy as np
    from sklearn.tree import DecisionTreeClassifier

    from ibt.distill.tree_file import save_tree_file
    from ibt.tasks.catalogue import get_task

    task = get_task("CartPole-v1")
    x = task.sample_features(500, np.random.default_rng(0))
    tree = DecisionTreeClassifier(max_leaf_nodes=4, random_state=0).fit(x, x[:, 2] > 0)
    save_tree_file(path, tree, task, {"algo": "ppo"})


@dataclass(frozen=True)
class Case:
    """A command that must be refused before any work (``{u}``: the user's folder, made by
    ``setup``; ``{c}``: a cache folder)."""

    name: str
    setup: Callable[[Path], None]
    argv: list[str]
    words: str  # the one line names the culprit with these words
    expected: str  # in docs/hostile-files.md
    module: str = "ibt"  # python -m MODULE ARGV


def _photos(folder: Path) -> None:
    """A user's folder of photos and letters (no cache)."""
    for name in ("photos", "letters"):
        (folder / name).mkdir()
        (folder / name / "one.txt").write_text(f"the user's {name}\n")


def _pipeline_output(folder: Path) -> None:
    """A pipeline's output folder: its marker, a cache with one entry, the user's notes."""
    from ibt.cache.store import load_or_compute

    load_or_compute("tree-eval", {"i": 1}, lambda: {"x": 1}, cache_dir=folder / "out" / "cache")
    (folder / "out" / ".ibt-pipeline.json").write_text(json.dumps(
        {"format": "ibt-pipeline/1", "files": {}, "cache": "cache"}))
    (folder / "out" / "notes.txt").write_text("keep me\n")


CASES: list[Case] = [
    Case("pipeline writes over a user's folder", _users_folder, [*PIPELINE, "-o", "{u}"],
         "bt.json (read-only: ibt never replaces it)",
         "exit 2 naming the read-only bt.json, the linked bt.xml and report.md"),
    Case("--force never replaces a read-only file", _users_folder,
         [*PIPELINE, "-o", "{u}", "--force"], "bt.json (read-only",
         "exit 2: a read-only file is never replaced, even with --force"),
    Case("pipeline into a folder of other files", _notes_and_link, [*PIPELINE, "-o", "{u}"],
         "did not write: bt.xml (a symbolic link), mine.xml, notes.txt, report.md",
         "exit 2 naming them; --force would replace bt.xml and report.md"),
    Case("-o is a loop of links", _inputs, [*PIPELINE, "-o", "{u}/loop"],
         "a loop of symbolic links", "exit 2 before any work"),
    Case("--cache-dir is a loop of links", _inputs,
         [*PIPELINE, "-o", "{u}/out", "--cache-dir", "{u}/loop"], "a loop of symbolic links",
         "exit 2 before any work (not after it, with a warning per entry)"),
    Case("--leaves past any tree", _inputs,
         ["pipeline", "CartPole-v1", "ppo", "--budget", "smoke", "--leaves", "4," + "9" * 25,
          "-o", "{u}/out"],
         "leaf limits must be at most 100,000", "exit 2 (no OverflowError, no MemoryError)"),
    Case("synthesize X -o X", _inputs, ["synthesize", "{u}/tree.json", "-o", "{u}/tree.json"],
         "never writes over its own input", "exit 2, the tree file intact"),
    Case("export --format json X -o X", _inputs,
         ["export", "{u}/bt.json", "--format", "json", "-o", "{u}/bt.json"],
         "never writes over its own input", "exit 2, the BT intact"),
    Case("export onto a link", _inputs,
         ["export", "{u}/bt.json", "--format", "json", "-o", "{u}/link.json"],
         "is a symbolic link", "exit 2: no link is replaced or followed"),
    Case("run-btcpp with _skipIf", _inputs, ["run-btcpp", "{u}/skip.xml", "--task",
                                             "CartPole-v1"],
         "the attribute _skipIf, which ibt does not model (this file differs from what ibt "
         "writes", "exit 2 naming _skipIf"),
    Case("run-btcpp with a SubTree", _inputs, ["run-btcpp", "{u}/subtree.xml", "--task",
                                               "CartPole-v1"],
         "node <SubTree>, which ibt does not model", "exit 2 naming SubTree"),
    Case("cache prune on a folder of photos", _photos,
         ["prune", "--cache-dir", "{u}", "--incomplete"], "is not an ibt cache (it holds "
         "letters, photos", "exit 2 naming the folder; nothing removed",
         module="ibt.cache.admin"),
    Case("cache stale on a pipeline's output folder", _pipeline_output,
         ["stale", "--cache-dir", "{u}/out"], "is an output folder of `python -m ibt pipeline`",
         "exit 2 naming its cache; nothing touched", module="ibt.cache.admin"),
    Case("cache prune on a pipeline's output folder", _pipeline_output,
         ["prune", "--cache-dir", "{u}/out"], "is an output folder of `python -m ibt pipeline`",
         "exit 2 naming its cache; nothing removed", module="ibt.cache.admin"),
    Case("run-btcpp of a Latin-1 file", _inputs, ["run-btcpp", "{u}/latin1.xml", "--task",
                                                  "CartPole-v1"],
         "latin1.xml is not UTF-8 text", "exit 2, one line naming the file"),
]


def cli(argv: list[str], env: dict[str, str] | None = None, timeout: float = 300,
        module: str = "ibt") -> subprocess.CompletedProcess[str]:
    """``python -m MODULE ARGV`` (``ibt``) in a fresh process importing this checkout's
    ``ibt``."""
    path = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    return subprocess.run([sys.executable, "-m", module, *map(str, argv)], capture_output=True,
                          text=True, cwd=ROOT, timeout=timeout,
                          env={**os.environ, "PYTHONPATH": path, "SDL_VIDEODRIVER": "dummy",
                               **(env or {})}, preexec_fn=_ctrl_c_default if env else None)


def _ctrl_c_default() -> None:
    """A child that takes Ctrl-C as a user's terminal does, even when this test runs as a
    background job (whose children inherit an ignored SIGINT)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def snapshot(folder: Path) -> dict[str, tuple[str, int, str]]:
    """Every entry under ``folder``, not following links: kind, mode, bytes' digest or target."""
    out = {}
    for path in sorted(folder.rglob("*")):
        st = path.lstat()
        if stat.S_ISLNK(st.st_mode):
            what = ("link", 0, os.readlink(path))
        elif stat.S_ISDIR(st.st_mode):
            what = ("dir", stat.S_IMODE(st.st_mode), "")
        else:
            what = ("file", stat.S_IMODE(st.st_mode),
                    hashlib.sha256(path.read_bytes()).hexdigest())
        out[str(path.relative_to(folder))] = what
    return out


def _run_case(case: Case, folder: Path) -> tuple[subprocess.CompletedProcess[str], dict, dict]:
    folder.mkdir(parents=True)
    case.setup(folder)
    before = snapshot(folder)
    argv = [a.replace("{u}", str(folder)) for a in case.argv]
    return cli(argv, module=case.module), before, snapshot(folder)


@pytest.fixture(scope="module")
def refused(tmp_path_factory):
    """Every case run once, in parallel: name -> (process, files before, files after)."""
    root = tmp_path_factory.mktemp("hostile")
    with ThreadPoolExecutor(max_workers=max(2, os.cpu_count() or 2)) as pool:
        runs = pool.map(lambda i_case: _run_case(i_case[1], root / f"case{i_case[0]}"),
                        enumerate(CASES))
        return {case.name: run for case, run in zip(CASES, runs, strict=True)}


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_refused_before_any_work_and_the_users_files_intact(case, refused):
    run, before, after = refused[case.name]
    assert run.returncode == 2, run.stderr
    lines = run.stderr.splitlines()
    assert len(lines) == 1 and "Traceback" not in run.stderr, run.stderr
    assert case.words in lines[0]
    assert after == before  # bytes, modes and links as they were; nothing added


# ------------------------------------------------------------------ the write phase, killed
FILES = ("bt.json", "bt.xml", "bt.png", "bt.svg", "faithful_bt.json", "faithful_bt.xml",
         "front.png", "episode.gif", "plan.json", "report.md")  # CartPole renders: every output


def _set(folder: Path) -> dict[str, str]:
    return {n: hashlib.sha256((folder / n).read_bytes()).hexdigest() for n in FILES}


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    """One cache for the pipeline runs of this module: the first computes, the rest read."""
    return tmp_path_factory.mktemp("cache")


def test_a_killed_write_leaves_the_old_set_or_the_new_one(tmp_path, cache):
    out = tmp_path / "out"
    first = cli([*PIPELINE, "-o", out, "--cache-dir", cache])
    assert first.returncode == 0, first.stderr
    old = _set(out)
    marker = json.loads((out / ".ibt-pipeline.json").read_text())
    assert {n: [d] for n, d in old.items()} == marker["files"]
    # SIGTERM once the new files are made, before the commit: the old set, whole
    stopped = cli([*PIPELINE, "-o", out, "--cache-dir", cache, "--keep", "0.5"],
                  env={"IBT_TEST_SIGNAL_AT": "written=SIGTERM"})
    assert stopped.returncode == 143 and "Traceback" not in stopped.stderr
    assert _set(out) == old and not list(out.glob(".ibt-pipeline-new-*"))
    # SIGINT in the middle of the renames: it waits for them, so the new set is whole
    interrupted = cli([*PIPELINE, "-o", out, "--cache-dir", cache, "--keep", "0.5"],
                      env={"IBT_TEST_SIGNAL_AT": "commit:bt.png=SIGINT"})
    assert interrupted.returncode == 130 and "Traceback" not in interrupted.stderr
    new = _set(out)
    assert new["report.md"] != old["report.md"] and "(target 50 %)" in (out / "report.md"
                                                                         ).read_text()
    marker = json.loads((out / ".ibt-pipeline.json").read_text())
    assert marker["state"] == "complete" and {n: [d] for n, d in new.items()} == marker["files"]


def test_force_says_what_it_replaces_and_keeps_the_rest(tmp_path, cache):
    out = tmp_path / "out"
    out.mkdir()
    _notes_and_link(out)
    run = cli([*PIPELINE, "-o", out, "--cache-dir", cache, "--force"])
    assert run.returncode == 0, run.stderr
    assert run.stdout.startswith("--force: replacing bt.xml (a symbolic link), report.md in")
    assert (out / "notes.txt").read_text() == "keep me\n"
    assert (out / "mine.xml").read_text() == "<mine/>\n"  # the link's target, not followed
    assert not (out / "bt.xml").is_symlink() and (out / "bt.xml").read_text().startswith("<?xml")


# --------------------------------------------------- every point of the write phase, in-process
NAMES = ("a.json", "b.png", "report.md")


def _writer(text: str, point: Callable[[str], None]) -> Callable[[Path], None]:
    def write(tmp: Path) -> None:
        for name in NAMES:
            (tmp / name).write_text(f"{text} {name}")
            point(f"temp:{name}")

    return write


def _state(folder: Path) -> str:
    texts = {n: (folder / n).read_text() for n in NAMES if (folder / n).exists()}
    if texts.get("report.md", "").startswith("INCOMPLETE"):
        return "incomplete"
    if texts == {n: f"old {n}" for n in NAMES}:
        return "old"
    if texts == {n: f"new {n}" for n in NAMES}:
        return "new"
    return f"MIXED {texts}"


POINTS = [*(f"temp:{n}" for n in NAMES), "written", "commit:marker", "commit:incomplete",
          *(f"commit:{n}" for n in NAMES)]


@pytest.fixture
def ctrl_c_raises():
    """Ctrl-C raises KeyboardInterrupt here, as in a terminal, even when the tests run as a
    background job (which starts with SIGINT ignored)."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


@pytest.mark.parametrize("how", ["SIGINT", "SIGTERM", "SIGINT twice", "crash"])
def test_every_point_of_the_write_phase_leaves_a_whole_set(tmp_path, monkeypatch, how,
                                                           ctrl_c_raises):
    """A signal (or two Ctrl-Cs) anywhere leaves the old or the new set; a crash (what SIGKILL
    is to the process) leaves them or a report.md saying the set is incomplete; the folder stays
    the pipeline's (a rerun may write there)."""
    from ibt.cli.checks import Terminated
    from ibt.cli.main import _sigterm_unwinds
    from ibt.pipeline import owned_folder

    for index, at in enumerate(POINTS):
        folder = owned_folder.claim(tmp_path / str(index), NAMES)
        owned_folder.write_set(folder, NAMES, _writer("old", lambda _: None), "INCOMPLETE")

        def point(step: str, at: str = at) -> None:
            if step != at:
                return
            if how == "crash":
                raise RuntimeError("crashed")
            for _ in range(2 if how == "SIGINT twice" else 1):
                signal.raise_signal(signal.SIGTERM if how == "SIGTERM" else signal.SIGINT)

        monkeypatch.setattr(owned_folder, "_hook", point)
        folder = owned_folder.claim(tmp_path / str(index), NAMES)
        with _sigterm_unwinds(), pytest.raises((KeyboardInterrupt, Terminated, RuntimeError)):
            owned_folder.write_set(folder, NAMES, _writer("new", point), "INCOMPLETE")
        monkeypatch.setattr(owned_folder, "_hook", lambda step: None)
        state = _state(tmp_path / str(index))
        committing = at.startswith("commit:")
        if how == "crash":
            assert state in (("new",) if at == "commit:report.md" else ("incomplete",)
                             if at != "commit:marker" and committing else ("old",)), at
        else:
            assert state == ("new" if committing else "old"), (at, state)
        owned_folder.claim(tmp_path / str(index), NAMES)  # still the pipeline's folder
        assert not list((tmp_path / str(index)).glob(".ibt-pipeline-new-*"))


def test_the_force_note_names_an_edited_file_as_edited(tmp_path):
    from ibt.pipeline import owned_folder

    folder = owned_folder.claim(tmp_path, NAMES)
    owned_folder.write_set(folder, NAMES, _writer("old", lambda _: None), "INCOMPLETE")
    (tmp_path / "report.md").write_text("the user's edit")
    note = owned_folder.claim(tmp_path, NAMES, force=True).note()
    assert note == (f"--force: replacing report.md (edited since ibt wrote it) in {tmp_path}")


def test_a_file_edited_during_the_run_is_not_replaced(tmp_path):
    from ibt.pipeline import owned_folder

    folder = owned_folder.claim(tmp_path, NAMES)
    owned_folder.write_set(folder, NAMES, _writer("old", lambda _: None), "INCOMPLETE")
    folder = owned_folder.claim(tmp_path, NAMES)
    (tmp_path / "b.png").write_text("the user's")
    with pytest.raises(owned_folder.FolderError, match=r"b\.png changed while the pipeline ran"):
        owned_folder.write_set(folder, NAMES, _writer("new", lambda _: None), "INCOMPLETE")
    assert (tmp_path / "b.png").read_text() == "the user's"
    assert (tmp_path / "report.md").read_text() == "old report.md"


# ------------------------------------------------------------------------------- the cache
def test_an_unwritable_cache_warns_once(tmp_path, monkeypatch):
    import warnings

    from ibt.cache import store as cache

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(cache, "write_entry", refuse)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for i in range(5):
            assert cache.load_or_compute("bt-eval", {"i": i}, lambda i=i: {"x": i},
                                         cache_dir=tmp_path) == {"x": i}
    assert len([w for w in caught if issubclass(w.category, cache.CacheWarning)]) == 1


@pytest.mark.parametrize("payload, says", [
    ({"returns": [1.0, 2.0]}, "2 returns for 3 episodes"),
    ({"returns": [1.0, 2.0, float("inf")]}, "not all finite"),
    ({"mean_return": 1.0, "std_return": -1.0}, "std_return is -1.0"),
    ({"mean_return": 1.0, "std_return": 0.0, "success_rate": 2.1}, "success_rate is 2.1"),
])
def test_a_forged_evaluation_payload_is_a_miss(tmp_path, payload, says):
    """Payload and digest both edited: the digest agrees, the numbers cannot be right."""
    import warnings

    from ibt.cache import store as cache

    params = {"task": "CartPole-v1", "episodes": 3}
    cache.load_or_compute("bt-eval", params, lambda: {"returns": [1.0, 2.0, 3.0]},
                          cache_dir=tmp_path)
    entry = tmp_path / "bt-eval" / cache.cache_key("bt-eval", params)
    data = json.dumps(payload).encode()
    (entry / "payload.json").write_bytes(data)
    manifest = json.loads((entry / "manifest.json").read_text())
    manifest["payload_sha256"] = cache.payload_digest(data)
    (entry / "manifest.json").write_text(json.dumps(manifest))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        again = cache.load_or_compute("bt-eval", params, lambda: {"returns": [4.0, 5.0, 6.0]},
                                      cache_dir=tmp_path)
    assert again == {"returns": [4.0, 5.0, 6.0]}
    assert any(says in str(w.message) for w in caught)


if __name__ == "__main__":  # the table of docs/hostile-files.md, from real runs
    import tempfile

    with tempfile.TemporaryDirectory() as scratch:
        print("| case | command | expected | observed |\n|---|---|---|---|")
        for i, case in enumerate(CASES):
            run, before, after = _run_case(case, Path(scratch) / f"case{i}")
            command = f"python -m {case.module} " + " ".join(a.replace("{u}", "DIR")
                                                              for a in case.argv)
            line = run.stderr.strip().replace(str(Path(scratch) / f"case{i}"), "DIR")
            intact = "files intact" if after == before else "FILES CHANGED"
            print(f"| {case.name} | `{command}` | {case.expected} | exit {run.returncode}; "
                  f"{intact}; `` {line.replace('|', '/')} `` |")
