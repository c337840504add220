"""The exported XML in the real BehaviorTree.CPP engine (behaviortreepy): every committed BT loads
with only its actions registered and decides as ``ibt`` does, state by state and episode by
episode; the README's Python deployment example runs.

``make test`` checks one committed tree per task (the methods taken in turn); the slow tests
check every ``data/trees/*/*/*.json``.
"""

from __future__ import annotations

import re
from collections import defaultdict
from pathlib import Path

import behaviortreepy as btpy
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ibt.bt.json_io import load_json
from ibt.bt.model import NO_DECISION, Action, BehaviorTree, Condition, Selector, Sequence
from ibt.evaluate.policies import BTPolicy
from ibt.evaluate.rollouts import final_seeds, rollout
from ibt.export.agreement import agreement_states, leaf_regions, threshold_neighbours
from ibt.export.btcpp import BUILTIN_IDS, action_ids, to_btcpp_xml
from ibt.export.engine import EngineTree, compare_rollouts, load_engine_tree, ticks_per_second
from ibt.paths import DATA_DIR
from ibt.tasks.catalogue import get_task

ROOT = Path(__file__).resolve().parent.parent
# discrete-action BTs; those with commands (Box tasks) run as Script nodes and are checked in
# tests/test_continuous_engine.py
TREES = sorted(p for p in DATA_DIR.glob("trees/*/*/*.json") if not get_task(p.parts[-3]).continuous)
XMLS = sorted(p for p in DATA_DIR.glob("trees/*/*/*.xml")  # committed beside the JSON files
              if not get_task(p.parts[-3]).continuous)
ROLLOUT_TASKS = ("CartPole-v1", "MountainCar-v0", "PackageDelivery-v0")
MIN_STATES = 10_000


def _name(path: Path) -> str:
    return "/".join(path.parts[-3:])


def ci_subset(paths: list[Path]) -> list[Path]:
    """One tree per task, deterministic: every method committed is taken by some task that has
    it (the rarest methods first), the other tasks take the methods in turn; the expert is the
    task's i-th among that method's trees."""
    by_task: dict[str, list[Path]] = defaultdict(list)
    for path in paths:
        by_task[path.parts[-3]].append(path)
    tasks = sorted(by_task)
    methods = sorted({p.stem for p in paths},
                     key=lambda m: (sum(any(f.stem == m for f in by_task[t]) for t in tasks), m))
    method_of: dict[str, str] = {}
    for method in methods:
        free = [t for t in tasks if t not in method_of and any(f.stem == method
                                                                 for f in by_task[t])]
        if free:
            method_of[free[0]] = method
    chosen = []
    for i, task in enumerate(tasks):
        method = method_of.get(task, sorted(methods)[i % len(methods)])
        same = [f for f in by_task[task] if f.stem == method] or by_task[task]
        chosen.append(same[i % len(same)])
    return chosen


def _check_agreement(path: Path) -> int:
    task = get_task(path.parts[-3])
    bt = load_json(path)
    engine = load_engine_tree(to_btcpp_xml(bt), task, source=_name(path))
    assert engine.bt.root == bt.root
    states = agreement_states(bt, task, n_random=MIN_STATES, seed=0)
    got, want = engine.decide(states), bt.decide(states)
    bad = np.flatnonzero(got != want)
    assert not len(bad), (f"{_name(path)}: engine and ibt disagree on {len(bad)} of "
                          f"{len(states)} states; first {states[bad[0]].tolist()}: engine "
                          f"{got[bad[0]]}, ibt {want[bad[0]]}")
    assert len(states) >= MIN_STATES and (want != NO_DECISION).all()
    assert engine.actions_ticked == len(states)  # one action a tick (the README's C++ relies on it)
    return len(states)


def test_trees_are_committed_and_the_subset_covers_every_task_and_method():
    assert len(TREES) >= 72
    subset = ci_subset(TREES)
    assert {p.parts[-3] for p in subset} == {p.parts[-3] for p in TREES}
    methods = {p.stem for p in TREES}
    assert {p.stem for p in subset} == methods or len(subset) < len(methods)


@pytest.mark.parametrize("path", ci_subset(TREES), ids=_name)
def test_engine_agrees_with_ibt_on_a_subset_of_committed_trees(path):
    _check_agreement(path)


