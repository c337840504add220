"""Bad input fails with a message that names the problem and the fix; the cache is atomic."""

from __future__ import annotations

import shutil

import pytest

import ibt
from ibt.cache.store import cache_key, is_cached, load_or_compute
from ibt.distill.loop import DistillConfig
from ibt.experts.expert import expert_path, load_expert
from ibt.tasks.catalogue import get_task


def test_unknown_task_names_the_closest_ones():
    with pytest.raises(KeyError, match="CartPole-v1"):
        ibt.get_task("CartPole-v2")


def test_unknown_config_parameter_is_named():
    with pytest.raises(TypeError, match=r"n_iteration.*did you mean 'n_iterations'"):
        ibt.config("smoke", n_iteration=3)
    with pytest.raises(ValueError, match="unknown profile"):
        ibt.config("fast")


def test_unknown_method_and_algorithm():
    with pytest.raises(ValueError, match="unknown method 'gail'"):
        DistillConfig(method="gail")
    with pytest.raises(ValueError, match="unknown algorithm 'ddpg'"):
        load_expert(get_task("CartPole-v1"), "ddpg")


def test_missing_expert_says_how_to_train(tmp_path):
    with pytest.raises(FileNotFoundError, match="python -m ibt train CartPole-v1 --algo dqn"):
        load_expert(get_task("CartPole-v1"), "dqn", tmp_path / "dqn.zip")


def test_corrupt_expert_is_refused(tmp_path):
    not_zip = tmp_path / "ppo.zip"
    not_zip.write_bytes(b"this is not a checkpoint")
    with pytest.raises(ValueError, match=r"not a Stable-Baselines3 checkpoint.*"
                       "python -m ibt train CartPole-v1 --algo ppo"):
        load_expert(get_task("CartPole-v1"), "ppo", not_zip)
    truncated = tmp_path / "trunc.zip"
    data = expert_path(get_task("CartPole-v1"), "ppo").read_bytes()
    truncated.write_bytes(data[: len(data) // 2])
    with pytest.raises(ValueError, match="python -m ibt train CartPole-v1 --algo ppo"):
        load_expert(get_task("CartPole-v1"), "ppo", truncated)


def test_mismatched_expert_is_refused(tmp_path):
    other = tmp_path / "ppo.zip"
    shutil.copy(expert_path(get_task("CartPole-v1"), "ppo"), other)
    with pytest.raises(ValueError, match="another task"):
        load_expert(get_task("MountainCar-v0"), "ppo", other)


@pytest.fixture
def demo_kind(monkeypatch):
    """A cache kind of the tests' own, at code version 1."""
    from ibt.cache import store as cache

    monkeypatch.setitem(cache.CODE_VERSIONS, "demo", 1)
    return cache.CODE_VERSIONS


def test_cache_hit_miss_and_atomicity(tmp_path, demo_kind):
    calls = []

    def compute():
        calls.append(1)
        return {"x": 1}

    params = {"a": 1}
    assert load_or_compute("demo", params, compute, cache_dir=tmp_path, codec="json") == {"x": 1}
    assert load_or_compute("demo", params, compute, cache_dir=tmp_path, codec="json") == {"x": 1}
    assert len(calls) == 1
    assert is_cached("demo", params, cache_dir=tmp_path)
    assert cache_key("demo", {"a": 1}) != cache_key("demo", {"a": 2})

    def crash():
        raise RuntimeError("interrupted")

    with pytest.raises(RuntimeError):
        load_or_compute("demo", {"a": 2}, crash, cache_dir=tmp_path)
    assert not is_cached("demo", {"a": 2}, cache_dir=tmp_path)
    leftovers = [p for p in tmp_path.rglob("*") if p.name.startswith(".")]
    assert leftovers == []


def test_refresh_and_profile_come_from_the_environment(monkeypatch):
    monkeypatch.setenv("IBT_PROFILE", "smoke")
    monkeypatch.setenv("IBT_REFRESH", "1")
    monkeypatch.delenv("IBT_SMOKE_DIR", raising=False)
    cfg = ibt.config("paper")
    assert cfg.profile == "smoke" and cfg.refresh
    assert "ibt-smoke-" in str(cfg.cache_dir)  # a scratch folder, never data/


def test_make_figures_time_is_recorded_atomically(tmp_path, capsys):
    import json

    from ibt.notebooks import main, record_time

    path = record_time(42.4, data_dir=tmp_path)
    facts = json.loads(path.read_text())
    assert facts["seconds"] == 42.4 and "cores" in facts["machine"]
    assert [p.name for p in path.parent.iterdir()] == [path.name]  # no temporary file
    assert main(["nonsense"]) == 2
    assert "usage" in capsys.readouterr().err
