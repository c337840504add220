"""The lesson's stages: the replayed iteration, the synthesis chain, shift, schedules, edits."""

from __future__ import annotations

import numpy as np
import pytest

import ibt
from ibt.bt.json_io import load_json
from ibt.bt.model import Action, BehaviorTree, Selector, Sequence
from ibt.distill import schedules
from ibt.distill.loop import DistillConfig, distill
from ibt.evaluate.policies import RandomPolicy
from ibt.evaluate.rollouts import final_seeds, rollout
from ibt.paths import DATA_DIR
from ibt.synth.imitation import imitation_bt
from ibt.synth.rules import leaf_paths
from ibt.tasks.catalogue import Task, get_task
from ibt.views import lesson, lesson_edits, lesson_synthesis
from tests.conftest import fit_tree

DELIVERY_BT = DATA_DIR / "trees" / "PackageDelivery-v0" / "dqn" / "imitation-bt.json"


@pytest.fixture(scope="module")
def delivery_bt() -> BehaviorTree:
    return load_json(DELIVERY_BT)


# --------------------------------------------------------------- 1. the replayed iteration
@pytest.mark.parametrize("method", ["imitation-bt", "dagger"])
def test_replay_reproduces_every_tree_of_a_run(method):
    # the replay draws the loop's random numbers in the loop's order, weighted or not
    task = get_task("MountainCar-v0")
    expert = ibt.load_expert(task, "dqn")
    config = DistillConfig.for_task(task, method=method, n_iterations=3,
                                    labels_per_iteration=120, selection_episodes=2,
                                    eval_envs=2)
    run = distill(task, expert, config, seed=3, progress=False)
    seen = []
    last = lesson.replay_iterations(task, expert, config, 3, 2,
                                    lambda i, record: seen.append((i, record)))
    assert lesson.same_tree(last, run.trees[2])
    assert [i for i, _ in seen] == [0, 1, 2]
    for i, record in seen:
        assert len(record["data_y"]) == run.iterations[i]["dataset"]
        assert len(record["step_x"]) == run.iterations[i]["labels"]
        if i == 0:  # no tree yet: the expert drives every step
            assert record["step_actor"].all() and (record["step_tree"] == -1).all()


def test_same_tree_tells_trees_apart():
    a, _ = fit_tree(leaves=6, seed=0)
    b, _ = fit_tree(leaves=6, seed=0)
    c, _ = fit_tree(leaves=6, seed=1)
    assert lesson.same_tree(a, b) and not lesson.same_tree(a, c)


def test_open_iteration_under_smoke(tmp_path):
    cfg = ibt.config("smoke", cache_dir=tmp_path / "cache", progress=False)
    it = lesson.open_iteration(cfg, "MountainCar-v0", "dqn", iteration=99)
    assert it.iteration == cfg.n_iterations - 1  # clipped to the run's last iteration
    assert it.matches_run
    assert it.beta == schedules.linear()(it.iteration, cfg.n_iterations)
    assert it.data.draws.sum() == len(it.data)  # resampled with replacement, as many as rows
    assert set(it.steps.actor) <= {"expert", "tree"}
    facts = it.summary()
    assert facts["steps the expert drove"] + facts["steps the tree drove"] == len(it.steps)
    assert facts["equals the cached run's tree of this iteration"] is True
    answer = lesson.answer_iteration(it)
    assert answer["steps the tree drove"] == facts["steps the tree drove"]


# ---------------------------------------------------------------- 2. the synthesis chain
SYNTHETIC = Task("Synthetic", "none", ("a", "b", "c", "d"), ("u", "v", "w"), (-1,) * 4, (1,) * 4)