@pytest.mark.slow
@pytest.mark.parametrize("path", TREES, ids=_name)
def test_engine_agrees_with_ibt_on_every_committed_tree(path):
    _check_agreement(path)


@pytest.mark.parametrize("path", XMLS, ids=_name)
def test_committed_xml_files_run_in_the_engine(path):
    """A committed XML loads with only its actions, decides as ibt reads it, and is the same
    tree as the JSON of the same name."""
    task = get_task(path.parts[-3])
    engine = load_engine_tree(path.read_text(), task, source=_name(path))
    states = agreement_states(engine.bt, task, n_random=2000, seed=0)
    assert np.array_equal(engine.decide(states), engine.bt.decide(states))
    twin = path.with_suffix(".json")
    if twin.exists():
        assert engine.bt.root == load_json(twin).root


@pytest.mark.parametrize("path", [
    *ci_subset(TREES),
    *(pytest.param(p, marks=pytest.mark.slow) for p in TREES if p not in ci_subset(TREES))],
    ids=_name)
def test_leaf_regions_partition_and_decide(path):
    """Each region's witness decides the region's action, and the regions' witnesses cover
    every action the BT takes on random states (a cheap check of leaf_regions itself)."""
    task = get_task(path.parts[-3])
    bt = load_json(path)
    if bt.relational_count:  # relational BTs (issue 26): regions are polytopes
        from ibt.bt.polytope import bt_regions, find_state

        for tests, action in bt_regions(bt):
            state = find_state(bt.n_features, tests, task.low, task.high)
            assert state is None or bt.decide(state[None])[0] == action
        return
    regions = leaf_regions(bt)
    lo = np.array([r.lo for r in regions])
    hi = np.array([r.hi for r in regions])
    x = task.sample_features(2000, np.random.default_rng(1)).astype(np.float64)
    inside = (x[:, None, :] > lo[None]) & (x[:, None, :] <= hi[None])
    member = inside.all(axis=2)
    assert (member.sum(axis=1) == 1).all()  # the boxes partition the space
    region_action = np.array([r.action for r in regions])[member.argmax(axis=1)]
    assert np.array_equal(region_action, bt.decide(x))


# ------------------------------------------------------------------ the engine, exactly
@pytest.fixture(scope="module")
def compare_engine():
    """One tree: ``x > t`` ? go : stop, for any threshold (rebuilt per threshold)."""
    def make(threshold: float, op: str) -> tuple[BehaviorTree, EngineTree]:
        bt = BehaviorTree(Selector((Sequence((Condition(0, op, threshold), Action(0))),
                                    Action(1))), ("x",), ("go", "stop"))
        return bt, EngineTree(to_btcpp_xml(bt), ("x",), ("go", "stop"))
    return make


@settings(max_examples=200, deadline=None)
@given(threshold=st.floats(min_value=-1e30, max_value=1e30, allow_nan=False),
       op=st.sampled_from(["<=", ">"]),
       offsets=st.lists(st.floats(-3, 3, allow_nan=False, width=32), min_size=1, max_size=4))
def test_a_script_condition_compares_exactly_as_ibt(compare_engine, threshold, op, offsets):
    """Law: for any threshold, the float32 values around it and any others decide alike."""
    bt, engine = compare_engine(threshold, op)
    values = [*threshold_neighbours(threshold), *offsets, float(np.float32(threshold))]
    x = np.array(values, dtype=np.float32)[:, None]
    assert np.array_equal(engine.decide(x), bt.decide(x))


def test_builtin_ids_are_the_engines_own():
    """Every name in BUILTIN_IDS that the engine knows as a node is taken in the factory."""
    tags = {"Action", "Condition", "Control", "Decorator", "BehaviorTree", "TreeNodesModel",
            "root", "CheckFeature"}
    for ident in sorted(BUILTIN_IDS - tags):
        with pytest.raises(RuntimeError, match="already registered"):
            btpy.BehaviorTreeFactory().register_simple_action(ident, lambda node: None)


