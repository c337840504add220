"""The Behavior Tree model every other part of ``ibt`` consumes.

A synthesised policy is a tree of small frozen dataclasses:

* ``Selector`` / ``Fallback``: tick children in order, succeed on the first success
  (same semantics; ``Selector`` names the root, ``Fallback`` an inner choice between rules);
* ``Sequence``: tick children in order, fail on the first failure;
* ``Inverter``: flip its child's status;
* ``Condition``: succeeds when ``obs[feature] op threshold`` with ``op`` in ``<=`` / ``>``, or,
  for a *relational* condition, ``w1 * obs[i] + w2 * obs[j] op threshold`` (its
  ``form``, a :class:`ibt.bt.linear.LinearForm`, computed in double by the floating-point rule
  of :mod:`ibt.bt.linear`);
* ``Action``: succeeds and is the decision.

Policies here are reactive (the paper's scope): actions finish within one tick, so RUNNING never
occurs and a tick's decision is the first action ticked. Comparisons are made in double precision
on observations cast to float32 first, which is exactly how scikit-learn's trees decide; this is
what makes a synthesised BT decide *exactly* as its source tree.

This module holds the nodes, node counting and the tree; the JSON format of ``data/trees/``
is in :mod:`ibt.bt.document` (``BehaviorTree.to_dict`` and ``from_dict`` call it), the three
executors (``tick``, ``decide_batch``, ``to_py_trees``) are in :mod:`ibt.bt.executors`, and the
proof that every state reaches an action in :mod:`ibt.bt.coverage`.
"""

from __future__ import annotations

import json
import math
from collections import Counter
from collections.abc import Iterator
from collections.abc import Sequence as Seq
from dataclasses import dataclass, field
from typing import Any, Union

import numpy as np

from ibt.bt.linear import MAX_TERMS, Form, LinearForm, ObliqueForm, checked_weight, terms_text

OPS = ("<=", ">")
MAX_DEPTH = 100  # levels below the root a BT may have (the committed ones have at most 7)
MAX_NODES = 100_000  # nodes a BT may have (the committed ones have at most 313)
NODE_TYPES = ("selector", "sequence", "fallback", "inverter", "condition", "action")
NO_DECISION = -1


@dataclass(frozen=True)
class Condition:
    """``obs[feature] <= threshold`` (op ``<=``) or ``obs[feature] > threshold`` (op ``>``).

    A relational condition has a ``form`` (``w1 * obs[i] + w2 * obs[j]``) and compares its
    double value with ``threshold``; its ``feature`` is then the form's first feature ``i``
    (build one with :meth:`relational`). Every reader of a condition's value goes through
    :meth:`value` / :meth:`holds`, which know both shapes.
    """

    feature: int
    op: str
    threshold: float
    form: Form | None = None

    def __post_init__(self) -> None:
        if self.op not in OPS:
            raise ValueError(f"condition op must be one of {OPS}, got {self.op!r:.60}")
        # normalised to plain int/float: NumPy scalars from scikit-learn compare equal anyway
        object.__setattr__(self, "feature", _index(self.feature, "a condition's feature"))
        object.__setattr__(self, "threshold", _finite(self.threshold))
        if self.form is not None:
            if not isinstance(self.form, LinearForm | ObliqueForm):
                raise ValueError(f"a condition's form must be a LinearForm or ObliqueForm, got "
                                 f"{self.form!r:.60}")
            if self.feature != self.form.i:
                raise ValueError(f"a relational condition's feature is its form's first "
                                 f"feature {self.form.i}, got {self.feature}; build it with "
                                 "Condition.relational(form, op, threshold)")
            if not math.isfinite(FLOAT32_MAX * sum(abs(w) for _, w in self.form.terms)):
                raise ValueError(f"the weights of {self.form} are too large: a form must stay "
                                 "finite in double on every float32 observation")

    type = "condition"

    @classmethod
    def relational(cls, form: Form, op: str, threshold: float) -> Condition:
        """``form op threshold``: a relational condition."""
        return cls(form.i, op, threshold, form)

    @property
    def features(self) -> tuple[int, ...]:
        """The features the condition reads."""
        return (self.feature,) if self.form is None else tuple(self.form.features)

    def value(self, x: np.ndarray) -> Any:
        """The compared value on widened features (one row or a batch): the feature's column,
        or the form computed by the floating-point rule."""
        if self.form is None:
            return x[..., self.feature]
        return self.form.value(x)

    def holds(self, x: np.ndarray) -> Any:
        """Where the condition succeeds on widened features (one row or a batch)."""
        v = self.value(x)
        return v <= self.threshold if self.op == "<=" else v > self.threshold


