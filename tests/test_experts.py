"""Committed experts load, answer with scores of shape (batch, n_actions), and are recorded."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from ibt.experts.expert import expert_path, load_expert
from ibt.paths import DATA_DIR
from ibt.tasks.catalogue import BUILTIN_BY_NAME, TASKS, get_task
from ibt.tasks.settings import CONTINUOUS_ALGOS

MANIFEST = pd.read_csv(DATA_DIR / "experts" / "manifest.csv")
COMMITTED = [(t, a) for t, a in zip(MANIFEST.task, MANIFEST.algo, strict=True)
             if expert_path(get_task(t), a).exists()]


def test_every_task_and_algo_has_hyperparameters():
    # the built-in tasks only: other tests register toy tasks of their own in the same process
    builtin = [TASKS[name] for name in BUILTIN_BY_NAME]
    assert all({"dqn", "ppo", "a2c"} <= set(dict(t.experts)) for t in builtin
               if not t.continuous)
    # Box tasks: one expert of an algorithm that acts in a Box
    assert all(dict(t.experts) and set(dict(t.experts)) <= set(CONTINUOUS_ALGOS)
               for t in builtin if t.continuous)


def test_manifest_has_the_required_columns():
    required = {"task", "algo", "timesteps", "seed", "mean_return", "std_return", "n_episodes",
                "wall_seconds"}
    assert required <= set(MANIFEST.columns)
    assert (MANIFEST.n_episodes == 100).all()


@pytest.mark.parametrize(("task", "algo"), COMMITTED)
def test_committed_expert_scores(task, algo):
    spec = get_task(task)
    if spec.continuous:
        pytest.skip("a Box task's expert has no per-action scores: "
                    "test_committed_box_expert_acts_in_its_box")
    expert = load_expert(spec, algo)
    env = spec.make_env()
    obs = np.stack([env.reset(seed=s)[0] for s in range(5)])
    scores = expert.scores(obs)
    assert scores.shape == (5, spec.n_actions)
    assert np.isfinite(scores).all()
    if algo != "dqn":  # log-probabilities
        assert np.allclose(np.exp(scores).sum(axis=1), 1.0, atol=1e-5)
    assert np.array_equal(expert.act(obs), scores.argmax(axis=1))


def test_random_baselines_cover_every_task():
    random = pd.read_csv(DATA_DIR / "experts" / "random.csv")
    assert set(BUILTIN_BY_NAME) <= set(random.task)
    for name in BUILTIN_BY_NAME:
        assert np.isfinite(get_task(name).random_return())


@pytest.mark.slow
def test_training_is_deterministic(tmp_path):
    from ibt.experts.expert import train_expert

    a, b = tmp_path / "a.zip", tmp_path / "b.zip"
    for path in (a, b):
        train_expert(get_task("CartPole-v1"), "ppo", path, timesteps=2048, progress=False)
    obs = np.random.default_rng(0).uniform(-0.2, 0.2, size=(50, 4)).astype(np.float32)
    assert np.array_equal(load_expert(get_task("CartPole-v1"), "ppo", a).scores(obs),
                          load_expert(get_task("CartPole-v1"), "ppo", b).scores(obs))


def test_fast_scores_match_sb3_distribution():
    import torch

    expert = load_expert(get_task("CartPole-v1"), "ppo")
    obs = np.random.default_rng(1).uniform(-0.2, 0.2, size=(32, 4)).astype(np.float32)
    with torch.no_grad():
        dist = expert.model.policy.get_distribution(expert._obs_tensor(obs))
        reference = torch.log_softmax(dist.distribution.logits, dim=-1).numpy()
    assert np.array_equal(expert.scores(obs), reference.astype(np.float64))


def test_training_leaves_no_scratch_folders(tmp_path, monkeypatch):
    """SB3's default logger and the checkpoint callback must not litter the temp folder."""
    import tempfile

    from ibt.experts import expert

    scratch = tmp_path / "tmp"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    # evaluate checkpoints even on this tiny budget, so the callback's folder is exercised
    monkeypatch.setattr(expert, "MIN_STEPS_FOR_CHECKPOINTS", 0)
    monkeypatch.setattr(expert, "EVAL_POINTS", 1)
    monkeypatch.setattr(expert, "EVAL_EPISODES", 1)
    expert.train_expert(get_task("CartPole-v1"), "dqn", tmp_path / "dqn.zip", timesteps=64,
                        progress=False)
    assert (tmp_path / "dqn.zip").exists()
    ours = [p.name for p in scratch.iterdir() if p.name.startswith(("SB3-", "ibt-"))]
    assert ours == []


