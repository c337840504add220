"""Plain-data cache payloads: exact round trips, self-verification, and the pickle migration."""

from __future__ import annotations

import json
import math
import sys
import types
import warnings
from contextlib import contextmanager

import joblib
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.tree import DecisionTreeClassifier

import ibt.bt
import ibt.distill
import ibt.refine
from ibt.bt.model import Action, BehaviorTree, Condition, Fallback, Inverter, Selector, Sequence
from ibt.cache import admin as cache_admin
from ibt.cache import migrations as cache_migrations
from ibt.cache import payloads
from ibt.cache import store as cache
from ibt.cache import upkeep as cache_upkeep
from ibt.cache.payloads import CODECS, PayloadError, difference
from ibt.cache.store import CacheWarning, cache_key, load_or_compute
from ibt.distill.loop import Distillation, tree_signature
from ibt.refine.by_return import Refinement
from ibt.refine.tree_arrays import TreeArrays
from tests.privileges import run_unprivileged


@pytest.fixture
def demo(monkeypatch):
    monkeypatch.setitem(cache.CODE_VERSIONS, "demo", 1)
    return cache.CODE_VERSIONS


def _fit(seed: int, n: int, n_features: int, labels: list[int], leaves: int | None,
         weighted: bool = False) -> DecisionTreeClassifier:
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, n_features)).astype(np.float32)
    y = np.array(labels)[rng.integers(0, len(labels), size=n)]
    weight = rng.uniform(0.1, 2.0, size=n) if weighted else None
    return DecisionTreeClassifier(max_leaf_nodes=leaves, random_state=seed).fit(
        x, y, sample_weight=weight)


_trees = st.builds(
    _fit, seed=st.integers(0, 2**16), n=st.integers(2, 80), n_features=st.integers(1, 5),
    labels=st.lists(st.integers(0, 6), min_size=1, max_size=4, unique=True),
    leaves=st.none() | st.integers(2, 12), weighted=st.booleans())
_scalars = (st.none() | st.booleans() | st.integers(-2**70, 2**70) | st.text(max_size=5)
            | st.floats(allow_nan=True, allow_infinity=True)
            | st.floats(width=32).map(np.float32) | st.integers(-9, 9).map(np.int64))
_plain = st.recursive(_scalars, lambda kids: (
    st.lists(kids, max_size=3) | st.lists(kids, max_size=3).map(tuple)
    | st.dictionaries(st.text(max_size=4) | st.sampled_from(["__tuple__", "__array__"]), kids,
                      max_size=3)
    | st.dictionaries(st.integers(0, 5), kids, max_size=2)), max_leaves=8)


def _same_decisions(a: DecisionTreeClassifier, b: DecisionTreeClassifier) -> None:
    assert tree_signature(a) == tree_signature(b)
    x = np.random.default_rng(1).normal(scale=3, size=(200, a.n_features_in_))
    assert np.array_equal(a.predict(x), b.predict(x))
    assert np.array_equal(a.predict_proba(x), b.predict_proba(x))
    assert list(vars(a)) == list(vars(b))
    for name in vars(a):
        assert difference(vars(a)[name], vars(b)[name], name) is None


@settings(max_examples=40, deadline=None)
@given(trees=st.lists(_trees, min_size=1, max_size=3), extra=_plain)
def test_a_distillation_round_trips_exactly(trees, extra):
    trees[0].n_actions_ = 7  # an attribute of our own on a fitted tree is kept too
    run = Distillation("CartPole-v1", "ppo", 3, {"method": "bc", "schedule": {"p": 0.5},
                                                 "extra": extra},
                       iterations=[{"iteration": i, "beta": 1.0 - i / 3, "nodes": np.int64(5),
                                    "selection_mean": float("nan"), "labels": 100}
                                   for i in range(len(trees))],
                       trees=trees, best_index=len(trees) - 1, wall_seconds=1.25)
    back = CODECS["distillation"].loads(CODECS["distillation"].dumps(run))
    assert difference(run, back) is None
    assert type(back) is Distillation
    assert (back.task, back.expert, back.seed, back.best_index, back.wall_seconds) == \
        ("CartPole-v1", "ppo", 3, len(trees) - 1, 1.25)
    assert difference(back.config, run.config) is None and difference(
        back.iterations, run.iterations) is None
    for a, b in zip(run.trees, back.trees, strict=True):
        _same_decisions(a, b)
    assert back.trees[0].n_actions_ == 7


