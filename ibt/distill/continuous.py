"""Interactive distillation of an expert with continuous actions into a regression tree.

The loop of :mod:`ibt.distill.loop` with a multi-output ``DecisionTreeRegressor`` fitted on the
expert's action vectors: each iteration rolls out the mixed policy (per step the
expert's action with probability beta_i, else the current tree's) until the iteration's label
budget is spent, the expert labels every visited state, the data are aggregated, a tree is
fitted and scored on held-out episodes; the best tree (highest mean return, then fewest nodes,
then earliest) is the result. The methods are those of :data:`ibt.distill.loop.METHODS` (same
schedules); a weighted method resamples the data with probability proportional to the
expert's critic weight of each state, :meth:`ibt.experts.expert.Expert.label`: the mean loss
``Q(s, pi*(s)) - Q(s, a)`` of random actions ``a`` (SAC/TD3), or of their log-likelihood
(PPO), i.e. how much a wrong action costs there.

A regression tree's leaves are command vectors; :mod:`ibt.synth.commands` merges them into a
few named commands so the paper's synthesis applies to command ids.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from sklearn.tree import DecisionTreeRegressor

from ibt.distill.loop import (
    CommandVectors,
    Distillation,
    MethodSchedule,
    check_loop_settings,
    interactive_loop,
)
from ibt.experts.expert import Expert
from ibt.tasks.settings import BOX_MAX_LEAF_NODES
from ibt.tasks.task import Task

DEFAULT_ITERATIONS = 20  #: iterations where the task's budget names none


@dataclass(frozen=True)
class BoxDistillConfig(MethodSchedule):
    """Everything that determines a continuous distillation run (with the expert and seed)."""

    method: str = "dagger"
    n_iterations: int = DEFAULT_ITERATIONS
    labels_per_iteration: int = 2000
    selection_episodes: int = 20
    max_leaf_nodes: int | None = BOX_MAX_LEAF_NODES
    max_depth: int | None = None
    collect_envs: int = 2
    eval_envs: int = 20

    def __post_init__(self) -> None:
        check_loop_settings(self.method, self.n_iterations, self.labels_per_iteration)
        if self.max_leaf_nodes is not None and self.max_leaf_nodes < 2:
            raise ValueError(f"max_leaf_nodes must be at least 2, got {self.max_leaf_nodes}")

    def as_params(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def for_task(cls, task: Task, **overrides: Any) -> BoxDistillConfig:
        """The task's budget (its catalogue entry), with ``overrides`` on top."""
        b = task.budget
        base = {"max_leaf_nodes": b.max_leaf_nodes, "max_depth": b.max_depth,
                "labels_per_iteration": b.labels_per_iteration,
                "n_iterations": b.max_iterations or DEFAULT_ITERATIONS}
        return cls(**{**base, **overrides})


def regression_signature(tree: DecisionTreeRegressor) -> bytes:
    """A fitted regression tree's decision function as bytes: equal bytes, equal actions."""
    t = tree.tree_
    head = np.array([t.node_count, t.n_outputs, tree.n_features_in_], dtype=np.int64)
    parts = [head, t.feature, t.threshold, t.children_left, t.children_right, t.value]
    return b"".join(np.ascontiguousarray(p).tobytes() for p in parts)


def tree_actions(tree: DecisionTreeRegressor, features: np.ndarray) -> np.ndarray:
    """The tree's action vectors ``(n, dims)`` (float32) for a batch of feature rows."""
    x = np.asarray(features, dtype=np.float32)
    return np.asarray(tree.predict(x), dtype=np.float32).reshape(len(x), -1)


def box_tree_policy(task: Task, tree: DecisionTreeRegressor):
    """``act`` of a regression tree on raw observations."""
    return lambda obs: tree_actions(tree, task.features(obs))


@dataclass(frozen=True)
class RegressionLearner(CommandVectors):
    """A regression tree of action vectors: the interactive loop's learner on a Box task."""

    config: BoxDistillConfig
    seed: int

    def fit(self, x: np.ndarray, y: np.ndarray) -> DecisionTreeRegressor:
        return DecisionTreeRegressor(max_leaf_nodes=self.config.max_leaf_nodes,
                                     max_depth=self.config.max_depth,
                                     random_state=self.seed).fit(x, y)

    def signature(self, tree: DecisionTreeRegressor) -> bytes:
        return regression_signature(tree)

    def predictor(self, tree: DecisionTreeRegressor) -> Callable[[np.ndarray], np.ndarray]:
        return lambda features: tree_actions(tree, features)


def distill_box(task: Task, expert: Expert, config: BoxDistillConfig, seed: int = 0, *,
                progress: bool = True) -> Distillation:
    """Run the interactive loop on a Box task (:func:`ibt.distill.loop.interactive_loop` with
    a :class:`RegressionLearner`); see the module docstring."""
    if not task.continuous or not expert.continuous:
        raise ValueError(f"{task.name} acts in a {'Box' if task.continuous else 'Discrete'} "
                         "space; distill_box is for Box tasks and their experts")
    if expert.n_actions != task.n_actions:
        raise ValueError(f"the expert acts in {expert.n_actions} dimensions, {task.name} in "
                         f"{task.n_actions}")
    return interactive_loop(task, expert, config, seed, RegressionLearner(config, seed),
                            progress=progress)


def regressor_doc(tree: DecisionTreeRegressor) -> dict[str, Any]:
    """A fitted regression tree as plain JSON data (floats by ``repr``: exact round trips),
    what :func:`regressor_from_doc` reads back into a tree that predicts identically."""
    t = tree.tree_
    state = t.__getstate__()
    nodes = state["nodes"]
    return {"n_features": int(tree.n_features_in_), "n_outputs": int(t.n_outputs),
            "max_depth": int(state["max_depth"]), "max_leaf_nodes": tree.max_leaf_nodes,
            "tree_max_depth": tree.max_depth, "random_state": tree.random_state,
            "fields": {name: nodes[name].tolist() for name in nodes.dtype.names},
            "values": t.value[:, :, 0].tolist()}


def regressor_from_doc(doc: dict[str, Any]) -> DecisionTreeRegressor:
    """The regression tree of :func:`regressor_doc`."""
    from sklearn.tree._tree import Tree

    n_outputs = int(doc["n_outputs"])
    template = Tree(int(doc["n_features"]), np.ones(n_outputs, dtype=np.intp), n_outputs)
    dtype = template.__getstate__()["nodes"].dtype
    fields = doc["fields"]
    nodes = np.zeros(len(fields["left_child"]), dtype=dtype)
    for name in dtype.names:
        nodes[name] = fields[name]
    values = np.asarray(doc["values"], dtype=np.float64).reshape(len(nodes), n_outputs, 1)
    template.__setstate__({"max_depth": int(doc["max_depth"]), "node_count": len(nodes),
                           "nodes": nodes, "values": values})
    tree = DecisionTreeRegressor(max_leaf_nodes=doc["max_leaf_nodes"],
                                 max_depth=doc["tree_max_depth"],
                                 random_state=doc["random_state"])
    tree.n_features_in_ = int(doc["n_features"])
    tree.n_outputs_ = n_outputs
    tree.max_features_ = int(doc["n_features"])
    tree.tree_ = template
    return tree