@pytest.mark.parametrize("leaves", [4, 12, 24])
def test_synthesis_stages_add_up(leaves):
    tree, _ = fit_tree(leaves=leaves)
    chain = lesson_synthesis.synthesis_stages(tree, SYNTHETIC)
    stages = chain.stages.set_index("stage")
    paths = leaf_paths(tree)
    assert stages.loc["1. decision tree", "nodes"] == tree.tree_.node_count
    assert stages.loc["2. paths", "terms"] == len(paths) == tree.get_n_leaves()
    assert stages.loc["2. paths", "literals"] == sum(len(p.term) for p in paths)
    # minimisation never adds literals; the merge never adds terms
    literals = stages.literals
    assert literals["4. Espresso"] <= literals["3. DNF per action"]
    assert literals["5. threshold merge"] <= literals["4. Espresso"]
    assert stages.terms["5. threshold merge"] <= stages.terms["4. Espresso"]
    bt = imitation_bt(tree, SYNTHETIC).bt
    assert chain.bt == bt
    assert stages.loc["7. Behavior Tree", "nodes"] == bt.node_count
    per_action = chain.per_action
    assert per_action["paths"].sum() == stages.loc["2. paths", "terms"]
    assert per_action["Espresso literals"].sum() == literals["4. Espresso"]
    assert per_action["default"].sum() == 1
    guarded = per_action[~per_action["default"]]
    assert guarded["k in the BT"].sum() == literals["6. ordering and default"]
    breakdown = chain.node_breakdown()
    assert breakdown.loc["total", "Behavior Tree"] == bt.node_count
    assert breakdown["Behavior Tree"].drop("total").sum() == bt.node_count
    assert breakdown.loc["total", "decision tree"] == tree.tree_.node_count
    assert str(bt.node_count) in chain.why_more_nodes()


def test_answer_defaults_lists_every_strategy():
    tree, _ = fit_tree(leaves=10)
    answer = lesson.answer_defaults(tree, SYNTHETIC)
    assert list(answer.index) == ["max_complexity", "most_frequent", "smallest_tree"]
    assert answer.loc["smallest_tree", "BT nodes"] == answer["BT nodes"].min()


# ---------------------------------------------------------------- 3. distribution shift
def test_visited_states_and_support():
    task = get_task("CartPole-v1")
    drivers = {"random": RandomPolicy(2, seed=0), "left": _Constant(0)}
    states, episodes = lesson.visited_states(task, drivers, final_seeds(4))
    assert list(episodes.index) == ["random", "left"]
    for name in drivers:
        assert (states.driver == name).sum() == episodes.loc[name, "states"]
    share = lesson.outside_support(states, "random", task.feature_names)
    # by the box's construction: per feature, 0.5 % of the states on each side (at least the
    # extreme one, as interpolated quantiles put it outside)
    n, k = episodes.loc["random", "states"], task.n_features
    assert share["random"] <= 100 * (2 * 0.005 * n * k + 2 * k) / n
    assert share["left"] > share["random"]  # always pushing left leaves the random box


def test_shift_errors_counts_disagreements():
    task = get_task("CartPole-v1")
    expert = ibt.load_expert(task, "ppo")
    states, _ = lesson.visited_states(task, {"expert": expert}, final_seeds(2))
    tree, _ = fit_tree(leaves=4, n_actions=2)
    errors = lesson.shift_errors(states, task, expert, {"tree": tree})
    x = states[list(task.feature_names)].to_numpy(np.float32)
    expected = 100 * np.mean(ibt.TreePolicy(task, tree).act(x) != expert.act(x))
    assert errors.loc["expert", "tree: % actions != expert"] == pytest.approx(expected)


class _Constant:
    def __init__(self, action: int) -> None:
        self.action = action

    def act(self, obs):
        return np.full(len(obs), self.action)


# ------------------------------------------------------------------------ 4. schedules
def test_schedule_labels_round_trip():
    for label, schedule in lesson.SCHEDULE_CHOICES.items():
        assert lesson.schedule_from_label(label) == schedule
    assert lesson.schedule_from_label("exponential p=0.7") == schedules.exponential(0.7)
    with pytest.raises(ValueError, match="unknown schedule"):
        lesson.schedule_from_label("cosine")


def test_schedule_view_under_smoke(tmp_path):
    cfg = ibt.config("smoke", cache_dir=tmp_path / "cache", progress=False)
    view = lesson.schedule_view(cfg, "CartPole-v1", "ppo", "first_only", 3)
    assert view.tree.get_n_leaves() <= 3
    assert view.facts["BT nodes"] == view.bt.node_count
    assert view.facts["episodes"] == cfg.final_episodes
    run = ibt.distill_cached(cfg, "CartPole-v1", "ppo", "imitation-bt", 0,
                             schedule=schedules.first_only(), max_leaf_nodes=3)
    assert run.config["schedule"]["kind"] == "first_only"
    assert lesson.same_tree(run.best_tree, view.tree)