@settings(max_examples=20, deadline=None)
@given(trees=st.lists(_trees, min_size=1, max_size=3))
def test_a_refinement_round_trips_exactly(trees):
    candidates = [TreeArrays.from_sklearn(t) for t in trees]
    refined = Refinement("LunarLander-v3", 1, {"stages": ["thresholds", "prune"],
                                               "max_leaves": None},
                         stages=[{"stage": "thresholds", "history": [(1.5, -2.0), (3.0, 4.25)],
                                  "compare_means": [1.0, float("-inf")]}],
                         candidates=candidates, best_index=0, selection_means=[0.5] * len(trees),
                         episodes=12, steps=3400, wall_seconds=2.5, cpu_seconds=2.25)
    back = CODECS["refinement"].loads(CODECS["refinement"].dumps(refined))
    assert difference(refined, back) is None
    assert isinstance(back.stages[0]["history"][0], tuple)
    for a, b in zip(refined.candidates, back.candidates, strict=True):
        assert type(b) is TreeArrays
        assert tree_signature(a.to_sklearn()) == tree_signature(b.to_sklearn())


def _bt() -> BehaviorTree:
    root = Selector((Sequence((Condition(0, "<=", 0.1 + 0.2), Inverter(Condition(1, ">", -3.5)),
                               Action(1))),
                     Fallback((Sequence((Condition(2, ">", 1e-300), Action(2))), Action(0)))))
    return BehaviorTree(root, ("x", "v", "carrying"), ("left", "right", "wait"),
                        value_labels=((2, ("none", "heavy")),))


def test_a_synthesis_round_trips_exactly():
    value = {"row": {"task": "CartPole-v1", "nodes": 9, "equivalent": True, "seconds": 0.125,
                     "n_numpy": np.int64(3)},
             "bt": _bt()}
    data = CODECS["synthesis"].dumps(value)
    back = CODECS["synthesis"].loads(data)
    assert back["bt"] == value["bt"] and difference(value, back) is None
    doc = json.loads(data)
    assert doc["schema"] == "ibt-synthesis" and doc["schema_version"] == 1
    assert doc["bt"]["format"] == "ibt-behavior-tree/1"  # the data/trees/ format
    with pytest.raises(TypeError, match="synthesis payload"):
        CODECS["synthesis"].dumps({"bt": value["bt"], "row": value["row"]})


@settings(max_examples=100, deadline=None)
@given(_plain)
def test_plain_values_round_trip_with_their_types(value):
    back = payloads.decode(json.loads(json.dumps(payloads.encode(value), allow_nan=False)))
    assert difference(value, back) is None


def test_what_cannot_be_stored_exactly_is_refused():
    for value in ({1, 2}, object(), np.array([1, 2]), 1j, [np.datetime64("2020-01-01")]):
        with pytest.raises(TypeError, match=r"cannot store|cannot hold"):
            payloads.encode(value)
    with pytest.raises(TypeError, match="dtype object"):
        payloads.dumps_npz("ibt-distillation", np.array([None, 1], dtype=object))
    with pytest.raises(TypeError, match="expected a Distillation"):
        CODECS["distillation"].dumps({"task": "x"})
    assert difference(1.0, np.float64(1.0)) is not None  # types count
    assert difference(0.0, -0.0) is not None and difference(math.nan, math.nan) is None
    assert difference({"a": 1, "b": 2}, {"b": 2, "a": 1}) is not None  # so does order


