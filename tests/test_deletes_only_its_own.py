"""Nothing is deleted that ibt did not write: the cache's upkeep works only in a folder it can
prove is a cache, and removes there only what looks like its own entries; the pipeline's
cleanup of its temporary folders touches only names it recorded; the sweep of temporary files
beside an output only names ``tempfile`` makes. Every test plants a user's files with ibt-like
names and checks their bytes afterwards."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import pytest

from ibt.cache import admin
from ibt.cache.store import ROOT_MARKER, load_or_compute
from tests.test_hostile_files import snapshot

OLD = time.time() - 3600  # an hour ago: past every grace period


def _photos(folder: Path) -> None:
    """A user's folder: photos and letters, in folders (what prune took for incomplete entries)."""
    for name in ("photos", "letters"):
        (folder / name).mkdir(parents=True)
        (folder / name / "one.txt").write_text(f"the user's {name}\n")


def _old(path: Path) -> None:
    os.utime(path, (OLD, OLD))


@pytest.mark.parametrize("command", ["prune", "stale", "verify", "summary"])
def test_upkeep_refuses_a_folder_that_is_not_a_cache(tmp_path, capsys, command):
    _photos(tmp_path)
    before = snapshot(tmp_path)
    assert admin.main([command, "--cache-dir", str(tmp_path), "--incomplete"
                       ][: 4 if command == "prune" else 3]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(tmp_path) in err[0] and "not an ibt cache" in err[0]
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize("command", ["prune", "stale", "verify"])
def test_upkeep_refuses_a_pipeline_output_folder_and_names_its_cache(tmp_path, capsys,
                                                                     command):
    out = tmp_path / "out"
    load_or_compute("tree-eval", {"i": 1}, lambda: {"x": 1}, cache_dir=out / "cache")
    (out / ".ibt-pipeline.json").write_text(json.dumps(
        {"format": "ibt-pipeline/1", "files": {}, "cache": "cache"}))
    (out / "notes.txt").write_text("the user's\n")
    before = snapshot(out)
    assert admin.main([command, "--cache-dir", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "output folder of `python -m ibt pipeline`" in err and str(out / "cache") in err
    assert snapshot(out) == before


def test_a_new_cache_is_marked_and_prune_removes_only_entries_it_wrote(tmp_path, capsys):
    cache = tmp_path / "cache"
    load_or_compute("tree-eval", {"i": 1}, lambda: {"x": 1}, cache_dir=cache)
    assert json.loads((cache / ROOT_MARKER).read_text())["format"] == "ibt-cache/1"
    ours = cache / "tree-eval" / "0123456789abcdef"  # an incomplete entry: no payload
    ours.mkdir()
    (ours / "manifest.json").write_text("{")
    planted = [cache / "tree-eval" / "holiday", cache / "tree-eval" / "fedcba9876543210"]
    for folder in planted:  # a user's folders in the cache, one with a key-like name
        folder.mkdir()
        (folder / "photo.jpg").write_bytes(b"\xff\xd8 the user's photo")
    before = {p: snapshot(p) for p in planted}
    assert admin.main(["prune", "--cache-dir", str(cache), "--incomplete"]) == 0
    assert not ours.exists()
    assert {p: snapshot(p) for p in planted} == before
    assert load_or_compute("tree-eval", {"i": 1}, lambda: {"x": 2}, cache_dir=cache) == {"x": 1}


def test_a_cache_made_before_the_marker_is_recognised_by_its_layout(tmp_path, capsys):
    from ibt.paths import DATA_DIR

    cache = tmp_path / "cache"
    load_or_compute("tree-eval", {"i": 1}, lambda: {"x": 1}, cache_dir=cache)
    (cache / ROOT_MARKER).unlink()  # as the caches written before it
    (cache / "code_hashes.json").write_text("{}")
    assert admin.main(["stale", "--cache-dir", str(cache)]) == 0
    assert admin.main(["verify", "--cache-dir", str(cache)]) == 0
    assert admin.main(["prune", "--cache-dir", str(cache), "--dry-run"]) == 0
    # the committed cache too, unmarked (a checkout stays clean)
    assert not (DATA_DIR / "cache" / ROOT_MARKER).exists()
    from ibt.cache.upkeep import check_cache_root

    check_cache_root(DATA_DIR / "cache")


def test_the_pipeline_removes_only_temporary_folders_it_recorded(tmp_path):
    from ibt.pipeline import owned_folder

    names = ("a.json", "report.md")

    def write(tmp: Path) -> None:
        for name in names:
            (tmp / name).write_text(name)

    unmarked = tmp_path / "unmarked"  # a folder without a marker, and one the pipeline owns
    unmarked.mkdir()
    owned = tmp_path / "owned"
    owned_folder.write_set(owned_folder.claim(owned, names), names, write, "INCOMPLETE")
    killed = owned / f"{owned_folder.TEMP_PREFIX}0123456789ab"  # what a killed run left
    killed.mkdir()
    (killed / "a.json").write_text("half")
    owned_folder._record_temporary(owned, killed.name, add=True)
    planted = []
    for folder in (unmarked, owned):
        for name in ("mine", "0123456789ac"):
            user = folder / f"{owned_folder.TEMP_PREFIX}{name}"
            user.mkdir()
            (user / "letter.txt").write_text("the user's letter\n")
            _old(user)
            planted.append(user)
    _old(killed)
    before = {p: snapshot(p) for p in planted}
    with pytest.raises(owned_folder.FolderError, match=r"did not write: \.ibt-pipeline-new-"):
        owned_folder.claim(unmarked, names)  # the user's folders are not the pipeline's
    for folder in (unmarked, owned):
        claimed = owned_folder.claim(folder, names, force=True)
        owned_folder.write_set(claimed, names, write, "INCOMPLETE")
    assert {p: snapshot(p) for p in planted} == before  # every planted folder intact
    assert not killed.exists()  # the recorded one removed
    marker = json.loads((owned / owned_folder.MARKER).read_text())
    assert marker["temporaries"] == []


def test_the_sweep_beside_an_output_removes_only_tempfile_names(tmp_path):
    from ibt.cli.checks import sweep_temp_files

    target = tmp_path / "bt.json"
    ours = tmp_path / ".bt.json.g_91v2lu.json"  # as tempfile.mkstemp names them
    users = [tmp_path / ".bt.json.backup", tmp_path / ".bt.json.my-old-version.json",
             tmp_path / ".ibt-probe-notes"]
    for path in (ours, *users):
        path.write_text("x")
        _old(path)
    assert sweep_temp_files(target) == [ours]
    assert all(p.exists() for p in users)
