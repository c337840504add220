"""A decision tree whose splits may be relational: CART on derived features.

A :class:`RelationalTreeClassifier` is a scikit-learn tree fitted on observations augmented
with derived columns (:class:`ibt.bt.linear.FeatureMap`), so column ``k >= n_features`` of its
``tree_`` is the linear form ``feature_map_.form(k)``. ``predict``/``apply``/``predict_proba``
/``decision_path`` take *observed* rows (``n_features`` columns) and augment them first by the
floating-point rule of :mod:`ibt.bt.linear`; everything that reads ``tree_`` (rules, Espresso,
synthesis, refinement) sees augmented column indices.

**The learner** (:func:`fit_relational_tree`): CART grown best-first (as scikit-learn grows a
tree with ``max_leaf_nodes``: the leaf whose best split decreases the weighted Gini impurity
most is split next), where each node's split is searched over the axis-aligned columns *and*
the candidate derived columns (every pair of non-binary features with every weight pair of
:data:`ibt.bt.linear.DEFAULT_WEIGHTS`; beyond :data:`MAX_PAIRED_FEATURES` such features, the
pairs among those an axis-aligned tree on the same rows uses, most important first, so the
columns, and memory, grow linearly with the features), and a relational split is taken only
where its impurity decrease exceeds the best axis-aligned split's by the factor ``1 + margin``
(:data:`DEFAULT_MARGIN`): a harder-to-read test must pay for itself. The search per node runs
on per-column histograms (at most :data:`MAX_BINS` candidate thresholds per column, from the
column's quantiles over the whole fit set); the best axis-aligned and the best relational
column are then rescanned exactly on the node's rows (every midpoint between two distinct
values, scikit-learn's threshold rule), and the exact decreases decide. The fitted tree keeps
only the derived columns it uses. No randomness: the result depends on the data only (the
``seed`` is recorded as ``random_state``).
"""

from __future__ import annotations

import heapq
from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from sklearn.tree import DecisionTreeClassifier

from ibt.bt.linear import DEFAULT_WEIGHTS, FeatureMap, LinearForm
from ibt.tasks.task import Task

#: a relational split must decrease the impurity by this factor more than the best axis split
#: (chosen before any result was seen: a tenth more, the least that is not noise at a leaf)
DEFAULT_MARGIN = 0.1
MAX_BINS = 255  # candidate thresholds per column in the histogram search
_CHUNK = 1 << 22  # histogram entries per bincount call (memory bound)
_PURE = 1e-7  # a node with less Gini impurity is a leaf (scikit-learn's EPSILON is smaller)
#: at most this many features are paired into derived columns (every task of the catalogue
#: has fewer, highway-fast-v0 the most with 25, so none of their candidates changes): beyond,
#: C(n, 2) pairs of a 1,000-feature task would take gigabytes
MAX_PAIRED_FEATURES = 32


class RelationalTreeClassifier(DecisionTreeClassifier):
    """CART over a :class:`FeatureMap`'s augmented columns; decides on observed rows."""

    feature_map_: FeatureMap

    def fit_relational(self, X: np.ndarray, y: np.ndarray, feature_map: FeatureMap,
                       sample_weight: np.ndarray | None = None) -> RelationalTreeClassifier:
        """Fit on ``feature_map.augment(X)``; remember the map."""
        self.feature_map_ = feature_map
        super().fit(feature_map.augment(X), y, sample_weight=sample_weight)
        return self

    def _augmented(self, X: Any) -> np.ndarray:
        x = np.atleast_2d(np.asarray(X, dtype=np.float64))
        if x.shape[1] == self.feature_map_.width and self.feature_map_.forms:
            raise ValueError("a relational tree takes observed rows "
                             f"({self.feature_map_.n_features} features), not augmented ones")
        return self.feature_map_.augment(x)

    def predict(self, X: Any, check_input: bool = True) -> np.ndarray:
        return super().predict(self._augmented(X), check_input=check_input)

    def predict_proba(self, X: Any, check_input: bool = True) -> Any:
        return super().predict_proba(self._augmented(X), check_input=check_input)

    def apply(self, X: Any, check_input: bool = True) -> np.ndarray:
        return super().apply(self._augmented(X), check_input=check_input)

    def decision_path(self, X: Any, check_input: bool = True) -> Any:
        return super().decision_path(self._augmented(X), check_input=check_input)

    @property
    def n_relational(self) -> int:
        """How many of the tree's splits are relational tests."""
        t = self.tree_
        split = t.children_left != -1
        return int((t.feature[split] >= self.feature_map_.n_features).sum())