def test_a_payload_of_another_schema_or_version_is_refused(monkeypatch):
    run = Distillation("CartPole-v1", "ppo", 0, {})
    data = CODECS["distillation"].dumps(run)
    with pytest.raises(PayloadError, match="expected schema 'ibt-refinement'"):
        CODECS["refinement"].loads(data)
    monkeypatch.setitem(payloads.SCHEMA_VERSIONS, "ibt-distillation", 2)
    with pytest.raises(PayloadError, match="version 1"):
        CODECS["distillation"].loads(data)
    with pytest.raises(PayloadError, match="not a readable npz"):
        CODECS["distillation"].loads(data[: len(data) // 2])


# --- the cache verifies itself --------------------------------------------------------------

def _entry(root, params):
    return root / "demo" / cache_key("demo", params)


def _run(tree_seed: int = 0) -> Distillation:
    return Distillation("CartPole-v1", "ppo", tree_seed, {"method": "bc"},
                        iterations=[{"iteration": 0}],
                        trees=[_fit(tree_seed, 60, 3, [0, 2], 6)], best_index=0)


def _lookup(root, params, value, calls):
    def compute():
        calls.append(1)
        return value
    return load_or_compute("demo", params, compute, cache_dir=root, codec="distillation")


def _one_warning(record, entry) -> str:
    messages = [str(w.message) for w in record if issubclass(w.category, CacheWarning)]
    assert len(messages) == 1, messages
    assert f"demo/{entry.name}" in messages[0]
    return messages[0]


@pytest.mark.parametrize("damage, message", [
    ("edit", "does not match"), ("swap", "does not match"), ("truncate", "does not match"),
    ("no-digest", "no payload digest"), ("empty-manifest", "unreadable manifest"),
    ("no-payload", "unreadable payload"), ("other-params", "other parameters"),
    ("pickle-codec", "migrate-plain --trust-pickles"),
])
def test_a_damaged_entry_is_recomputed_with_one_warning(tmp_path, demo, damage, message):
    calls: list[int] = []
    first, other = _run(0), _run(1)
    _lookup(tmp_path, {"a": 1}, first, calls)
    _lookup(tmp_path, {"a": 2}, other, calls)
    entry, other_entry = _entry(tmp_path, {"a": 1}), _entry(tmp_path, {"a": 2})
    payload, manifest_file = entry / "payload.npz", entry / "manifest.json"
    manifest = json.loads(manifest_file.read_text())
    if damage == "edit":
        data = bytearray(payload.read_bytes())
        data[len(data) // 2] ^= 0xFF
        payload.write_bytes(bytes(data))
    elif damage == "swap":
        payload.write_bytes((other_entry / "payload.npz").read_bytes())
    elif damage == "truncate":
        payload.write_bytes(payload.read_bytes()[:100])
    elif damage == "no-digest":
        del manifest["payload_sha256"]
        manifest_file.write_text(json.dumps(manifest))
    elif damage == "empty-manifest":
        manifest_file.write_text("")
        assert cache_upkeep.classify(entry).status == "incomplete"
    elif damage == "no-payload":
        payload.unlink()
    elif damage == "other-params":  # a whole entry copied under another key
        manifest_file.write_text((other_entry / "manifest.json").read_text())
        payload.write_bytes((other_entry / "payload.npz").read_bytes())
    else:
        manifest_file.write_text(json.dumps({**manifest, "codec": "joblib"}))
    calls.clear()
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        back = _lookup(tmp_path, {"a": 1}, first, calls)
    assert message in _one_warning(record, entry)
    assert calls == [1] and back is first
    # Expect: the recomputed entry verifies again, a hit without warnings
    calls.clear()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        again = _lookup(tmp_path, {"a": 1}, None, calls)
    assert calls == [] and difference(again, first) is None
    assert sorted(p.name for p in entry.iterdir()) == ["manifest.json", "payload.npz"]


def test_a_lookup_with_another_codec_is_an_error_and_overwrites_nothing(tmp_path, demo):
    from ibt.cache.store import CodecConflict

    load_or_compute("demo", {"a": 1}, lambda: {"x": 1}, cache_dir=tmp_path, codec="json")
    entry = _entry(tmp_path, {"a": 1})
    before = {p.name: p.read_bytes() for p in entry.iterdir()}
    with pytest.raises(CodecConflict, match="stored as 'json' but looked up as 'distillation'"):
        _lookup(tmp_path, {"a": 1}, _run(0), [])
    assert {p.name: p.read_bytes() for p in entry.iterdir()} == before


def test_a_hit_returns_an_equal_value_and_reads_no_pickle(tmp_path, demo, monkeypatch):
    calls: list[int] = []
    _lookup(tmp_path, {"a": 1}, _run(3), calls)
    monkeypatch.setattr("pickle.loads", None)  # any unpickling would fail loudly
    monkeypatch.setattr("pickle.load", None)
    back = _lookup(tmp_path, {"a": 1}, None, calls)
    assert calls == [1] and difference(back, _run(3)) is None


def test_a_payload_that_would_run_code_is_a_miss(tmp_path, demo):
    """An npz whose member is a pickle (an object array) is never unpickled on the read path."""
    import io

    from ibt.cache.store import entry_manifest, manifest_text, payload_digest

    marker = tmp_path / "ran"

    class Boom:
        def __reduce__(self):
            return (open, (str(marker), "w"))

    buffer = io.BytesIO()
    np.savez(buffer, meta=np.array([Boom()], dtype=object))
    data = buffer.getvalue()
    entry = _entry(tmp_path / "c", {"a": 1})
    entry.mkdir(parents=True)
    (entry / "payload.npz").write_bytes(data)
    (entry / "manifest.json").write_text(manifest_text(entry_manifest(
        "demo", {"a": 1}, "distillation", payload_sha256=payload_digest(data))))
    with pytest.warns(CacheWarning, match="undecodable payload"):
        value = _lookup(tmp_path / "c", {"a": 1}, _run(0), [])
    assert type(value) is Distillation and not marker.exists()


def _assert_not_written(root, before):
    after = sorted(str(p.relative_to(root)) for p in root.rglob("*"))
    assert after == before


def test_an_unwritable_cache_returns_the_value_without_writing(tmp_path, demo, monkeypatch):
    """What a read-only folder does to a non-root writer, simulated (tests may run as root)."""
    import ibt.files

    calls: list[int] = []
    _lookup(tmp_path, {"a": 1}, _run(0), calls)
    before = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*"))

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(ibt.files.tempfile, "mkstemp", refuse)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert tree_signature(_lookup(tmp_path, {"a": 1}, None, calls).trees[0]) \
            == tree_signature(_run(0).trees[0])  # a hit writes nothing
    with pytest.warns(CacheWarning, match="not stored .*PermissionError"):
        value = _lookup(tmp_path, {"a": 2}, _run(1), calls)
    assert value.seed == 1 and calls == [1, 1]
    _assert_not_written(tmp_path, before)


#: the two lookups of a read-only cache, run as a user who meets permission bits
READ_ONLY_LOOKUPS = """
import sys, warnings
from pathlib import Path
from ibt.cache import store as cache
from ibt.cache.store import CacheWarning
from tests.test_payloads import _lookup, _run
cache.CODE_VERSIONS["demo"] = 1
root, calls = Path(sys.argv[1]), []
_lookup(root, {"a": 1}, None, calls)  # stored: read, not computed
with warnings.catch_warnings(record=True) as record:
    warnings.simplefilter("always")
    assert _lookup(root, {"a": 2}, _run(1), calls).seed == 1
assert len(calls) == 1, calls
print(*[w.message for w in record if issubclass(w.category, CacheWarning)], sep="\\n")
"""


def test_a_read_only_cache_folder_returns_the_value(tmp_path, demo):
    """Run without root's permission override (CI runs as root, which writes anyway)."""
    calls: list[int] = []
    _lookup(tmp_path, {"a": 1}, _run(0), calls)
    before = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*"))
    folders = [tmp_path, *[p for p in tmp_path.rglob("*") if p.is_dir()]]
    for folder in folders:
        folder.chmod(0o555)
    try:
        done = run_unprivileged([sys.executable, "-c", READ_ONLY_LOOKUPS, str(tmp_path)])
        assert done.returncode == 0, done.stderr
        assert "not stored" in done.stdout and len(done.stdout.splitlines()) == 1, done.stdout
        _assert_not_written(tmp_path, before)
    finally:
        for folder in folders:
            folder.chmod(0o755)


# --- the migration of pickled entries --------------------------------------------------------

def _legacy_pickle_entry(root, kind, params, value, codec_params=None):
    """A committed-style entry whose payload.joblib names the classes' old module paths."""
    folder = root / kind / cache_key(kind, params)
    folder.mkdir(parents=True)
    joblib.dump(value, folder / "payload.joblib", compress=3)
    manifest = {**cache.entry_manifest(kind, params, "joblib"), "wall_seconds": 1.5}
    (folder / "manifest.json").write_text(cache.manifest_text(manifest))
    return folder


@contextmanager
def _old_module_paths():
    """Pickle as the code before the reorganisation did (``ibt.distill.Distillation``, ...)."""
    trees = types.ModuleType("ibt.trees")
    with pytest.MonkeyPatch.context() as m:
        m.setitem(sys.modules, "ibt.trees", trees)
        for module, cls in [(ibt.distill, Distillation), (ibt.refine, Refinement),
                            (trees, TreeArrays),
                            *[(ibt.bt, c) for c in (BehaviorTree, Selector, Fallback, Sequence,
                                                    Inverter, Condition, Action)]]:
            m.setattr(module, cls.__name__, cls, raising=False)
            m.setattr(cls, "__module__", module.__name__)
        yield
    assert Action.__module__ == "ibt.bt.model" and "ibt.trees" not in sys.modules


def test_migrate_plain_converts_pickles_exactly_and_keeps_keys(tmp_path):
    run = _run(5)
    refined = Refinement("CartPole-v1", 0, {"stages": ["prune"]},
                         stages=[{"stage": "prune", "history": [(1.0, 2.0)]}],
                         candidates=[TreeArrays.from_sklearn(run.trees[0])],
                         selection_means=[1.0])
    synthesis = {"row": {"task": "CartPole-v1", "nodes": 5}, "bt": _bt()}
    cases = {"distill": ({"seed": 5}, run), "refine": ({"seed": 0}, refined),
             "synthesis": ({"seed": 1}, synthesis)}
    with _old_module_paths():
        folders = {kind: _legacy_pickle_entry(tmp_path, kind, params, value)
                   for kind, (params, value) in cases.items()}
    json_folder = tmp_path / "bt-eval" / cache_key("bt-eval", {"bt": "x"})
    json_folder.mkdir(parents=True)
    (json_folder / "payload.json").write_text('{"mean_return": 1.5}')
    (json_folder / "manifest.json").write_text(cache.manifest_text(
        cache.entry_manifest("bt-eval", {"bt": "x"}, "json")))
    assert {e.status for e in cache_upkeep.entries(tmp_path)} == {"unmigrated"}
    before = {k: json.loads((f / "manifest.json").read_text()) for k, f in folders.items()}

    assert cache_admin.main(["migrate-plain", "--cache-dir", str(tmp_path),
                             "--trust-pickles"]) == 0
    assert list(tmp_path.rglob("*.joblib")) == []
    assert {e.status for e in cache_upkeep.entries(tmp_path)} == {"current"}
    assert cache_upkeep.verify(tmp_path) == []
    for kind, folder in folders.items():
        manifest = json.loads((folder / "manifest.json").read_text())
        assert manifest.pop("codec") == cache_migrations.PLAIN_CODECS[kind]
        assert len(manifest.pop("payload_sha256")) == 64
        assert manifest == {k: v for k, v in before[kind].items() if k != "codec"}
        params, value = cases[kind]
        back = load_or_compute(kind, params, lambda: pytest.fail("recomputed"),
                               cache_dir=tmp_path, codec=cache_migrations.PLAIN_CODECS[kind])
        assert difference(value, back) is None
    assert load_or_compute("bt-eval", {"bt": "x"}, lambda: pytest.fail("recomputed"),
                           cache_dir=tmp_path, codec="json") == {"mean_return": 1.5}
    # Expect: a re-run changes nothing
    report = cache_migrations.migrate_plain(tmp_path)
    assert not report.converted and not report.digested and sum(report.verified.values()) == 4


def test_an_interrupted_migration_is_finished_by_a_rerun(tmp_path):
    with _old_module_paths():
        folder = _legacy_pickle_entry(tmp_path, "distill", {"seed": 5}, _run(5))
    _, data = cache_migrations.convert_pickle(folder, "distill")
    (folder / "payload.npz").write_bytes(data)  # killed after writing the payload
    assert cache_migrations.migrate_plain(tmp_path).converted == {"distill": 1}
    assert sorted(p.name for p in folder.iterdir()) == ["manifest.json", "payload.npz"]
    assert cache_upkeep.verify(tmp_path) == []


def test_migrate_plain_refuses_pickles_without_trust(tmp_path, capsys):
    marker = tmp_path / "unpickling-ran"

    class Boom:
        def __reduce__(self):
            return (open, (str(marker), "w"))

    folder = _legacy_pickle_entry(tmp_path / "c", "distill", {"seed": 0}, Boom())
    assert cache_admin.main(["migrate-plain", "--cache-dir", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1
    assert "runs whatever code" in err and "--trust-pickles" in err
    assert not marker.exists() and (folder / "payload.joblib").exists()
    # with the flag, the pickle is loaded (the marker proves it ran) and refused as no run
    assert cache_admin.main(["migrate-plain", "--cache-dir", str(tmp_path / "c"),
                             "--trust-pickles"]) == 1
    assert marker.exists() and (folder / "payload.joblib").exists()
    assert "not what distill entries hold" in capsys.readouterr().out