FLOAT32_MAX = float(np.finfo(np.float32).max)


@dataclass(frozen=True)
class Action:
    """A leaf that succeeds and makes ``action`` the tick's decision."""

    action: int

    def __post_init__(self) -> None:
        object.__setattr__(self, "action", _index(self.action, "an action"))

    type = "action"


def _index(value: Any, what: str) -> int:
    """``value`` as a non-negative integer index, or a ``ValueError`` naming ``what``."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise ValueError(f"{what} must be an integer index, got {value!r:.60}")
    if value < 0:
        raise ValueError(f"{what} must be a non-negative index, got {value!r:.60}")
    return int(value)


def _finite(value: Any) -> float:
    """``value`` as a finite float, or a ``ValueError`` (an integer too large for a double
    included: it would be infinite)."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        raise ValueError(f"a condition's threshold must be a number, got {value!r:.60}")
    number = finite_number(value)
    if number is None:
        raise ValueError(f"a condition's threshold must be finite (a number a double holds "
                         f"exactly), got {value!r:.60}")
    return number


def finite_number(value: Any) -> float | None:
    """``value`` (a JSON number) as a finite double, or ``None`` when it is not exactly one
    (NaN, infinity, not a number at all, or an integer a double does not hold exactly, such as
    ``10**30``: read as a double it would silently become another number)."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating):
        return None
    try:
        number = float(value)
    except OverflowError:
        return None
    if isinstance(value, int | np.integer) and number != int(value):
        return None
    return number if math.isfinite(number) else None


@dataclass(frozen=True)
class Inverter:
    """Flip the status of ``child``."""

    child: Node
    type = "inverter"

    @property
    def children(self) -> tuple[Node, ...]:
        return (self.child,)


@dataclass(frozen=True)
class Sequence:
    """Tick children in order; fail at the first failure, succeed when all succeed."""

    children: tuple[Node, ...] = field(default_factory=tuple)
    type = "sequence"


@dataclass(frozen=True)
class Fallback:
    """Tick children in order; succeed at the first success, fail when all fail."""

    children: tuple[Node, ...] = field(default_factory=tuple)
    type = "fallback"


@dataclass(frozen=True)
class Selector(Fallback):
    """A Fallback used as the root of a synthesised policy."""

    type = "selector"


Node = Union[Selector, Fallback, Sequence, Inverter, Condition, Action]  # noqa: UP007


Terms = tuple[tuple[int, float], ...]  #: a linear command's terms (feature, weight), in sum order


@dataclass(frozen=True)
class Commands:
    """What each action of a BT for continuous actions sends: action ``i`` is the command
    ``values[i]``, one number per named dimension (``dimensions``, with ``units``), plus, for a
    *linear* command, its ``terms``: dimension ``d`` of command ``i`` is then
    ``values[i][d] + w1 * x[f1] + ... + wk * x[fk]`` over ``terms[i][d]`` (at most
    :data:`ibt.bt.linear.MAX_TERMS` features), computed in double left to right on the widened
    float32 observation, the floating-point rule of :mod:`ibt.bt.linear`. The environment clips
    what it receives to its action space; :meth:`evaluate` does not clip.

    JSON (the ``commands`` key of a BT document; ``terms`` only where a command is linear)::

        "commands": {"dimensions": ["main_engine", "side_engine"],
                     "units": ["throttle", "throttle"],
                     "values": [[-1.0, 0.0], [-1.0, 0.0]],
                     "terms": [[[[1, 10.0], [3, -10.0]], []], [[], []]]}

    ``values`` has one row per entry of ``action_names`` (the command's name), each row one
    finite number per dimension; ``terms`` one list per command and dimension of
    ``[feature, weight]`` pairs.
    """

    dimensions: tuple[str, ...]
    units: tuple[str, ...]
    values: tuple[tuple[float, ...], ...]
    terms: tuple[tuple[Terms, ...], ...] | None = None

    def __post_init__(self) -> None:
        if self.terms is None:
            return
        if len(self.terms) != len(self.values) or any(len(row) != len(self.dimensions)
                                                       for row in self.terms):
            raise ValueError("commands.terms must hold one list of terms per command and "
                             "dimension")
        for i, row in enumerate(self.terms):
            for d, terms in enumerate(row):
                features = [f for f, _ in terms]
                if len(terms) > MAX_TERMS or len(set(features)) != len(features):
                    raise ValueError(f"command {i}, dimension {d}: at most {MAX_TERMS} terms, "
                                     "each feature once")
                for f, w in terms:
                    _index(f, f"command {i}'s feature")
                    checked_weight(w, f"of command {i}")
                if not math.isfinite(FLOAT32_MAX * sum(abs(w) for _, w in terms)):
                    raise ValueError(f"command {i}, dimension {d}: weights too large to stay "
                                     "finite in double on every float32 observation")
        if not any(row_terms for row in self.terms for row_terms in row):
            object.__setattr__(self, "terms", None)  # all constant: the plain form

    @property
    def linear(self) -> bool:
        """Does some command depend on the features?"""
        return self.terms is not None

    @property
    def features(self) -> tuple[int, ...]:
        """Every feature some command reads, in index order."""
        return tuple(sorted({f for row in self.terms or () for terms in row for f, _ in terms}))

    def to_dict(self) -> dict[str, Any]:
        doc: dict[str, Any] = {"dimensions": list(self.dimensions), "units": list(self.units),
                               "values": [list(v) for v in self.values]}
        if self.terms is not None:
            doc["terms"] = [[[[f, w] for f, w in terms] for terms in row] for row in self.terms]
        return doc

    @classmethod
    def from_dict(cls, doc: Any, n_actions: int) -> Commands:
        """Read and check a ``commands`` document: ``ValueError`` names the first problem."""
        keys = {"dimensions", "units", "values"}
        if not isinstance(doc, dict) or set(doc) not in (keys, keys | {"terms"}):
            raise ValueError("commands must be an object with exactly 'dimensions', 'units' "
                             "and 'values' (and 'terms' for linear commands)")
        dims = checked_names(doc["dimensions"], "commands.dimensions")
        units = doc["units"]
        if not isinstance(units, list) or len(units) != len(dims) or not all(
                isinstance(u, str) for u in units):
            raise ValueError("commands.units must be a list of one string per dimension")
        values = doc["values"]
        if not isinstance(values, list) or len(values) != n_actions:
            raise ValueError(f"commands.values must hold one command per action ({n_actions})")
        rows = []
        for i, row in enumerate(values):
            if not isinstance(row, list) or len(row) != len(dims):
                raise ValueError(f"command {i} must be a list of {len(dims)} numbers")
            bad = [v for v in row if finite_number(v) is None or abs(float(v)) > FLOAT32_MAX]
            if bad:  # commands are sent as float32: the same rule as observations
                raise ValueError(f"command {i} holds {bad[0]!r:.60}, not a finite number that "
                                 f"fits in float32 (at most {FLOAT32_MAX:.8g} in magnitude; one "
                                 "a double holds exactly); give every command such values")
            rows.append(tuple(float(v) for v in row))
        terms = None
        if "terms" in doc:
            terms = _terms_from_doc(doc["terms"], n_actions, len(dims))
        return cls(dims, tuple(units), tuple(rows), terms)

    def array(self) -> np.ndarray:
        """The commands' constant parts as a float32 matrix ``(n_actions, dimensions)``."""
        return np.asarray(self.values, dtype=np.float32).reshape(len(self.values), -1)

    def evaluate(self, ids: np.ndarray, features: np.ndarray) -> np.ndarray:
        """The command vectors ``(n, dimensions)`` in double sent on widened feature rows
        ``(n, n_features)`` whose decisions are ``ids`` (the floating-point rule; not clipped)."""
        ids = np.asarray(ids, dtype=np.int64)
        out = np.asarray(self.values, dtype=np.float64).reshape(len(self.values), -1)[ids]
        if self.terms is None:
            return out
        x = np.asarray(features, dtype=np.float64)
        for i, row in enumerate(self.terms):
            rows = ids == i
            if not rows.any():
                continue
            for d, terms in enumerate(row):
                total = out[rows, d]
                for f, w in terms:
                    total = total + w * x[rows, f]
                out[rows, d] = total
        return out

    def text(self, action: int, feature_names: Seq[str], precision: int = 4) -> list[str]:
        """One line per dimension: ``main_engine := -1 + 10 * y - 10 * vy``."""
        out = []
        for d, name in enumerate(self.dimensions):
            terms = self.terms[action][d] if self.terms is not None else ()
            rounded = tuple((f, float(f"{w:.{precision}g}")) for f, w in terms)
            bias = float(f"{self.values[action][d]:.{precision}g}")
            out.append(f"{name} := {terms_text(rounded, feature_names, bias)}")
        return out


def _terms_from_doc(doc: Any, n_actions: int, n_dims: int) -> tuple[tuple[Terms, ...], ...]:
    """``commands.terms`` read strictly: ``[[[[feature, weight], ...] per dimension] per
    command]``."""
    if not isinstance(doc, list) or len(doc) != n_actions:
        raise ValueError(f"commands.terms must hold one entry per command ({n_actions})")
    rows = []
    for i, row in enumerate(doc):
        if not isinstance(row, list) or len(row) != n_dims:
            raise ValueError(f"commands.terms[{i}] must hold one list of terms per dimension")
        dims = []
        for d, terms in enumerate(row):
            if not isinstance(terms, list) or not all(
                    isinstance(t, list) and len(t) == 2 for t in terms):
                raise ValueError(f"commands.terms[{i}][{d}] must be a list of [feature, "
                                 "weight] pairs")
            dims.append(tuple((_index(f, f"commands.terms[{i}][{d}]'s feature"),
                               checked_weight(w, f"in commands.terms[{i}][{d}]"))
                              for f, w in terms))
        rows.append(tuple(dims))
    return tuple(rows)


@dataclass(frozen=True)
class BehaviorTree:
    """A BT with the names that make it readable and runnable on its own."""

    root: Node
    feature_names: tuple[str, ...]
    action_names: tuple[str, ...]
    # labels of categorical features' integer values 0..k-1 ({feature index: labels}); only
    # used to print conditions readably (``carrying == heavy``), never to decide
    value_labels: tuple[tuple[int, tuple[str, ...]], ...] = ()
    # continuous actions: the command vector each action sends (None: discrete actions)
    commands: Commands | None = None

    def nodes(self) -> Iterator[Node]:
        """All nodes, depth first, root included (the order of py_trees' ``iterate``)."""
        yield from iterate(self.root)

    @property
    def node_count(self) -> int:
        """Every node: root, composites, inverters, conditions and actions."""
        return sum(1 for _ in self.nodes())

    def node_types(self) -> dict[str, int]:
        """How many nodes of each type (for the node-distribution figures)."""
        counts = Counter(node.type for node in self.nodes())
        return {name: counts.get(name, 0) for name in NODE_TYPES}

    @property
    def n_features(self) -> int:
        return len(self.feature_names)

    def decide(self, features: np.ndarray) -> np.ndarray:
        """Decisions for a batch of states: ``features`` has exactly the shape
        ``(n, n_features)``, one row per state (:func:`tick` decides one state)."""
        x = np.asarray(features)
        if x.ndim != 2 or x.shape[1] != self.n_features:
            raise ValueError(f"decide takes a batch of shape (n, {self.n_features}), one row per "
                             f"state, got shape {x.shape}; for one state use tick(bt, state) or "
                             "bt.decide(state[None])")
        from ibt.bt.executors import decide_batch

        return decide_batch(self.root, x)

    def label(self, node: Node, precision: int = 4) -> str:
        """A readable label: ``pole_angle <= 0.05``, ``push_right``, ``Sequence``."""
        if isinstance(node, Condition) and node.form is not None:
            text = node.form.text(self.feature_names)
            return f"{text} {node.op} {_fmt(node.threshold, precision)}"
        if isinstance(node, Condition):
            name = self.feature_names[node.feature]
            labels = dict(self.value_labels).get(node.feature)
            if labels:
                return _categorical_label(name, labels, node)
            return f"{name} {node.op} {_fmt(node.threshold, precision)}"
        if isinstance(node, Action):
            return self.action_names[node.action]
        return type(node).__name__

    @property
    def relational_count(self) -> int:
        """How many condition nodes are relational (test a linear form of two features)."""
        return relational_tests(self.root)

    def to_dict(self) -> dict[str, Any]:
        """The JSON document of ``data/trees/`` (see :func:`from_dict`; the format is
        :mod:`ibt.bt.document`'s)."""
        from ibt.bt.document import tree_to_dict

        return tree_to_dict(self)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=1)

    @classmethod
    def from_dict(cls, doc: Any) -> BehaviorTree:
        """Read a document of :meth:`to_dict`, strictly: ``ValueError`` names the first problem
        (missing or unknown keys, a fractional index, a non-finite threshold, an index out of
        range, a state that reaches no action; see :meth:`validate`)."""
        from ibt.bt.document import tree_from_dict

        return tree_from_dict(cls, doc)

    @classmethod
    def from_json(cls, text: str | bytes) -> BehaviorTree:
        """Read a BT document from strict JSON (UTF-8, no duplicate keys: a key given twice
        would silently mean its last value): ``ValueError`` names the first problem."""
        from ibt.bt.document import strict_json

        return cls.from_dict(strict_json(text))

    def validate(self) -> None:
        """Raise ``ValueError`` unless every feature and action index is in range, every
        composite has children, and every state provably reaches an action.

        The proof (:func:`unreached_state`) accepts a root that ends with an unguarded action
        (a default), tree-shaped Fallbacks whose last child always acts, and guards that
        together cover every state; a BT for which it finds a state reaching no action (which
        would send no decision to the environment) is refused with that state.
        """
        check_size(self.root)
        for node in self.nodes():
            if isinstance(node, Condition) and not max(node.features) < len(self.feature_names):
                raise ValueError(f"condition on feature {max(node.features)}, but the tree "
                                 f"names {len(self.feature_names)} features")
            if isinstance(node, Action) and not node.action < len(self.action_names):
                raise ValueError(f"action {node.action}, but the tree names "
                                 f"{len(self.action_names)} actions")
            if isinstance(node, Fallback | Sequence) and not node.children:
                raise ValueError(f"a {node.type} without children")
        if self.commands is not None and self.commands.features and not (
                self.commands.features[-1] < len(self.feature_names)):
            raise ValueError(f"a command reads feature {self.commands.features[-1]}, but the "
                             f"tree names {len(self.feature_names)} features")
        from ibt.bt.coverage import unreached_state
        from ibt.bt.executors import decide_batch

        state = unreached_state(self)
        if state is not None:
            where = ", ".join(f"{name}={value:.6g}"
                              for name, value in zip(self.feature_names, state, strict=True))
            found = decide_batch(self.root, state[None], finite=False)[0] == NO_DECISION
            problem = (f"no action is reached on some states (e.g. {where})" if found else
                       f"cannot prove that every state reaches an action (the proof fails near "
                       f"{where})")
            raise ValueError(f"{problem}; end the root Selector with an unguarded default "
                             "action, or make the guards cover every state")