def feature_map_of(tree: Any) -> FeatureMap | None:
    """A relational tree's feature map, ``None`` for an axis-aligned tree."""
    return getattr(tree, "feature_map_", None)


def relational_tests(tree: Any) -> int:
    """The number of relational splits of a tree (0 for an axis-aligned one)."""
    return tree.n_relational if isinstance(tree, RelationalTreeClassifier) else 0


# --- the learner -----------------------------------------------------------------------------

@dataclass(frozen=True)
class RelationalSettings:
    """What the relational learner tries: weight pairs and the margin a relational split must
    beat the best axis split by."""

    weights: tuple[tuple[float, float], ...] = DEFAULT_WEIGHTS
    margin: float = DEFAULT_MARGIN
    max_bins: int = MAX_BINS

    def as_params(self) -> dict[str, Any]:
        return {"weights": [list(w) for w in self.weights], "margin": self.margin,
                "max_bins": self.max_bins}


def _non_binary(x: np.ndarray) -> list[int]:
    """The features that take more than two values in ``x`` (a binary flag, such as a leg's
    ground contact, gains nothing from a weighted sum)."""
    return [i for i in range(x.shape[1]) if len(np.unique(x[:, i][:64_000])) > 2]


def paired_features(x: np.ndarray, among: Sequence[int] | None = None) -> list[int]:
    """The features whose pairs become candidate columns: the non-binary ones of ``x`` (those
    of ``among`` where given, in its order of preference), at most :data:`MAX_PAIRED_FEATURES`
    of them (the first: by index where ``among`` is not given), in index order."""
    features = _non_binary(x)
    if among is not None:
        allowed = set(features)
        features = [i for i in among if i in allowed]
    return sorted(features[:MAX_PAIRED_FEATURES])


def axis_preferred(x: np.ndarray, y: np.ndarray, sample_weight: np.ndarray | None = None,
                   max_leaf_nodes: int | None = None) -> list[int] | None:
    """Where ``x`` has more than :data:`MAX_PAIRED_FEATURES` non-binary features: those an
    axis-aligned tree on the same rows uses, most important first (then the rest in index
    order); None otherwise (every feature is paired)."""
    if len(_non_binary(x)) <= MAX_PAIRED_FEATURES:
        return None
    tree = DecisionTreeClassifier(max_leaf_nodes=max(max_leaf_nodes or 0, MAX_PAIRED_FEATURES),
                                  random_state=0).fit(x, y, sample_weight=sample_weight)
    importance = tree.feature_importances_
    return sorted(range(x.shape[1]), key=lambda i: (-importance[i], i))


def candidate_map(x: np.ndarray, weights: Sequence[tuple[float, float]] = DEFAULT_WEIGHTS,
                  among: Sequence[int] | None = None) -> FeatureMap:
    """Every pair of the paired features of ``x`` (:func:`paired_features`) with every weight
    pair."""
    x = np.asarray(x)
    return FeatureMap.pairs(x.shape[1], weights, paired_features(x, among))


def one_significant(value: float) -> float:
    """``value`` rounded to one significant digit (a weight a reader can say: 0.07, 3, 20)."""
    if value == 0 or not np.isfinite(value):
        raise ValueError(f"a weight must be finite and non-zero, got {value!r}")
    return float(f"{value:.0e}")


def scaled_candidate_map(x: np.ndarray,
                         weights: Sequence[tuple[float, float]] = DEFAULT_WEIGHTS) -> FeatureMap:
    """:func:`candidate_map` with each pair's second weight scaled by the ratio of the two
    features' spreads (standard deviations in ``x``), to one significant digit: fixed weights
    of 0.5 to 2 cannot relate features whose scales differ (MountainCar's position spreads
    about 13 times as far as its velocity); where the ratio rounds to 1 the candidates are
    :func:`candidate_map`'s. A feature that does not vary is left out."""
    x = np.asarray(x, dtype=np.float64)
    spread = x.std(axis=0)
    features = [i for i in paired_features(x) if spread[i] > 0]
    forms: list[LinearForm] = []
    for a, i in enumerate(features):
        for j in features[a + 1:]:
            ratio = one_significant(spread[i] / spread[j])
            for w1, w2 in weights:
                form = LinearForm(i, j, w1, one_significant(w2 * ratio))
                if form not in forms:
                    forms.append(form)
    return FeatureMap(x.shape[1], tuple(forms))


@dataclass
class _Split:
    gain: float  # Gini decrease of the node (not weighted by the node's share)
    column: int
    threshold: float


@dataclass
class _Node:
    rows: np.ndarray
    depth: int
    counts: np.ndarray  # weighted class counts
    split: _Split | None = None
    left: int = -1
    right: int = -1


