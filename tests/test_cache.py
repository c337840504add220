"""Cache keys carry code and package versions; stale entries are listed, pruned, migrated."""

from __future__ import annotations

import json

import numpy as np
import pytest
from sklearn.tree import DecisionTreeClassifier

from ibt.cache import admin as cache_admin
from ibt.cache import migrations as cache_migrations
from ibt.cache import store as cache
from ibt.cache import upkeep as cache_upkeep
from ibt.cache.store import cache_key, is_cached, legacy_cache_key, load_or_compute
from ibt.distill.loop import tree_signature


@pytest.fixture
def demo(monkeypatch):
    monkeypatch.setitem(cache.CODE_VERSIONS, "demo", 1)
    return cache.CODE_VERSIONS


def _count(calls):
    def compute():
        calls.append(1)
        return {"n": len(calls)}
    return compute


def test_a_bumped_code_version_misses(tmp_path, demo):
    calls: list[int] = []
    params = {"a": 1}
    load_or_compute("demo", params, _count(calls), cache_dir=tmp_path, codec="json")
    load_or_compute("demo", params, _count(calls), cache_dir=tmp_path, codec="json")
    assert len(calls) == 1  # a hit
    demo["demo"] = 2
    assert not is_cached("demo", params, cache_dir=tmp_path)
    assert load_or_compute("demo", params, _count(calls), cache_dir=tmp_path,
                           codec="json") == {"n": 2}
    # Expect: the old entry is stale (listed and pruned), the new one current
    found = {e.status for e in cache_upkeep.entries(tmp_path)}
    assert found == {"stale", "current"}
    stale = [e for e in cache_upkeep.entries(tmp_path) if e.status == "stale"]
    assert "code version 1 (now 2)" in stale[0].reason
    assert [e.status for e in cache_upkeep.prune(tmp_path)] == ["stale"]
    assert [e.status for e in cache_upkeep.entries(tmp_path)] == ["current"]


def test_an_upgraded_package_misses(tmp_path, demo, monkeypatch):
    calls: list[int] = []
    load_or_compute("demo", {"a": 1}, _count(calls), cache_dir=tmp_path, codec="json")
    real = cache.key_packages()
    assert set(real) == {"gymnasium", "highway-env", "numpy", "scikit-learn", "stable-baselines3",
                         "torch"}
    monkeypatch.setattr(cache, "key_packages", lambda: {**real, "scikit-learn": "99.0"})
    monkeypatch.setattr(cache_upkeep, "key_packages", lambda: {**real, "scikit-learn": "99.0"})
    assert not is_cached("demo", {"a": 1}, cache_dir=tmp_path)
    (entry,) = cache_upkeep.entries(tmp_path)
    assert entry.status == "stale" and "scikit-learn" in entry.reason


def test_unknown_kind_is_an_error(tmp_path):
    with pytest.raises(KeyError, match=r"add it to ibt\.cache\.store\.CODE_VERSIONS"):
        load_or_compute("no-such-kind", {}, dict, cache_dir=tmp_path, codec="json")


def test_manifest_recomputes_its_key(tmp_path, demo):
    load_or_compute("demo", {"a": [1, 2]}, dict, cache_dir=tmp_path, codec="json")
    (folder,) = (tmp_path / "demo").iterdir()
    manifest = json.loads((folder / "manifest.json").read_text())
    assert manifest["code_version"] == 1
    assert cache_key("demo", manifest["params"], version=manifest["code_version"],
                     packages=manifest["key_packages"]) == folder.name
    # a renamed folder is an orphan; a folder without manifest is incomplete
    folder.rename(tmp_path / "demo" / "0000000000000000")
    (tmp_path / "demo" / "1111111111111111").mkdir()
    assert [e.status for e in cache_upkeep.entries(tmp_path)] == ["orphan", "incomplete"]
    assert len(cache_upkeep.prune(tmp_path, dry_run=True)) == 2
    assert len(list(cache_upkeep.entries(tmp_path))) == 2  # a dry run removes nothing


def test_reads_log_lists_unread_entries(tmp_path, demo, monkeypatch):
    load_or_compute("demo", {"a": 1}, dict, cache_dir=tmp_path / "c", codec="json")
    load_or_compute("demo", {"a": 2}, dict, cache_dir=tmp_path / "c", codec="json")
    monkeypatch.setenv(cache.READS_ENV, str(tmp_path / "reads"))
    load_or_compute("demo", {"a": 1}, dict, cache_dir=tmp_path / "c", codec="json")
    reads = cache_upkeep.read_log(tmp_path / "reads")
    assert reads == {f"demo/{cache_key('demo', {'a': 1})}"}
    unread = cache_upkeep.not_current(tmp_path / "c", reads)
    assert [(e.status, e.key) for e in unread] == [("unread", cache_key("demo", {"a": 2}))]


def _tree(labels: list[int]) -> DecisionTreeClassifier:
    x = np.array([[0.0], [1.0], [2.0], [3.0]])
    return DecisionTreeClassifier(max_leaf_nodes=2, random_state=0).fit(x, labels)


def test_signature_distinguishes_class_labels():
    a, b = _tree([0, 0, 1, 1]), _tree([0, 0, 2, 2])
    # Expect: the same splits and class indices, other labels: other decisions
    assert np.array_equal(a.tree_.threshold, b.tree_.threshold)
    assert a.predict([[3.0]])[0] != b.predict([[3.0]])[0]
    assert tree_signature(a) != tree_signature(b)
    assert tree_signature(a) == tree_signature(_tree([0, 0, 1, 1]))
    # the collision that was
    assert cache_migrations._old_signature(a) == cache_migrations._old_signature(b)


