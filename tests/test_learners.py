"""The learner registry: which learners the ladder offers an agent, and a learner registered
from outside the engine tried by the ladder like the built-in ones."""

from __future__ import annotations

import json
from types import SimpleNamespace
from typing import Any

import pytest

from ibt.engine import learners
from ibt.engine.learners import (
    BOX,
    DISCRETE,
    LEARNER_DISTIL,
    LEARNERS,
    Learner,
    get_learner,
    learner_of_tree,
    learners_for,
    loop_fit,
    rank,
)


def _agent(continuous: bool, n_features: int) -> Any:
    return SimpleNamespace(continuous=continuous, task=SimpleNamespace(n_features=n_features))


def test_the_built_in_learners_in_the_ladders_order_with_their_kinds():
    assert list(LEARNERS)[:5] == ["axis", "relational", "box", "oblique", "controller"]
    assert get_learner("oblique").kind == get_learner("controller").kind == "controller-distil"
    assert [(get_learner(n).actions, get_learner(n).kind) for n in ("axis", "relational", "box")] \
        == [(DISCRETE, "distill"), (DISCRETE, "distill-rel"), (BOX, "box-distill")]
    assert rank("axis") < rank("relational")


@pytest.mark.parametrize("first", ["ibt.engine.controller_learners", "ibt.engine.learners"])
def test_the_registry_is_the_same_whichever_module_is_imported_first(first):
    import subprocess
    import sys

    said = subprocess.run([sys.executable, "-c", f"import {first}; from ibt.engine.learners "
                           "import LEARNERS; print(' '.join(LEARNERS))"],
                          capture_output=True, text=True, check=False)
    assert said.returncode == 0, said.stderr
    assert said.stdout.split() == ["axis", "relational", "box", "oblique", "controller"]


@pytest.mark.parametrize(("continuous", "n_features", "combined", "offered"), [
    (False, 4, True, ("axis", "relational", "oblique")),
    (False, 4, False, ("axis",)),  # tests that combine features off
    (False, 1, True, ("axis",)),  # one feature: nothing to combine
    (True, 3, True, ("box", "controller")),
    (True, 3, False, ("box",)),
])
def test_an_agent_is_offered_the_learners_that_accept_its_actions(continuous, n_features,
                                                                   combined, offered):
    assert learners_for(_agent(continuous, n_features), combined) == offered


def test_an_unknown_learner_is_named_with_the_known_ones():
    with pytest.raises(ValueError, match=r"unknown learner 'cart'.*axis, relational, box"):
        get_learner("cart")


class Stumps:
    """A toy learner's tree fit: the loop's CART, at most two levels deep (the interactive
    loop's :class:`ibt.distill.loop.Learner`, as a new learner's module would give)."""

    def __init__(self, config: Any, seed: int) -> None:
        from ibt.distill.loop import ClassifierLearner

        self.base, self.config, self.seed = ClassifierLearner(config, seed), config, seed

    def __getattr__(self, name: str) -> Any:  # label, signature, predictor, mix: CART's
        return getattr(self.base, name)

    def fit(self, x: Any, y: Any) -> Any:
        from sklearn.tree import DecisionTreeClassifier

        return DecisionTreeClassifier(max_depth=2, max_leaf_nodes=self.config.max_leaf_nodes,
                                      random_state=self.seed).fit(x, y)


def _stump_settings(cfg: Any, agent: Any, method: str | None, overrides: dict[str, Any]) -> Any:
    from ibt.engine import budgets

    return budgets.distill_config(cfg, agent.task, method or "imitation-bt", **overrides)


def _stump_refine(cfg: Any, agent: Any, tree: Any, seed: int, scale: float,
                  episodes: int | None) -> Any:
    return tree  # a toy: its tree as distilled


STUMP = Learner("stump", DISCRETE, LEARNER_DISTIL, "distillation", _stump_settings,
                loop_fit(Stumps), lambda cfg, agent, run, seed: run.best_tree, _stump_refine)


def test_a_learner_registered_outside_the_engine_is_tried_by_the_ladder(agents, tmp_path,
                                                                       monkeypatch):
    """The recipe of docs/ARCHITECTURE.md: a learner (here in this test) and its registry
    entry, nothing else; the ladder then distils and refines with it at every rung, after the
    built-in ones, and its distillation is cached under the shared kind, keyed on its name."""
    import ibt
    from ibt.engine.agent import sb3_agent
    from ibt.engine.ladder import Settings, run_ladder
    from ibt.tasks.catalogue import resolve_task

    monkeypatch.setattr(learners, "LEARNERS", dict(LEARNERS))  # the registry as it was, after
    learners.register_learner(STUMP)
    agent = sb3_agent(resolve_task("ToyLine-v0"), "ppo", agents / "line.zip")
    assert learners_for(agent) == ("axis", "stump")
    cfg = ibt.config("smoke", cache_dir=tmp_path, progress=False)
    ladder = run_ladder(cfg, agent, Settings(keep=2.0, rungs=(4,), search=False),
                        agent_mean=0.0, random_mean=-10.0)
    assert ladder.steps == ["distil axis at 4 leaves", "refine axis at 4 leaves",
                            "distil stump at 4 leaves", "refine stump at 4 leaves"]
    stumps = [c for c in ladder.candidates if c.learner == "stump"]
    assert [c.stage for c in stumps] == ["distilled", "refined"]
    assert all(c.tree.get_depth() <= 2 for c in stumps) and stumps[0].label == "distilled"
    manifests = list((tmp_path / LEARNER_DISTIL).glob("*/manifest.json"))
    assert len(manifests) == 1
    params = json.loads(manifests[0].read_text())["params"]
    assert (params["learner"], params["learner_version"]) == ("stump", 1)


def test_a_built_in_learner_module_is_among_the_shared_kinds_sources(tmp_path, monkeypatch):
    """A new ``engine/learner_<name>.py`` changes the digest of both shared kinds (the code
    guard then asks for a decision) and no other kind's."""
    import shutil

    from ibt.cache import guard

    package = tmp_path / "ibt"
    shutil.copytree(guard.PACKAGE, package, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(guard, "PACKAGE", package)
    before = guard.current()
    (package / "engine" / "learner_stump.py").write_text("STUMP = 1\n")
    changed = {k for k, v in guard.current().items() if v != before[k]}
    assert changed == {"learner-distil", "learner-refine"}


@pytest.mark.parametrize(("module", "cls", "learner"), [
    ("ibt.distill.oblique", "ObliqueArrays", "oblique"),
    ("ibt.distill.controller", "ControllerArrays", "controller"),
    ("ibt.refine.commands", "CommandArrays", "box")])
def test_the_engine_finds_the_learner_of_a_tree_by_its_class(module, cls, learner):
    from importlib import import_module

    tree = object.__new__(getattr(import_module(module), cls))
    entry = learner_of_tree(tree)
    assert entry is not None and entry.name == learner and entry.measured_as_bt
    assert (entry.lay_out is not None) == (learner != "box")  # box: the front's synthesisers


def test_a_classifier_has_no_learner_of_its_own():
    from sklearn.tree import DecisionTreeClassifier

    assert learner_of_tree(DecisionTreeClassifier()) is None