def _gini(counts: np.ndarray) -> float:
    total = counts.sum()
    return 0.0 if total <= 0 else float(1.0 - np.square(counts / total).sum())


def _edges(column: np.ndarray, max_bins: int) -> np.ndarray:
    """Candidate thresholds of a column: distinct values at its quantiles (``v <= edge``)."""
    values = np.unique(column)
    if len(values) > max_bins + 1:
        pick = np.unique(np.linspace(0, len(values) - 1, max_bins + 1).round().astype(np.int64))
        values = values[pick]
    return values[:-1]  # the largest value splits nothing off


def _exact(values: np.ndarray, y: np.ndarray, w: np.ndarray, n_classes: int
           ) -> tuple[float, float]:
    """The best (Gini decrease, threshold) on one column by a full scan, scikit-learn's rule:
    thresholds at midpoints of consecutive distinct float32 values."""
    order = np.argsort(values, kind="stable")
    v = values[order].astype(np.float64)
    onehot = np.zeros((len(v), n_classes))
    onehot[np.arange(len(v)), y[order]] = w[order]
    cumulative = np.cumsum(onehot, axis=0)
    left, total = cumulative[:-1], cumulative[-1]
    right = total - left
    wl, wr = left.sum(axis=1), right.sum(axis=1)
    valid = (v[1:] > v[:-1]) & (wl > 0) & (wr > 0)
    if not valid.any():
        return -np.inf, 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        gl = 1.0 - np.square(left / wl[:, None]).sum(axis=1)
        gr = 1.0 - np.square(right / wr[:, None]).sum(axis=1)
    W = total.sum()
    gain = _gini(total) - (wl * gl + wr * gr) / W
    gain = np.where(valid, gain, -np.inf)
    k = int(np.argmax(gain))
    a, b = v[k], v[k + 1]
    t = a / 2.0 + b / 2.0
    if t == b or not np.isfinite(t):  # scikit-learn's rule for neighbours
        t = a
    return float(gain[k]), float(t)