def checked_names(values: Any, what: str) -> tuple[str, ...]:
    """A non-empty list of distinct non-empty strings, as a tuple."""
    if (not isinstance(values, list) or not values
            or not all(isinstance(v, str) and v for v in values)):
        raise ValueError(f"{what} must be a non-empty list of non-empty strings")
    if len(set(values)) != len(values):
        repeated = next(v for v in values if values.count(v) > 1)
        raise ValueError(f"{what} names {repeated!r:.60} twice")
    return tuple(values)


def _categorical_label(name: str, labels: tuple[str, ...], node: Condition) -> str:
    """``carrying == heavy`` / ``location in {depot, zone_a}`` for integer-coded categories."""
    cut = int(np.floor(node.threshold))  # x <= t  <=>  x in 0..cut for integer x
    below, above = labels[: cut + 1], labels[cut + 1:]
    chosen = below if node.op == "<=" else above
    other = above if node.op == "<=" else below
    if len(chosen) == 1:
        return f"{name} == {chosen[0]}"
    if len(other) == 1:
        return f"{name} != {other[0]}"
    return f"{name} in {{{', '.join(chosen)}}}"


def _fmt(value: float, precision: int) -> str:
    text = f"{value:.{precision}g}"
    return text


def relational_tests(root: Node) -> int:
    """How many condition nodes under ``root`` are relational (a relational test is one
    condition node, like any other)."""
    return sum(1 for node in iterate(root) if isinstance(node, Condition) and node.form is not None)


