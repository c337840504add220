"""The pipeline's output folder (:mod:`ibt.pipeline.owned_folder`): a run replaces only the
files it wrote, refuses the user's before any work (naming them), writes its outputs as one set
recorded in the marker, and removes only the temporary folders and markers it made. In-process
and quick: the command line's refusals are in ``tests/test_hostile_files.py``."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import stat
import threading
import time
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ibt.pipeline import owned_folder
from ibt.pipeline.owned_folder import MARKER, FolderError, claim, release, take, write_set

NAMES = ("a.json", "b.png", "report.md")


def _write(text: str, names: tuple[str, ...] = NAMES):
    def write(tmp: Path) -> None:
        for name in names:
            (tmp / name).write_text(f"{text} {name}")

    return write


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _marker(folder: Path) -> dict:
    return json.loads((folder / MARKER).read_text())


def _ours(folder: Path, text: str = "old") -> None:
    """``folder`` as a finished run leaves it."""
    write_set(claim(folder, NAMES), NAMES, _write(text), "INCOMPLETE")


# ---------------------------------------------------------------------- the claim, before work
def test_a_missing_or_empty_folder_is_claimed_with_nothing_to_replace(tmp_path):
    for path in (tmp_path / "new", tmp_path):
        folder = claim(path, NAMES)
        assert folder.replaceable == {} and folder.forced == [] and folder.kept == []
        assert folder.note() is None and folder.cache is None
    assert not (tmp_path / "new").exists()  # claiming makes nothing


def test_a_folder_that_cannot_be_listed_is_refused(tmp_path):
    (tmp_path / "file").write_text("not a folder")
    with pytest.raises(FolderError, match=r"^-o .*file: cannot list it \(.+\); choose another"):
        claim(tmp_path / "file", NAMES)


def test_the_users_files_are_refused_by_name_and_force_replaces_only_the_outputs(tmp_path):
    (tmp_path / "report.md").write_text("my notes")
    (tmp_path / "notes.txt").write_text("keep me")
    (tmp_path / "photos").mkdir()
    with pytest.raises(FolderError) as err:
        claim(tmp_path, NAMES, option="--out")
    assert str(err.value) == (
        f"--out {tmp_path} holds files ibt pipeline did not write: notes.txt, photos (a "
        "folder), report.md; choose a new or empty folder, or pass --force to replace "
        "report.md (other files are left as they are)")
    folder = claim(tmp_path, NAMES, force=True)
    assert folder.forced == ["report.md"] and folder.kept == ["notes.txt", "photos"]
    assert folder.replaceable == {"report.md": _digest(tmp_path / "report.md")}
    assert folder.note() == (f"--force: replacing report.md in {tmp_path}; left as they are: "
                             "notes.txt, photos")
    write_set(folder, NAMES, _write("new"), "INCOMPLETE")
    assert (tmp_path / "notes.txt").read_text() == "keep me"
    assert (tmp_path / "report.md").read_text() == "new report.md"
    assert claim(tmp_path, NAMES, force=True).forced == []  # now the pipeline's


def test_the_users_files_without_an_output_name_are_refused_without_a_replace_clause(tmp_path):
    (tmp_path / "notes.txt").write_text("keep me")
    with pytest.raises(FolderError, match=r"pass --force \(other files are left as they are\)"):
        claim(tmp_path, NAMES)


def test_a_long_list_of_names_is_cut_after_six(tmp_path):
    for i in range(9):
        (tmp_path / f"user{i}.txt").write_text("x")
    with pytest.raises(FolderError, match=r"did not write: user0\.txt, user1\.txt, user2\.txt, "
                       r"user3\.txt, user4\.txt, user5\.txt and 3 more; choose"):
        claim(tmp_path, NAMES)
    for i in range(3):
        (tmp_path / f"user{i}.txt").unlink()
    with pytest.raises(FolderError, match=r"did not write: user3\.txt, user4\.txt, user5\.txt, "
                       r"user6\.txt, user7\.txt, user8\.txt; choose"):
        claim(tmp_path, NAMES)


def test_a_link_is_forced_as_a_link_and_its_target_left_alone(tmp_path):
    (tmp_path / "mine.png").write_text("my picture")
    (tmp_path / "b.png").symlink_to("mine.png")
    with pytest.raises(FolderError, match=r"b\.png \(a symbolic link\), mine\.png; .* to "
                       r"replace b\.png \(other"):
        claim(tmp_path, NAMES)
    folder = claim(tmp_path, NAMES, force=True)
    assert folder.forced == ["b.png (a symbolic link)"] and folder.kept == ["mine.png"]
    assert folder.replaceable == {"b.png": "link"}
    assert folder.note() == (f"--force: replacing b.png (a symbolic link) in {tmp_path}; a link "
                             "is replaced, its target left alone; left as they are: mine.png")
    write_set(folder, NAMES, _write("new"), "INCOMPLETE")
    assert not (tmp_path / "b.png").is_symlink()
    assert (tmp_path / "b.png").read_text() == "new b.png"
    assert (tmp_path / "mine.png").read_text() == "my picture"
    assert "link" not in json.dumps(_marker(tmp_path)["files"])  # never a digest


def test_a_link_to_a_file_of_ours_is_still_the_users(tmp_path):
    _ours(tmp_path)
    (tmp_path / "extra.json").symlink_to("a.json")
    with pytest.raises(FolderError, match=r"did not write: extra\.json \(a symbolic link\)"):
        claim(tmp_path, NAMES)


def test_a_read_only_output_is_never_replaced_even_with_force(tmp_path):
    (tmp_path / "a.json").write_text("mine")
    (tmp_path / "a.json").chmod(0o444)
    (tmp_path / "notes.txt").write_text("keep me")
    for force in (False, True):
        with pytest.raises(FolderError) as err:
            claim(tmp_path, NAMES, force=force)
        assert str(err.value) == (f"-o {tmp_path} holds a.json (read-only: ibt never replaces "
                                  "it) (and files it did not write: notes.txt); choose another "
                                  "folder")
    (tmp_path / "notes.txt").unlink()
    with pytest.raises(FolderError, match=r"holds a\.json \(read-only: ibt never replaces it\); "
                       "choose another folder$"):
        claim(tmp_path, NAMES, force=True)


def test_a_read_only_file_of_ours_or_marker_is_refused(tmp_path):
    _ours(tmp_path / "file")
    (tmp_path / "file" / "b.png").chmod(0o400)
    with pytest.raises(FolderError, match=r"holds b\.png \(read-only"):
        claim(tmp_path / "file", NAMES, force=True)
    _ours(tmp_path / "marker")
    (tmp_path / "marker" / MARKER).chmod(0o444)
    with pytest.raises(FolderError, match=rf"holds {MARKER} \(read-only\); choose"):
        claim(tmp_path / "marker", NAMES, force=True)


def test_a_read_only_file_that_is_no_output_is_the_users_not_a_refusal(tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    (tmp_path / "notes.txt").chmod(0o444)
    assert claim(tmp_path, NAMES, force=True).kept == ["notes.txt"]


def test_an_output_name_that_is_a_folder_is_refused(tmp_path):
    (tmp_path / "b.png").mkdir()
    with pytest.raises(FolderError, match=r"holds b\.png \(not a regular file\); choose"):
        claim(tmp_path, NAMES, force=True)


@pytest.mark.parametrize("mode, writable", [(0o200, True), (0o020, True), (0o002, True),
                                            (0o644, True), (0o444, False), (0o555, False),
                                            (0o000, False)])
def test_read_only_means_no_write_bit_at_all(tmp_path, mode, writable):
    path = tmp_path / "f"
    path.write_text("x")
    path.chmod(mode)
    try:
        assert owned_folder.read_only(path.stat()) is (not writable)
    finally:
        path.chmod(0o644)


def test_a_file_edited_since_ibt_wrote_it_is_named_as_edited(tmp_path):
    _ours(tmp_path)
    (tmp_path / "a.json").write_text("the user's edit")
    with pytest.raises(FolderError, match=r"did not write: a\.json \(edited since ibt wrote it\);"
                       r" .* to replace a\.json \(other"):
        claim(tmp_path, NAMES)
    folder = claim(tmp_path, NAMES, force=True)
    assert folder.forced == ["a.json (edited since ibt wrote it)"]
    assert folder.replaceable == {"a.json": _digest(tmp_path / "a.json"),
                                  "b.png": _digest(tmp_path / "b.png"),
                                  "report.md": _digest(tmp_path / "report.md")}


def test_a_rerun_replaces_its_own_files_without_force(tmp_path):
    _ours(tmp_path)
    folder = claim(tmp_path, NAMES)
    assert folder.forced == [] and folder.kept == [] and folder.note() is None
    assert folder.replaceable == {n: _digest(tmp_path / n) for n in NAMES}
    text = (tmp_path / MARKER).read_text()  # one key a line, sorted: readable and diffable
    assert text == json.dumps(json.loads(text), indent=1, sort_keys=True) + "\n"
    written = write_set(folder, NAMES, _write("new"), "INCOMPLETE")
    assert written == [tmp_path / n for n in NAMES]
    assert {n: (tmp_path / n).read_text() for n in NAMES} == {n: f"new {n}" for n in NAMES}
    marker = _marker(tmp_path)
    assert marker == {"format": "ibt-pipeline/1", "state": "complete", "cache": None,
                      "temporaries": [], "files": {n: [_digest(tmp_path / n)] for n in NAMES}}
    assert folder.replaceable == {n: _digest(tmp_path / n) for n in NAMES}


def test_an_older_output_of_ours_that_is_no_longer_an_output_is_still_ours(tmp_path):
    _ours(tmp_path)
    assert claim(tmp_path, ("report.md",)).kept == []  # a.json, b.png: ours, not the user's
    assert claim(tmp_path, ("report.md",)).replaceable == {
        "report.md": _digest(tmp_path / "report.md")}


@pytest.mark.parametrize("marker", [
    "not json", "[1, 2]", '{"format": "other/1", "files": {}}',
    '{"format": "ibt-pipeline/1", "files": []}', '{"format": "ibt-pipeline/1"}'])
def test_a_foreign_or_broken_marker_proves_nothing(tmp_path, marker):
    (tmp_path / "a.json").write_text("x")
    (tmp_path / MARKER).write_text(marker.replace("{}", json.dumps(
        {"a.json": [_digest(tmp_path / "a.json")]})))
    with pytest.raises(FolderError, match=r"did not write: a\.json;"):
        claim(tmp_path, NAMES)


def test_a_marker_that_is_a_link_proves_nothing(tmp_path):
    _ours(tmp_path / "real")
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "a.json").write_text("old a.json")
    (tmp_path / "out" / MARKER).symlink_to(tmp_path / "real" / MARKER)
    with pytest.raises(FolderError, match=rf"did not write: {MARKER} \(a symbolic link\), "
                       r"a\.json;"):
        claim(tmp_path / "out", NAMES)


def test_a_digest_is_recorded_as_a_list_or_as_one_string(tmp_path):
    _ours(tmp_path)
    marker = _marker(tmp_path)
    marker["files"] = {n: d[0] for n, d in marker["files"].items()}
    (tmp_path / MARKER).write_text(json.dumps(marker))
    assert claim(tmp_path, NAMES).forced == []
    marker["files"]["a.json"] = 7  # neither: proves nothing
    (tmp_path / MARKER).write_text(json.dumps(marker))
    assert claim(tmp_path, NAMES, force=True).forced == ["a.json (edited since ibt wrote it)"]


def test_sha256_is_the_digest_of_the_whole_file(tmp_path):
    path = tmp_path / "big"
    data = os.urandom((1 << 20) + 17)  # past one read
    path.write_bytes(data)
    assert owned_folder.sha256(path) == hashlib.sha256(data).hexdigest()


# --------------------------------------------------------------------------------- the cache
def test_a_cache_inside_the_folder_is_recorded_and_stays_ours(tmp_path):
    out = tmp_path / "out"
    folder = claim(out, NAMES, cache=out / "cache")
    assert folder.cache == "cache"
    assert claim(out, NAMES, cache=tmp_path / "elsewhere").cache is None
    assert take(folder) is True
    (out / "cache").mkdir()
    assert _marker(out)["cache"] == "cache"
    again = claim(out, NAMES)  # no --cache-dir now: the marker names the cache it made
    assert again.cache == "cache" and again.kept == []
    write_set(again, NAMES, _write("new"), "INCOMPLETE")
    assert _marker(out)["cache"] == "cache"


def test_a_folder_of_the_cache_s_name_is_the_users_where_no_marker_names_it(tmp_path):
    (tmp_path / "cache").mkdir()
    with pytest.raises(FolderError, match=r"did not write: cache \(a folder\);"):
        claim(tmp_path, NAMES)


def test_a_link_named_as_the_cache_is_the_users(tmp_path):
    folder = claim(tmp_path, NAMES, cache=tmp_path / "cache")
    take(folder)
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "cache").symlink_to(tmp_path / "elsewhere")
    with pytest.raises(FolderError, match=r"did not write: cache \(a symbolic link\)"):
        claim(tmp_path, NAMES)


def test_a_file_named_as_the_cache_is_the_users(tmp_path):
    take(claim(tmp_path, NAMES, cache=tmp_path / "cache"))
    (tmp_path / "cache").write_text("mine")
    with pytest.raises(FolderError, match=r"did not write: cache;"):
        claim(tmp_path, NAMES)


def test_take_and_release_leave_a_failed_first_run_s_folder_as_found(tmp_path):
    out = tmp_path / "out"
    folder = claim(out, NAMES)
    assert take(folder) is True and _marker(out)["state"] == "empty"
    assert take(folder) is False  # the marker is there now
    release(folder)
    assert list(out.iterdir()) == []
    folder = claim(out, NAMES, cache=out / "cache")
    take(folder)
    (out / "cache").mkdir()
    release(folder)  # its cache stays, and the marker naming it
    assert _marker(out)["cache"] == "cache"
    (out / "cache").rmdir()
    release(folder)
    assert list(out.iterdir()) == []


def test_release_keeps_a_marker_that_lists_files(tmp_path):
    _ours(tmp_path)
    release(claim(tmp_path, NAMES))
    assert set(_marker(tmp_path)["files"]) == set(NAMES)


def test_take_rewrites_the_marker_only_for_a_new_cache_or_temporaries(tmp_path):
    _ours(tmp_path)
    before = (tmp_path / MARKER).stat().st_mtime_ns, (tmp_path / MARKER).read_text()
    os.utime(tmp_path / MARKER, ns=(1, 1))
    take(claim(tmp_path, NAMES))
    assert (tmp_path / MARKER).stat().st_mtime_ns == 1  # nothing to record: not rewritten
    assert (tmp_path / MARKER).read_text() == before[1]
    take(claim(tmp_path, NAMES, cache=tmp_path / "cache"))
    assert _marker(tmp_path)["cache"] == "cache"
    assert _marker(tmp_path)["files"] == json.loads(before[1])["files"]
    assert _marker(tmp_path)["state"] == "complete"


# ----------------------------------------------------------------------- temporary folders
def test_a_recent_temporary_folder_is_left_for_the_run_that_may_still_use_it(tmp_path):
    _ours(tmp_path)
    recent = tmp_path / f"{owned_folder.TEMP_PREFIX}0123456789ab"
    recent.mkdir()
    owned_folder._record_temporary(tmp_path, recent.name, add=True)
    take(claim(tmp_path, NAMES))
    assert recent.is_dir() and _marker(tmp_path)["temporaries"] == [recent.name]
    old = time.time() - owned_folder.STALE_SECONDS - 5
    os.utime(recent, (old, old))
    take(claim(tmp_path, NAMES))
    assert not recent.exists() and _marker(tmp_path)["temporaries"] == []


def test_a_recorded_temporary_that_is_a_link_or_a_file_is_left_alone(tmp_path):
    out = tmp_path / "out"
    _ours(out)
    (tmp_path / "mine").mkdir()
    link = out / f"{owned_folder.TEMP_PREFIX}aaaaaaaaaaaa"
    link.symlink_to(tmp_path / "mine")
    file = out / f"{owned_folder.TEMP_PREFIX}bbbbbbbbbbbb"
    file.write_text("mine")
    for path in (link, file):
        owned_folder._record_temporary(out, path.name, add=True)
        os.utime(path, (1, 1), follow_symlinks=False)
    os.utime(tmp_path / "mine", (1, 1))
    take(claim(out, NAMES))
    assert link.is_symlink() and (tmp_path / "mine").is_dir() and file.read_text() == "mine"
    assert _marker(out)["temporaries"] == [link.name, file.name]


@pytest.mark.parametrize("names", [
    ["..", "."], ["mine"], [f"{owned_folder.TEMP_PREFIX}a/../../x"], [3], "not a list"])
def test_only_names_the_pipeline_makes_count_as_its_temporaries(names):
    assert owned_folder._temporaries({"temporaries": names}) == []
    ok = f"{owned_folder.TEMP_PREFIX}0123456789ab"
    assert owned_folder._temporaries({"temporaries": [ok]}) == [ok]


def test_a_write_leaves_no_temporary_folder_and_records_none(tmp_path):
    _ours(tmp_path)
    assert not list(tmp_path.glob(f"{owned_folder.TEMP_PREFIX}*"))
    assert _marker(tmp_path)["temporaries"] == []


def test_the_temporary_folder_is_recorded_before_it_is_made(tmp_path):
    take(claim(tmp_path, NAMES))
    tmp = owned_folder._new_temporary(tmp_path)
    assert tmp.is_dir() and tmp.name.startswith(owned_folder.TEMP_PREFIX)
    assert _marker(tmp_path)["temporaries"] == [tmp.name]
    owned_folder._record_temporary(tmp_path, tmp.name, add=False)
    assert _marker(tmp_path)["temporaries"] == []


def test_dropping_one_temporary_keeps_every_other_in_order(tmp_path):
    take(claim(tmp_path, NAMES))
    names = [f"{owned_folder.TEMP_PREFIX}{c * 12}" for c in "cab"]
    for name in names:
        owned_folder._record_temporary(tmp_path, name, add=True)
    assert _marker(tmp_path)["temporaries"] == names
    owned_folder._record_temporary(tmp_path, names[1], add=False)  # "a": before the others
    assert _marker(tmp_path)["temporaries"] == [names[0], names[2]]
    owned_folder._record_temporary(tmp_path, names[0], add=True)  # again: moved last, once
    assert _marker(tmp_path)["temporaries"] == [names[2], names[0]]


# ------------------------------------------------------------------------------ the set
def test_a_run_that_makes_an_output_missing_replaces_nothing(tmp_path):
    _ours(tmp_path)
    with pytest.raises(RuntimeError, match=r"^the pipeline did not make b\.png$"):
        write_set(claim(tmp_path, NAMES), NAMES, _write("new", ("a.json", "report.md")),
                  "INCOMPLETE")
    assert {n: (tmp_path / n).read_text() for n in NAMES} == {n: f"old {n}" for n in NAMES}
    assert not list(tmp_path.glob(f"{owned_folder.TEMP_PREFIX}*"))


def test_an_optional_output_left_out_is_removed_where_ours(tmp_path):
    _ours(tmp_path)
    written = write_set(claim(tmp_path, NAMES), NAMES, _write("new", ("a.json", "report.md")),
                        "INCOMPLETE", optional=("b.png",))
    assert written == [tmp_path / "a.json", tmp_path / "report.md"]
    assert not (tmp_path / "b.png").exists()
    assert set(_marker(tmp_path)["files"]) == {"a.json", "report.md"}


def test_an_optional_output_edited_by_the_user_is_kept_and_stays_listed(tmp_path):
    _ours(tmp_path)
    (tmp_path / "b.png").write_text("the user's")
    folder = claim(tmp_path, NAMES, force=True)
    write_set(folder, NAMES, _write("new", ("a.json", "report.md")), "INCOMPLETE",
              optional=("b.png",))
    assert (tmp_path / "b.png").read_text() == "the user's"
    assert "b.png" in _marker(tmp_path)["files"]  # the old digests: still not provably ours
    assert claim(tmp_path, NAMES, force=True).forced == ["b.png (edited since ibt wrote it)"]


def test_a_file_that_appears_during_the_run_is_not_replaced(tmp_path):
    folder = claim(tmp_path, NAMES)
    (tmp_path / "a.json").write_text("the user's, new")
    with pytest.raises(FolderError, match=r"a\.json changed while the pipeline ran"):
        write_set(folder, NAMES, _write("new"), "INCOMPLETE")
    assert (tmp_path / "a.json").read_text() == "the user's, new"


def test_a_file_made_read_only_during_the_run_is_not_replaced(tmp_path):
    _ours(tmp_path)
    folder = claim(tmp_path, NAMES)
    (tmp_path / "b.png").chmod(0o444)
    with pytest.raises(FolderError, match=r"^-o .*: b\.png changed while the pipeline ran"):
        write_set(folder, NAMES, _write("new"), "INCOMPLETE")
    assert (tmp_path / "b.png").read_text() == "old b.png"


def test_a_file_removed_during_the_run_is_simply_written(tmp_path):
    _ours(tmp_path)
    folder = claim(tmp_path, NAMES)
    (tmp_path / "b.png").unlink()
    write_set(folder, NAMES, _write("new"), "INCOMPLETE")
    assert (tmp_path / "b.png").read_text() == "new b.png"


def test_a_forced_link_replaced_by_a_file_during_the_run_is_not_replaced(tmp_path):
    (tmp_path / "mine.png").write_text("mine")
    (tmp_path / "b.png").symlink_to("mine.png")
    folder = claim(tmp_path, NAMES, force=True)
    (tmp_path / "b.png").unlink()
    (tmp_path / "b.png").write_text("mine too")
    with pytest.raises(FolderError, match=r"b\.png changed"):
        write_set(folder, NAMES, _write("new"), "INCOMPLETE")


def test_mid_commit_the_marker_lists_old_new_and_the_incomplete_report(tmp_path, monkeypatch):
    _ours(tmp_path)
    old = {n: _digest(tmp_path / n) for n in NAMES}
    seen = {}

    def hook(step: str) -> None:
        if step == "commit:incomplete":
            seen["marker"] = _marker(tmp_path)
            seen["report"] = (tmp_path / "report.md").read_text()

    monkeypatch.setattr(owned_folder, "_hook", hook)
    write_set(claim(tmp_path, NAMES), NAMES, _write("new"), "THE SET IS INCOMPLETE")
    new = {n: _digest(tmp_path / n) for n in NAMES}
    stub = hashlib.sha256(b"THE SET IS INCOMPLETE").hexdigest()
    assert seen["report"] == "THE SET IS INCOMPLETE"
    assert seen["marker"]["state"] == "writing"
    assert seen["marker"]["files"] == {"a.json": [old["a.json"], new["a.json"]],
                                       "b.png": [old["b.png"], new["b.png"]],
                                       "report.md": [old["report.md"], new["report.md"], stub]}
    assert _marker(tmp_path)["files"] == {n: [d] for n, d in new.items()}


# --------------------------------------------------------------------- signals held, the law
@pytest.fixture
def ctrl_c_raises():
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def test_signals_wait_for_the_block_and_are_delivered_once_after(ctrl_c_raises):
    got = []
    previous = signal.signal(signal.SIGTERM, lambda s, f: got.append(s))
    try:
        with pytest.raises(KeyboardInterrupt):
            with owned_folder.signals_held():
                signal.raise_signal(signal.SIGTERM)
                signal.raise_signal(signal.SIGINT)
                signal.raise_signal(signal.SIGTERM)
                got.append("block ended")
        assert got == ["block ended", signal.SIGTERM]
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_signals_are_not_touched_outside_the_main_thread():
    seen = []

    def run() -> None:
        with owned_folder.signals_held():
            seen.append(signal.getsignal(signal.SIGTERM))

    before = signal.getsignal(signal.SIGTERM)
    thread = threading.Thread(target=run)
    thread.start()
    thread.join()
    assert seen == [before]


def test_the_test_hook_signals_only_at_its_step(monkeypatch):
    got = []
    previous = signal.signal(signal.SIGUSR1, lambda s, f: got.append(s))
    try:
        monkeypatch.setenv(owned_folder.TEST_SIGNAL_ENV, "written=SIGUSR1")
        owned_folder._hook("commit:marker")
        assert got == []
        owned_folder._hook("written")
        assert got == [signal.SIGUSR1]
    finally:
        signal.signal(signal.SIGUSR1, previous)


_NAME = st.text("abcdefghijklmnopqrstuvwxyz._-", min_size=1, max_size=8).filter(
    lambda n: n not in (".", "..") and not n.startswith(".ibt-pipeline"))


@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(users=st.dictionaries(_NAME, st.binary(max_size=20), max_size=5),
       outputs=st.sets(st.sampled_from(["a.json", "b.png", "c.xml", "x", "y"]), min_size=1,
                       max_size=4))
def test_law_force_changes_only_output_names_and_a_refusal_changes_nothing(tmp_path_factory,
                                                                          users, outputs):
    """For any folder of the user's files: without --force the claim refuses exactly when one
    is there, naming each; with it, the run replaces only files of an output name, and every
    other file keeps its bytes."""
    folder = tmp_path_factory.mktemp("law")
    names = (*sorted(outputs), "report.md")
    for name, data in users.items():
        (folder / name).write_bytes(data)
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    if users:
        with pytest.raises(FolderError) as err:
            claim(folder, names)
        assert all(name in str(err.value) for name in users)
    else:
        assert claim(folder, names).forced == []
    claimed = claim(folder, names, force=True)
    assert sorted(f.split(" (")[0] for f in claimed.forced) == sorted(set(users) & set(names))
    assert claimed.kept == sorted(set(users) - set(names))
    write_set(claimed, names, _write("new", names), "INCOMPLETE")
    after = {p.name: p.read_bytes() for p in folder.iterdir() if p.name != MARKER}
    assert {n: b for n, b in after.items() if n not in names} == {
        n: b for n, b in before.items() if n not in names}
    assert all(after[n] == f"new {n}".encode() for n in names)
    assert stat.S_ISREG((folder / MARKER).lstat().st_mode)
    assert claim(folder, names, force=True).kept == sorted(set(users) - set(names))