def _legacy_entry(root, kind, params, payload):
    folder = root / kind / legacy_cache_key(kind, params)
    folder.mkdir(parents=True)
    (folder / "payload.json").write_text(json.dumps(payload))
    (folder / "manifest.json").write_text(json.dumps(
        {"kind": kind, "params": params, "codec": "json",
         "versions": cache.package_versions()}))
    return folder


def test_migration_rekeys_only_entries_with_current_versions(tmp_path, demo):
    keep = _legacy_entry(tmp_path, "demo", {"a": 1}, {"x": 1})
    old = _legacy_entry(tmp_path, "demo", {"a": 2}, {"x": 2})
    manifest = json.loads((old / "manifest.json").read_text())
    manifest["versions"]["scikit-learn"] = "0.1"
    (old / "manifest.json").write_text(json.dumps(manifest))
    assert {e.status for e in cache_upkeep.entries(tmp_path)} == {"legacy"}
    report = cache_migrations.migrate(tmp_path)
    assert report.migrated["demo"] == 1 and len(report.refused) == 1
    assert "scikit-learn" in report.refused[0][1]
    assert not keep.exists() and old.exists()
    # Expect: the migrated entry is a hit under today's key, with the same payload
    assert load_or_compute("demo", {"a": 1}, lambda: {"x": "recomputed"}, cache_dir=tmp_path,
                           codec="json") == {"x": 1}
    assert cache_migrations.migrate(tmp_path).migrated == {}  # a re-run changes nothing more
    assert cache_admin.main(["stale", "--cache-dir", str(tmp_path)]) == 0
    assert cache_admin.main(["stale", "--cache-dir", str(tmp_path / "none")]) == 2


def test_stray_temporary_files_are_listed_and_pruned(tmp_path, demo):
    import os
    import time

    load_or_compute("demo", {"a": 1}, dict, cache_dir=tmp_path, codec="json")
    (folder,) = (tmp_path / "demo").iterdir()
    old = [folder / ".payload.json.k3j2_x.json", folder / ".manifest.json.8fq1.json"]
    for path in old:
        path.write_text("{")  # what an atomic write killed mid-way leaves
        stamp = time.time() - 3600
        os.utime(path, (stamp, stamp))
    (folder / ".payload.json.fresh.json").write_text("{")  # a write in progress: left alone
    found = cache_upkeep.not_current(tmp_path)
    assert sorted(e.name for e in found) == sorted(f"demo/{folder.name}/{p.name}" for p in old)
    assert {e.status for e in found} == {"temporary"}
    assert {e.status for e in cache_upkeep.entries(tmp_path)} == {"current"}
    assert len(cache_upkeep.prune(tmp_path)) == 2
    assert sorted(p.name for p in folder.iterdir()) == [
        ".payload.json.fresh.json", "manifest.json", "payload.json"]
    assert load_or_compute("demo", {"a": 1}, lambda: {"x": 2}, cache_dir=tmp_path,
                           codec="json") == {}  # still a hit


def test_an_unreadable_manifest_is_incomplete_and_pruned_only_on_request(tmp_path, demo):
    load_or_compute("demo", {"a": 1}, dict, cache_dir=tmp_path, codec="json")
    load_or_compute("demo", {"a": 2}, dict, cache_dir=tmp_path, codec="json")
    empty = tmp_path / "demo" / cache_key("demo", {"a": 1})
    (empty / "manifest.json").write_text("")
    garbled = tmp_path / "demo" / cache_key("demo", {"a": 2})
    (garbled / "manifest.json").write_text("{not json")
    (tmp_path / "demo" / "2222222222222222").mkdir()  # no payload: nothing to keep
    found = {e.key: e for e in cache_upkeep.entries(tmp_path)}
    assert {e.status for e in found.values()} == {"incomplete"}
    assert "unreadable or empty manifest" in found[empty.name].reason
    # Expect: the payload-less folder goes, the entries that still hold a payload stay
    assert [e.key for e in cache_upkeep.prune(tmp_path)] == ["2222222222222222"]
    assert empty.exists() and garbled.exists()
    assert cache_admin.main(["prune", "--incomplete", "--cache-dir", str(tmp_path)]) == 0
    assert not empty.exists() and not garbled.exists()


def test_unmigrated_entries_are_listed_but_never_pruned(tmp_path, demo):
    load_or_compute("demo", {"a": 1}, dict, cache_dir=tmp_path, codec="json")
    (folder,) = (tmp_path / "demo").iterdir()
    manifest = json.loads((folder / "manifest.json").read_text())
    del manifest["payload_sha256"]
    (folder / "manifest.json").write_text(json.dumps(manifest))
    (entry,) = cache_upkeep.not_current(tmp_path)
    assert entry.status == "unmigrated" and "migrate-plain" in entry.reason
    assert cache_upkeep.prune(tmp_path) == [] and folder.exists()
    assert cache_admin.main(["migrate-plain", "--cache-dir", str(tmp_path)]) == 0  # no pickle
    assert cache_upkeep.not_current(tmp_path) == [] and cache_upkeep.verify(tmp_path) == []