# ---------------------------------------------------------------------- 5. editing a BT
@pytest.mark.parametrize("value", ["depot", "zone_a", "zone_b", "charger"])
def test_categorical_tests_match_their_values(delivery_bt, value):
    states = lesson_edits.all_states("PackageDelivery-v0")
    code = ("depot", "zone_a", "zone_b", "charger").index(value)
    for op, expected in (("==", states[:, 0] == code), ("!=", states[:, 0] != code)):
        test = lesson_edits.feature_test(delivery_bt, "location", op, value)
        probe = BehaviorTree(Selector((Sequence((test, Action(1))), Action(0))),
                             delivery_bt.feature_names, delivery_bt.action_names)
        assert (probe.decide(states) == 1).tolist() == expected.tolist()


def test_feature_test_rejects_bad_input(delivery_bt):
    with pytest.raises(ValueError, match="unknown feature"):
        lesson_edits.feature_test(delivery_bt, "speed", "<=", 3)
    with pytest.raises(ValueError, match="one of the feature's values"):
        lesson_edits.feature_test(delivery_bt, "location", "==", "moon")
    with pytest.raises(ValueError, match="unknown action"):
        lesson_edits.guard(delivery_bt, [["battery", "<=", 3]], "fly")


def test_add_guard_first_and_last(delivery_bt):
    states = lesson_edits.all_states("PackageDelivery-v0")
    low = states[:, 1] <= 2
    rule = lesson_edits.guard(delivery_bt, [["battery", "<=", 2]], "wait")
    first = lesson_edits.add_guard(delivery_bt, rule, position=0)
    assert first.node_count == delivery_bt.node_count + 3
    assert (first.decide(states)[low] == delivery_bt.action_names.index("wait")).all()
    assert (first.decide(states)[~low] == delivery_bt.decide(states)[~low]).all()
    diff = lesson_edits.decision_diff(delivery_bt, first, states)
    assert len(diff) == int((delivery_bt.decide(states)[low] != 7).sum())
    assert set(diff.after) == {"wait"} and (diff.battery <= 2).all()
    # just before the default: acts only where no rule fired (the default's own region)
    last = lesson_edits.add_guard(delivery_bt, rule, position=-1)
    assert last.root.children[-2:] == (rule, delivery_bt.root.children[-1])
    default = delivery_bt.root.children[-1].action
    changed = last.decide(states) != delivery_bt.decide(states)
    assert (delivery_bt.decide(states)[changed] == default).all()
    assert lesson_edits.decision_diff(delivery_bt, delivery_bt, states).empty


def test_all_states():
    states = lesson_edits.all_states("PackageDelivery-v0")
    assert states.shape == (4 * 11 * 3 * 3 * 3, 5) and len(np.unique(states, axis=0)) == 1188
    with pytest.raises(ValueError, match="continuous"):
        lesson_edits.all_states("CartPole-v1")


def test_evaluate_variants_batch_size_does_not_change_episodes(delivery_bt):
    task = get_task("PackageDelivery-v0")
    policy = ibt.BTPolicy(task, delivery_bt)
    seeds = final_seeds(12)
    table = lesson_edits.evaluate_variants(task, {"bt": policy}, {"drain 2": {"drain_scale": 2}},
                                           seeds)
    reference = rollout(task, policy.act, seeds, n_envs=3, env_kwargs={"drain_scale": 2})
    assert table.loc[0, "mean_return"] == pytest.approx(reference.mean)
    assert table.loc[0, "environment"] == "drain 2" and "battery_failure_rate" in table


def test_guard_sweep_rows(delivery_bt):
    sweep = lesson_edits.guard_sweep(delivery_bt,
                                     [["battery", "<=", 4], ["location", "!=", "charger"]],
                                     "go_charger", [2, 4], "PackageDelivery-v0",
                                     {"d1": {}, "d2": {"drain_scale": 2}}, final_seeds(4))
    assert len(sweep) == 4 and set(sweep["battery <="]) == {2, 4}
    changed = sweep.groupby("battery <=")["states changed"].first()
    assert changed[2] < changed[4]  # a looser guard overrides more states
