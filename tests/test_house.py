"""One home per concept: a task is one catalogue entry, a synthesiser one module and one line,
and below the boundary (CLI, runs, views) nothing looks a task up by name."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from sklearn.tree import DecisionTreeClassifier

import ibt
from ibt.synth.registry import SYNTHESISERS, Synthesiser, get_synthesiser
from ibt.tasks.settings import TaskBudget, hp
from ibt.tasks.task import Task

ROOT = Path(__file__).resolve().parent.parent
BELOW_THE_BOUNDARY = ("engine", "experts", "evaluate", "distill", "refine", "synth", "bt", "export",
                      "report", "cache")


def test_no_task_lookup_below_the_boundary():
    # Expect: names become tasks in ibt.cli, ibt.runs and ibt.views only (and the catalogue)
    offenders = []
    for package in BELOW_THE_BOUNDARY:
        for path in sorted((ROOT / "ibt" / package).rglob("*.py")):
            for number, line in enumerate(path.read_text().splitlines(), 1):
                if re.search(r"\b(get_task|resolve_task)\(|str \| Task\b|Task \| str\b", line):
                    offenders.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()}")
    assert not offenders, "\n".join(offenders)


def test_tasks_are_hashable_and_an_edited_copy_is_used_as_given():
    from dataclasses import replace

    from ibt.experts.expert import expert_path

    cartpole = ibt.get_task("CartPole-v1")
    edited = replace(cartpole, name="CartPole-edited")
    assert hash(cartpole) != hash(edited) and {cartpole: 1}[cartpole] == 1
    assert expert_path(edited, "ppo").parent.name == "CartPole-edited"  # not the registry's


def test_an_unregistered_task_object_loads_its_checkpoint():
    from dataclasses import replace

    from ibt.experts.expert import expert_path, load_expert

    cartpole = ibt.get_task("CartPole-v1")
    mine = replace(cartpole, name="MyCartPole")  # never registered
    expert = load_expert(mine, "ppo", expert_path(cartpole, "ppo"))
    assert expert.task is mine and expert.n_actions == 2


@pytest.fixture(scope="module")
def toy_task(tmp_path_factory):
    """A new task in one place: its catalogue entry, registered at run time."""
    from ibt.experts.expert import expert_path, train_expert
    from ibt.experts.training import random_baselines
    from ibt.tasks.catalogue import TASKS, register_task

    task = Task(name="ToyLine-v0", gym_id="ToyLine-v0", feature_names=("position",),
                action_names=("left", "stay", "right"), low=(-1.0,), high=(1.0,),
                setup_module="tests.fixtures.toy_line",
                budget=TaskBudget(max_leaf_nodes=4, labels_per_iteration=200),
                experts=(("ppo", hp(4096, 1, n_steps=256, batch_size=64, gamma=0.9)),),
                paper_seeds=1)
    register_task(task)
    experts = tmp_path_factory.mktemp("experts")
    train_expert(task, "ppo", expert_path(task, "ppo", experts), progress=False)
    random_baselines([task], n_episodes=5, path=experts / "random.csv")
    yield task, experts
    TASKS.pop(task.name, None)


def test_a_task_registered_at_run_time_runs_a_two_process_grid(toy_task, tmp_path):
    from ibt.runs import grid

    task, experts = toy_task
    cfg = ibt.config("smoke", cache_dir=tmp_path / "cache", data_dir=tmp_path / "data",
                     experts_dir=experts, n_jobs=2)
    cells = grid.seed_budget(grid.grid([task.name], ["ppo"], ["bc", "imitation-bt"], [0, 1]))
    assert len(cells) == 2  # paper_seeds=1 of the entry
    results = grid.run_grid(cfg, cells, n_jobs=2)  # two worker processes: the Task travels
    assert list(results.task) == ["ToyLine-v0"] * 2 and results.leaves.max() <= 4
    synthesis = grid.synthesize_grid(cfg, results)
    assert set(synthesis.method) == set(SYNTHESISERS)
    assert synthesis.equivalent.all()
    rolled = synthesis[synthesis.evaluated == "BT rollout"]
    assert len(rolled) == len(SYNTHESISERS) and rolled.matches_tree.all()


@pytest.fixture
def toy_synthesiser(monkeypatch):
    entry = Synthesiser("tree-shaped", "tests.fixtures.toy_synthesiser:tree_shaped_bt",
                        on_front=True, description="a test's synthesiser")
    monkeypatch.setitem(SYNTHESISERS, entry.name, entry)
    return entry


def _small_tree(task: Task) -> DecisionTreeClassifier:
    rng = np.random.default_rng(0)
    x = task.sample_features(400, rng)
    y = (x[:, 2] > 0).astype(int)
    return DecisionTreeClassifier(max_leaf_nodes=3, random_state=0).fit(x, y)


def test_a_registered_synthesiser_reaches_the_cli_the_grid_and_the_front(
        toy_synthesiser, tmp_path, capsys):
    from ibt.cli import build_parser, main
    from ibt.distill.tree_file import save_tree_file
    from ibt.runs import front, grid

    task = ibt.get_task("CartPole-v1")
    assert get_synthesiser("tree-shaped") is toy_synthesiser
    # the CLI offers it and writes its verified BT
    assert "tree-shaped" in build_parser().format_help() or main(["synthesize", "--help"]) == 0
    tree_file = save_tree_file(tmp_path / "tree.json", _small_tree(task), task, {})
    assert main(["synthesize", str(tree_file), "--method", "tree-shaped",
                 "-o", str(tmp_path / "bt.json")]) == 0
    assert "tree-shaped" in capsys.readouterr().out
    # the grid synthesises with every registered method
    assert "tree-shaped" in grid.bt_methods()
    cfg = ibt.config("smoke", cache_dir=tmp_path / "cache", data_dir=tmp_path / "data")
    made = grid.synthesize_run(cfg, task, "ppo", "tree-shaped", 0, "imitation-bt")
    assert made["row"]["equivalent"] and made["bt"].node_count > 1
    # the front builds every on-front synthesiser's BT of a tree
    sizes = front.bt_sizes(cfg, task, _small_tree(task))
    assert sizes["nodes_tree_shaped"] >= 1 and "tree-shaped" in front.front_synthesisers()