def iterate(node: Node) -> Iterator[Node]:
    """Depth-first, parent before children."""
    yield node
    for child in getattr(node, "children", ()):
        yield from iterate(child)


def check_size(root: Node) -> None:
    """``ValueError`` unless the tree is at most :data:`MAX_DEPTH` deep and has at most
    :data:`MAX_NODES` nodes (checked without recursion, so any object graph is safe)."""
    stack: list[tuple[Any, int]] = [(root, 0)]
    count = 0
    while stack:
        node, depth = stack.pop()
        count += 1
        if depth > MAX_DEPTH:
            raise ValueError(f"the behavior tree is more than {MAX_DEPTH} levels deep; a BT "
                             "this deep is not one ibt writes (flatten it)")
        if count > MAX_NODES:
            raise ValueError(f"the behavior tree has more than {MAX_NODES:,} nodes (or a node "
                             "that contains itself); a BT this large is not one ibt writes")
        stack.extend((child, depth + 1) for child in getattr(node, "children", ()))



def indexed(root: Node) -> list[tuple[Node, tuple[int, ...]]]:
    """Every node in depth-first order with the positions of its children in that order.

    Positions come from one traversal, so a node object used twice in a tree (frozen
    dataclasses: equal nodes may be one object) gets two positions; this is how traces and
    drawings name nodes.
    """
    out: list[tuple[Node, tuple[int, ...]]] = []

    def walk(node: Node) -> int:
        position = len(out)
        out.append((node, ()))
        kids = tuple(walk(child) for child in getattr(node, "children", ()))
        out[position] = (node, kids)
        return position

    walk(root)
    return out