def test_smoke_profile_shares_one_scratch_folder_per_process(monkeypatch):
    import ibt

    monkeypatch.delenv("IBT_SMOKE_DIR", raising=False)
    monkeypatch.delenv("IBT_PROFILE", raising=False)
    assert ibt.config("smoke").cache_dir == ibt.config("smoke").cache_dir


BOX_COMMITTED = [(t, a) for t, a in COMMITTED if get_task(t).continuous]


def test_the_three_box_experts_are_committed_and_meet_their_bars():
    assert {("Pendulum-v1", "sac"), ("MountainCarContinuous-v0", "sac"),
            ("LunarLanderContinuous-v3", "ppo")} <= set(BOX_COMMITTED)
    rows = MANIFEST[MANIFEST.task.isin([t for t, _ in BOX_COMMITTED])]
    assert rows.meets_bar.all() and (rows.status == "ok").all()


@pytest.mark.parametrize(("task", "algo"), BOX_COMMITTED)
def test_committed_box_expert_acts_in_its_box(task, algo):
    """Action vectors inside the Box, equal to SB3's own deterministic predict; the critic's
    loss is 0 at the expert's action and positive elsewhere; the label's weights are finite."""
    spec = get_task(task)
    expert = load_expert(spec, algo)
    env = spec.make_env()
    obs = np.stack([env.reset(seed=s)[0] for s in range(8)])
    actions = expert.act(obs)
    assert actions.shape == (8, spec.n_actions) and actions.dtype == np.float32
    assert np.array_equal(spec.check_action(actions), actions)
    predicted = np.clip(expert.model.predict(obs, deterministic=True)[0], spec.action_low,
                        spec.action_high)
    assert np.allclose(actions, predicted, atol=1e-6)
    assert np.all(expert.action_loss(obs, actions) == 0.0)
    other = np.clip(-actions + 0.5, spec.action_low, spec.action_high)
    assert expert.action_loss(obs, other).sum() > 0
    labels, weights = expert.label(obs)
    assert np.array_equal(labels, actions) and np.isfinite(weights).all() and (weights >= 0).all()
    with pytest.raises(TypeError, match="Box"):
        expert.scores(obs)


@pytest.mark.parametrize(("task", "algo"), BOX_COMMITTED)
def test_box_actions_and_tensors_are_sb3s_to_the_bit(task, algo):
    """The expert's own short paths (the SAC actor's tanh of its mean without building the
    distribution; a flat observation's tensor without the device lookup) give SB3's numbers
    exactly, for a labelling call's batch (2) and a rollout's (64)."""
    import torch

    spec = get_task(task)
    expert = load_expert(spec, algo)
    policy = expert.model.policy
    obs = np.random.default_rng(3).uniform(-1, 1, size=(64, spec.n_features)).astype(np.float32)
    for batch in (obs[:2], obs):
        tensor = expert._obs_tensor(batch)
        assert torch.equal(tensor, policy.obs_to_tensor(batch)[0])
        with torch.no_grad():
            if algo == "sac":
                raw = policy.unscale_action(policy.actor(tensor, deterministic=True).numpy())
            else:
                raw = policy.get_distribution(tensor).get_actions(deterministic=True).numpy()
        reference = np.clip(raw, spec.action_low, spec.action_high).astype(np.float32)
        assert np.array_equal(expert.act(batch), reference)