class _Search:
    """Split search over histogram bins of every column, then an exact rescan."""

    def __init__(self, xf: np.ndarray, y: np.ndarray, w: np.ndarray, n_classes: int,
                 n_axis: int, settings: RelationalSettings) -> None:
        self.x, self.y, self.w, self.k = xf, y, w, n_classes
        self.n_axis = n_axis
        self.margin = settings.margin
        edges = [_edges(xf[:, c], settings.max_bins) for c in range(xf.shape[1])]
        self.n_edges = np.array([len(e) for e in edges])
        self.n_bins = int(self.n_edges.max()) + 1
        self.bins = np.empty(xf.shape, dtype=np.int32)
        for c, e in enumerate(edges):  # bin b: e[b-1] < v <= e[b]
            self.bins[:, c] = np.searchsorted(e, xf[:, c], side="left")

    def best(self, rows: np.ndarray, counts: np.ndarray) -> _Split | None:
        gains = self._histogram_gains(rows, counts)
        on_axis, derived = gains[:self.n_axis], gains[self.n_axis:]
        axis: int | None = int(np.argmax(on_axis)) if np.isfinite(on_axis).any() else None
        rel: int | None = (self.n_axis + int(np.argmax(derived))
                           if len(derived) and np.isfinite(derived).any() else None)
        exact = {c: _exact(self.x[rows, c], self.y[rows], self.w[rows], self.k)
                 for c in (axis, rel) if c is not None}
        axis_gain = exact[axis][0] if axis is not None else -np.inf
        pick = axis if axis_gain > 0 else None
        if rel is not None and exact[rel][0] > 0 and (
                exact[rel][0] > (1.0 + self.margin) * max(axis_gain, 0.0)):
            pick = rel  # a relational split pays for itself
        if pick is None:
            return None
        gain, threshold = exact[pick]
        return _Split(gain, pick, threshold)

    def _histogram_gains(self, rows: np.ndarray, counts: np.ndarray) -> np.ndarray:
        n_cols, nb, k = self.x.shape[1], self.n_bins, self.k
        hist = np.zeros((n_cols, nb, k))
        yw = self.y[rows]
        w = self.w[rows]
        step = max(1, _CHUNK // max(1, len(rows)))
        for start in range(0, n_cols, step):
            cols = np.arange(start, min(n_cols, start + step))
            flat = ((cols[None, :] * nb + self.bins[np.ix_(rows, cols)]) * k + yw[:, None])
            local = flat - start * nb * k
            part = np.bincount(local.ravel(), weights=np.repeat(w, len(cols)),
                               minlength=len(cols) * nb * k)
            hist[cols] = part.reshape(len(cols), nb, k)
        left = np.cumsum(hist, axis=1)[:, :-1, :]  # threshold edge b: bins 0..b go left
        total = counts[None, None, :]
        right = total - left
        wl, wr = left.sum(axis=2), right.sum(axis=2)
        with np.errstate(divide="ignore", invalid="ignore"):
            gl = 1.0 - np.square(left / wl[..., None]).sum(axis=2)
            gr = 1.0 - np.square(right / wr[..., None]).sum(axis=2)
            gain = _gini(counts) - (wl * gl + wr * gr) / counts.sum()
        valid = (wl > 1e-12) & (wr > 1e-12)
        valid &= np.arange(nb - 1)[None, :] < self.n_edges[:, None]
        gain = np.where(valid, gain, -np.inf)
        return gain.max(axis=1)


def fit_relational_tree(x: np.ndarray, y: np.ndarray, *, max_leaf_nodes: int | None = None,
                        max_depth: int | None = None,
                        settings: RelationalSettings | None = None,
                        feature_map: FeatureMap | None = None,
                        sample_weight: np.ndarray | None = None,
                        seed: int = 0) -> RelationalTreeClassifier:
    """A :class:`RelationalTreeClassifier` on observed rows ``x`` (see the module docstring).

    ``feature_map``: the candidate derived columns (default :func:`candidate_map` of ``x``);
    the fitted tree's own map keeps only those it uses.
    """
    settings = settings or RelationalSettings()
    x = np.asarray(x)
    if x.ndim != 2 or len(x) != len(y) or len(x) == 0:
        raise ValueError(f"expected rows of features and one label each, got {x.shape} and "
                         f"{np.shape(y)}")
    if max_leaf_nodes is not None and max_leaf_nodes < 2:
        raise ValueError(f"max_leaf_nodes must be at least 2, got {max_leaf_nodes}")
    candidates = feature_map or candidate_map(
        x, settings.weights, axis_preferred(x, y, sample_weight, max_leaf_nodes))
    with np.errstate(over="ignore"):
        xf = candidates.augment(x).astype(np.float32)  # as scikit-learn casts its input
    if not np.isfinite(xf).all():
        raise ValueError("derived features overflow float32: rescale the features")
    classes, yk = np.unique(np.asarray(y), return_inverse=True)
    k = len(classes)
    w = (np.ones(len(x)) if sample_weight is None
         else np.asarray(sample_weight, dtype=np.float64))
    search = _Search(xf, yk, w, k, x.shape[1], settings)
    nodes: list[_Node] = []

    def make(rows: np.ndarray, depth: int) -> int:
        counts = np.bincount(yk[rows], weights=w[rows], minlength=k).astype(np.float64)
        node = _Node(rows, depth, counts)
        can_split = (len(rows) >= 2 and _gini(counts) > _PURE
                     and (max_depth is None or depth < max_depth))
        node.split = search.best(rows, counts) if can_split else None
        nodes.append(node)
        return len(nodes) - 1

    total = w.sum()
    make(np.arange(len(x)), 0)
    frontier: list[tuple[float, int]] = []

    def push(i: int) -> None:
        s = nodes[i].split
        if s is not None:
            heapq.heappush(frontier, (-s.gain * nodes[i].counts.sum() / total, i))

    push(0)
    leaves = 1
    while frontier and (max_leaf_nodes is None or leaves < max_leaf_nodes):
        _, i = heapq.heappop(frontier)
        node = nodes[i]
        assert node.split is not None
        go_left = xf[node.rows, node.split.column] <= node.split.threshold
        node.left = make(node.rows[go_left], node.depth + 1)
        node.right = make(node.rows[~go_left], node.depth + 1)
        push(node.left)
        push(node.right)
        leaves += 1
    return _assemble(nodes, classes, candidates, max_leaf_nodes, max_depth, seed)


def _assemble(nodes: list[_Node], classes: np.ndarray, candidates: FeatureMap,
              max_leaf_nodes: int | None, max_depth: int | None, seed: int
              ) -> RelationalTreeClassifier:
    """The grown nodes as a fitted scikit-learn tree over the derived columns it uses."""
    from sklearn.tree._tree import NODE_DTYPE, Tree

    n_axis = candidates.n_features
    used = sorted({n.split.column for n in nodes if n.left != -1 and n.split is not None
                   and n.split.column >= n_axis})
    fmap = FeatureMap(n_axis, tuple(candidates.form(c) for c in used))
    column = {c: n_axis + i for i, c in enumerate(used)}
    n = len(nodes)
    records = np.zeros(n, dtype=NODE_DTYPE)
    values = np.zeros((n, 1, len(classes)))
    depth = 0
    for i, node in enumerate(nodes):
        leaf = node.left == -1
        records[i]["left_child"] = node.left
        records[i]["right_child"] = node.right
        split = node.split
        if leaf or split is None:
            records[i]["feature"], records[i]["threshold"] = -2, -2.0
        else:
            records[i]["feature"] = column.get(split.column, split.column)
            records[i]["threshold"] = split.threshold
        records[i]["impurity"] = _gini(node.counts)
        records[i]["n_node_samples"] = len(node.rows)
        records[i]["weighted_n_node_samples"] = node.counts.sum()
        records[i]["missing_go_to_left"] = 0
        values[i, 0] = node.counts / max(node.counts.sum(), 1e-300)
        depth = max(depth, node.depth)
    tree = Tree(fmap.width, np.array([len(classes)], dtype=np.intp), 1)
    tree.__setstate__({"max_depth": depth, "node_count": n, "nodes": records,
                       "values": values})
    model = RelationalTreeClassifier(max_leaf_nodes=max_leaf_nodes, max_depth=max_depth,
                                     random_state=seed)
    model.n_features_in_ = fmap.width
    model.n_outputs_ = 1
    model.classes_ = classes
    model.n_classes_ = len(classes)
    model.max_features_ = fmap.width
    model.tree_ = tree
    model.feature_map_ = fmap
    return model


def as_relational(tree: DecisionTreeClassifier, feature_map: FeatureMap
                  ) -> RelationalTreeClassifier:
    """A fitted tree over ``feature_map``'s augmented columns (a refined tree rebuilt by
    :meth:`ibt.refine.tree_arrays.TreeArrays.to_sklearn`) as a relational tree."""
    if int(tree.n_features_in_) != feature_map.width:
        raise ValueError(f"the tree reads {tree.n_features_in_} columns, the feature map has "
                         f"{feature_map.width}")
    model = RelationalTreeClassifier.__new__(RelationalTreeClassifier)
    model.__dict__.update(vars(tree))
    model.feature_map_ = feature_map
    return model


def compile_tree(tree: Any) -> Any:
    """A tree's compiled traversal on observed features (relational or axis-aligned: the
    compiled tree appends a relational tree's derived columns itself)."""
    from ibt.evaluate.policies import CompiledTree

    return CompiledTree(tree)


__all__ = ["DEFAULT_MARGIN", "LinearForm", "RelationalSettings", "RelationalTreeClassifier",
           "as_relational", "candidate_map", "compile_tree", "feature_map_of",
           "fit_relational_tree", "one_significant", "relational_tests", "scaled_candidate_map"]


# ------------------------------------------------------------------------ the augmented task
@dataclass(frozen=True)
class AugmentedTask(Task):
    """A task whose features are the observed ones and a feature map's derived columns."""

    feature_map: FeatureMap | None = None

    def features(self, obs: np.ndarray) -> np.ndarray:
        base = super().features(obs)
        return base if self.feature_map is None else self.feature_map.augment(base)

    def observations(self, features: np.ndarray) -> np.ndarray:
        """Augmented rows -> the raw observations (their observed columns)."""
        x = np.asarray(features)
        n = self.feature_map.n_features if self.feature_map is not None else x.shape[1]
        return super().observations(x[:, :n])


def augmented_task(task: Task, feature_map: FeatureMap, **overrides: Any) -> AugmentedTask:
    """``task`` on ``feature_map``'s augmented rows (the one home of synthesis's and
    refinement's view of a relational tree's task): the derived columns are features named as
    a reader writes them, each bounded by interval arithmetic on the task's box; ``overrides``
    replace other fields (synthesis: ``discrete_state=False, integer_features=False``)."""
    if feature_map.n_features != task.n_features:
        raise ValueError(f"the relational tree's feature map reads {feature_map.n_features} "
                         f"features, but task {task.name} has {task.n_features}; use the task "
                         "it was fitted on")
    low, high = list(task.low), list(task.high)
    for form in feature_map.forms:
        ends = [w * b for w, i in ((form.w1, form.i), (form.w2, form.j))
                for b in (task.low[i], task.high[i])]
        a = sorted(ends[:2])
        b = sorted(ends[2:])
        low.append(a[0] + b[0])
        high.append(a[1] + b[1])
    values = {f.name: getattr(task, f.name) for f in fields(Task)}
    values.update(feature_names=feature_map.names(task.feature_names), low=tuple(low),
                  high=tuple(high), feature_map=feature_map, **overrides)
    return AugmentedTask(**values)
