"""The interactive loop's progress bar: with ``progress`` it shows iterations and the expert
labels collected on stderr (and leaves no line behind); without it, nothing at all."""

from __future__ import annotations

import textwrap

import numpy as np

from ibt.distill.loop import DistillConfig, LoopProgress, distill
from ibt.experts.callable_agent import load_callable_agent
from ibt.tasks.catalogue import get_task

CARTPOLE = get_task("CartPole-v1")
RULE = """
def act(obs):
    return 1 if obs[2] + 0.1 * obs[3] > 0 else 0
"""


def _distil(tmp_path, progress: bool):
    path = tmp_path / "rule.py"
    path.write_text(textwrap.dedent(RULE))
    expert = load_callable_agent(CARTPOLE, f"{path}:act")
    config = DistillConfig.for_task(CARTPOLE, n_iterations=2, labels_per_iteration=60,
                                    selection_episodes=1, max_leaf_nodes=4)
    return distill(CARTPOLE, expert, config, seed=0, progress=progress)


def test_the_loop_shows_iterations_and_labels_only_when_asked(tmp_path, capfd, monkeypatch):
    monkeypatch.setattr(LoopProgress, "interval", 0.0)  # every batch of labels redraws
    shown = _distil(tmp_path, progress=True)
    err = capfd.readouterr().err
    assert "imitation-bt CartPole-v1/callable s0" in err and "2/2" in err
    assert " labels" in err and "collecting" in err
    assert f"{shown.expert_labels:,} labels" in err  # the count the record keeps
    silent = _distil(tmp_path, progress=False)
    said = capfd.readouterr()
    assert said.err == "" and said.out == ""
    # the bar changes nothing the loop decides
    assert [it["selection_mean"] for it in silent.iterations] == [
        it["selection_mean"] for it in shown.iterations]
    assert np.array_equal(silent.best_tree.tree_.threshold, shown.best_tree.tree_.threshold)
