"""A cached computation's source cannot change without a decision: bump or record."""

from __future__ import annotations

import json

from ibt.cache import guard as code_guard


def test_the_recorded_code_versions_and_sources_are_current():
    record = json.loads(code_guard.RECORD.read_text())
    # Expect: no kind whose sources changed without a bump or a recorded decision
    assert code_guard.differences(record) == [], "\n".join(code_guard.differences(record))


def test_a_source_change_without_a_bump_is_caught(monkeypatch):
    record = code_guard.current()
    kind = "refine"
    changed = {**record, kind: {**record[kind], "sources": "0" * 64}}
    lines = code_guard.differences(changed)
    assert len(lines) == 1 and lines[0].startswith("refine: its sources changed")
    bumped = {**record, kind: {**record[kind], "version": -1}}
    assert code_guard.differences(bumped)[0].startswith("refine: version -1 ->")


def test_every_cache_kind_names_existing_sources():
    from ibt.cache.store import CODE_VERSIONS

    assert set(code_guard.KIND_SOURCES) == set(CODE_VERSIONS)
    for sources in code_guard.KIND_SOURCES.values():
        assert all((code_guard.PACKAGE / name).is_file() for name in sources if "*" not in name)


def test_growing_the_key_packages_rekeys_entries_written_under_the_installed_versions(
        tmp_path, monkeypatch):
    from ibt.cache import migrations as cache_migrations
    from ibt.cache import store as cache
    from ibt.cache import upkeep as cache_upkeep

    calls: list[int] = []

    def compute() -> dict:
        calls.append(1)
        return {"x": 1}

    cache.load_or_compute("tree-eval", {"a": 1}, compute, cache_dir=tmp_path, codec="json")
    assert "pyeda" not in cache.KEY_PACKAGES and "pyeda" in cache.TRACKED_PACKAGES
    grown = (*cache.KEY_PACKAGES, "pyeda")  # as numpy and torch joined them
    monkeypatch.setattr(cache, "KEY_PACKAGES", grown)
    monkeypatch.setattr(cache_upkeep, "KEY_PACKAGES", grown)
    monkeypatch.setattr(cache_migrations, "KEY_PACKAGES", grown)
    # Expect: the old entry is now stale (its key lacks the new package) ...
    assert [e.status for e in cache_upkeep.entries(tmp_path)] == ["stale"]
    report = cache_migrations.migrate(tmp_path)
    # ... and after the migration it is current and a lookup hits it without computing
    assert [e.status for e in cache_upkeep.entries(tmp_path)] == ["current"], report
    assert cache.load_or_compute("tree-eval", {"a": 1}, compute, cache_dir=tmp_path,
                                 codec="json") == {"x": 1}
    assert calls == [1]