def test_odd_names_load_and_tick_in_the_engine():
    features = ("speed (m/s)", "1st", "true_north", "x.y", "x y")
    actions = ("go left", "1up", "Sequence", "ScriptCondition", "stop")
    root = Selector((*(Sequence((Condition(i, ">", 0.5), Action(i))) for i in range(4)),
                     Action(4)))
    bt = BehaviorTree(root, features, actions)
    engine = EngineTree(to_btcpp_xml(bt), features, actions)
    assert engine.action_ids == action_ids(actions)
    x = np.random.default_rng(0).uniform(0, 1, (400, 5)).astype(np.float32)
    assert np.array_equal(engine.decide(x), bt.decide(x))
    assert set(engine.decide(x)) == set(range(5))


def test_engine_errors_name_the_problem():
    task = get_task("MountainCar-v0")
    bt = load_json(DATA_DIR / "trees/MountainCar-v0/dqn/imitation-bt.json")
    cartpole = get_task("CartPole-v1")
    with pytest.raises(ValueError, match=r"key 'position'.*another task"):
        load_engine_tree(to_btcpp_xml(bt), cartpole)
    with pytest.raises(ValueError, match=r"CheckFeature condition.*portable flavour"):
        load_engine_tree(to_btcpp_xml(bt, flavour="check-feature"), task)
    with pytest.raises(ValueError, match="unknown action ID 'jump'"):
        load_engine_tree(to_btcpp_xml(bt).replace('"left"', '"jump"'), task)
    broken = to_btcpp_xml(bt).replace('code="position', 'code="position +')
    with pytest.raises(ValueError, match="unsupported ScriptCondition"):
        load_engine_tree(broken, task)


# ---------------------------------------------------------------------------- rollouts
def _rollout_trees(task: str) -> list[Path]:
    return [p for p in TREES if p.parts[-3] == task]


def _biggest(task: str) -> Path:
    """The task's largest committed tree (by file size: loading them all takes seconds)."""
    return max(_rollout_trees(task), key=lambda p: (p.stat().st_size, str(p)))


def _check_rollouts(path: Path, episodes: int) -> None:
    task = get_task(path.parts[-3])
    engine = load_engine_tree(path.read_text() if path.suffix == ".xml" else
                              to_btcpp_xml(load_json(path)), task)
    result = compare_rollouts(task, engine, final_seeds(episodes))
    assert result.disagreements == 0
    assert result.ticks == int(result.engine.lengths.sum()) > 0
    assert np.array_equal(result.engine.returns, result.python.returns), _name(path)
    assert np.array_equal(result.engine.lengths, result.python.lengths)


@pytest.mark.parametrize("task", ROLLOUT_TASKS)
def test_engine_rollouts_equal_the_python_bt(task):
    _check_rollouts(_biggest(task), episodes=5)


@pytest.mark.slow
@pytest.mark.parametrize("path", [p for t in ROLLOUT_TASKS for p in _rollout_trees(t)],
                         ids=_name)
def test_engine_rollouts_equal_the_python_bt_for_every_tree(path):
    _check_rollouts(path, episodes=20)


def test_ticks_per_second_measures_both_executors():
    task = get_task("CartPole-v1")
    bt = load_json(DATA_DIR / "trees/CartPole-v1/ppo/imitation-bt.json")
    engine = load_engine_tree(to_btcpp_xml(bt), task)
    rates = ticks_per_second(engine, task.sample_features(200, np.random.default_rng(0)),
                             min_seconds=0.05)
    assert set(rates) == {"BehaviorTree.CPP", "ibt Python executor"}
    assert all(rate > 100 for rate in rates.values())


# ------------------------------------------------------------------------------ README
def readme_python_example() -> str:
    """The Python block of the deployment page, ``docs/deploy.md`` (the README links it)."""
    text = (ROOT / "docs" / "deploy.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, flags=re.DOTALL)
    assert len(blocks) == 1, "the deployment page has exactly one Python block"
    return blocks[0]


def test_readme_python_example_runs_and_matches_the_python_bt(monkeypatch, capsys):
    monkeypatch.chdir(ROOT)
    namespace: dict = {"__name__": "readme_example"}
    exec(compile(readme_python_example(), "README.md", "exec"), namespace)
    task = get_task("MountainCar-v0")
    bt = load_json(ROOT / "data/trees/MountainCar-v0/dqn/imitation-bt.json")
    expected = rollout(task, BTPolicy(task, bt).act, [0]).returns[0]
    assert namespace["episode_return"] == expected
    assert capsys.readouterr().out.strip() == f"return {expected}"
