"""Relational tests: a condition on a weighted sum of two features.

A relational test reads ``w1 * x[i] + w2 * x[j] <= T``. Learners never see that form
directly: they see *derived features*, extra columns ``z = w1 * x[i] + w2 * x[j]`` appended to
the observation (:meth:`FeatureMap.augment`), so every tree learner, refinement and synthesiser
that works on axis-aligned splits works on relational ones unchanged, and only the BT's
conditions are rewritten into the relational form at the end.

**The floating-point rule** (what makes a BT decide exactly as its tree, in ``ibt`` and in
BehaviorTree.CPP's ``ScriptCondition``):

* a feature is read as its float32 value widened to double (as every executor does);
* a derived value is computed in double, left to right: ``(w1 * xi) + (w2 * xj)``;
* a tree fitted on derived columns compares ``float32(z) <= t`` (scikit-learn casts its input
  to float32); the relational BT condition compares the double ``z <= T`` with
  ``T = exact_threshold(t)``, the double for which both agree on every double ``z``
  (round-to-nearest-even decides the tie at the midpoint between two float32 values).

BehaviorTree.CPP evaluates ``w1 * xi + w2 * xj <= T`` in double with the same order of
operations, so the engine, the Python executors and the tree agree bit for bit, provided the
weights and ``T`` are written with ``repr`` (shortest round-trip digits).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

#: the weights a learner tries by default: sums and differences first (same-unit features),
#: then one-decimal ratios; readable forms are preferred (integers, one decimal)
DEFAULT_WEIGHTS: tuple[tuple[float, float], ...] = (
    (1.0, 1.0), (1.0, -1.0), (1.0, 0.5), (1.0, -0.5), (0.5, 1.0), (-0.5, 1.0),
    (1.0, 2.0), (1.0, -2.0), (2.0, 1.0), (-2.0, 1.0),
)


def checked_weight(value: Any, name: str) -> float:
    """A form's weight as a double: finite, non-zero and normal (BehaviorTree.CPP's number
    parser rejects subnormal doubles), one rule wherever a BT is read, run or exported."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.integer
                                                 | np.floating):
        raise ValueError(f"a linear form's weight {name} must be a number, "
                         f"got {value!r:.60}")
    try:
        number = float(value)
    except OverflowError:  # an integer beyond the double range
        number = math.inf
    if isinstance(value, int | np.integer) and number != int(value):
        number = math.inf  # an integer a double does not hold: not read exactly
    # one rule wherever a BT is read, run or exported: BehaviorTree.CPP's number parser
    # rejects subnormal doubles, so a weight must be a normal double
    if not sys.float_info.min <= abs(number) < math.inf:
        raise ValueError(f"a linear form's weight {name} must be finite and non-zero, "
                         f"and not subnormal (at least {sys.float_info.min:.4g} in "
                         "magnitude; a number a double holds exactly), got "
                         f"{value!r:.60}")
    return number


@dataclass(frozen=True, order=True)
class LinearForm:
    """``w1 * x[i] + w2 * x[j]`` with ``i != j``; weights finite and non-zero."""

    i: int
    j: int
    w1: float = 1.0
    w2: float = -1.0

    def __post_init__(self) -> None:
        for name in ("i", "j"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 0:
                raise ValueError(f"a linear form's feature {name} must be a non-negative "
                                 f"integer index, got {value!r:.60}")
            object.__setattr__(self, name, int(value))
        if self.i == self.j:
            raise ValueError(f"a linear form needs two different features, got {self.i} twice")
        for name in ("w1", "w2"):
            object.__setattr__(self, name, checked_weight(getattr(self, name), name))

    @property
    def terms(self) -> tuple[tuple[int, float], ...]:
        """``((i, w1), (j, w2))``: the form as its terms, in the order they are added."""
        return ((self.i, self.w1), (self.j, self.w2))

    @property
    def features(self) -> tuple[int, ...]:
        return (self.i, self.j)

    def value(self, features: np.ndarray) -> np.ndarray:
        """The form on rows of *already widened* features (float32 values as doubles)."""
        x = np.asarray(features, dtype=np.float64)
        return self.w1 * x[..., self.i] + self.w2 * x[..., self.j]

    def text(self, names: Sequence[str]) -> str:
        """As a reader writes it: ``x - vx``, ``0.5 * x + vx``, ``-2 * angle + vy``."""
        first = _term(self.w1, names[self.i], leading=True)
        second = _term(abs(self.w2), names[self.j], leading=False)
        return f"{first} {'-' if self.w2 < 0 else '+'} {second}"

    def script(self, keys: Sequence[str]) -> str:
        """The BehaviorTree.CPP script expression: exact weights, same order of operations."""
        return f"{self.w1!r} * {keys[self.i]} + {self.w2!r} * {keys[self.j]}"

    def to_json(self) -> dict[str, Any]:
        return {"features": [self.i, self.j], "weights": [self.w1, self.w2]}

    @classmethod
    def from_json(cls, doc: Any) -> LinearForm:
        if not isinstance(doc, dict) or set(doc) != {"features", "weights"}:
            raise ValueError("a linear form must be {\"features\": [i, j], \"weights\": [w1, w2]}"
                             f", got {doc!r:.80}")
        features, weights = doc["features"], doc["weights"]
        if not (isinstance(features, list) and isinstance(weights, list)
                and len(features) == 2 and len(weights) == 2):
            raise ValueError(f"a linear form has two features and two weights, got {doc!r:.80}")
        return cls(features[0], features[1], weights[0], weights[1])


MAX_TERMS = 4  #: the most features one oblique test or one linear command reads


@dataclass(frozen=True)
class ObliqueForm:
    """``w1 * x[f1] + ... + wk * x[fk]`` over one, three or four distinct features (two are a
    :class:`LinearForm`: build either with :func:`linear_form`), summed in double left to
    right, the floating-point rule of this module: ``((w1 * x1) + (w2 * x2)) + (w3 * x3)``."""

    features: tuple[int, ...]
    weights: tuple[float, ...]

    def __post_init__(self) -> None:
        features, weights = tuple(self.features), tuple(self.weights)
        if not 1 <= len(features) <= MAX_TERMS or len(features) == 2:
            raise ValueError(f"an oblique form has 1, 3 or {MAX_TERMS} terms (two are a "
                             f"LinearForm: use linear_form), got {len(features)}")
        if len(weights) != len(features):
            raise ValueError(f"an oblique form needs one weight per feature, got "
                             f"{len(features)} features and {len(weights)} weights")
        for f in features:
            if isinstance(f, bool) or not isinstance(f, int | np.integer) or f < 0:
                raise ValueError(f"an oblique form's features must be non-negative integer "
                                 f"indices, got {f!r:.60}")
        if len(set(features)) != len(features):
            raise ValueError(f"an oblique form reads each feature once, got {features}")
        object.__setattr__(self, "features", tuple(int(f) for f in features))
        object.__setattr__(self, "weights", tuple(checked_weight(w, f"w{k + 1}")
                                                  for k, w in enumerate(weights)))

    @property
    def terms(self) -> tuple[tuple[int, float], ...]:
        return tuple(zip(self.features, self.weights, strict=True))

    @property
    def i(self) -> int:
        """The first feature (a condition's ``feature``)."""
        return self.features[0]

    def value(self, features: np.ndarray) -> np.ndarray:
        """The form on rows of *already widened* features, by the floating-point rule."""
        x = np.asarray(features, dtype=np.float64)
        total = self.weights[0] * x[..., self.features[0]]
        for f, w in zip(self.features[1:], self.weights[1:], strict=True):
            total = total + w * x[..., f]
        return total

    def text(self, names: Sequence[str]) -> str:
        """``0.5 * x + vx - angle``."""
        return terms_text(self.terms, names)

    def script(self, keys: Sequence[str]) -> str:
        """The BehaviorTree.CPP script expression: exact weights, same order of operations
        (:func:`script_sum`)."""
        return script_sum([f"{w!r} * {keys[f]}" for f, w in self.terms])

    def to_json(self) -> dict[str, Any]:
        return {"features": list(self.features), "weights": list(self.weights)}

    def sort_key(self) -> tuple[Any, ...]:
        return (self.features, self.weights)


Form = LinearForm | ObliqueForm


def linear_form(terms: Sequence[tuple[int, float]]) -> Form:
    """The form of ``terms`` (feature, weight), in that order: a :class:`LinearForm` for two
    terms (the relational learner's shape), else an :class:`ObliqueForm`."""
    terms = list(terms)
    if len(terms) == 2:
        (i, w1), (j, w2) = terms
        return LinearForm(i, j, w1, w2)
    return ObliqueForm(tuple(f for f, _ in terms), tuple(w for _, w in terms))


def form_from_json(doc: Any) -> Form:
    """A form written by ``to_json``: ``{"features": [...], "weights": [...]}``, 1 to
    :data:`MAX_TERMS` terms."""
    if not isinstance(doc, dict) or set(doc) != {"features", "weights"}:
        raise ValueError("a linear form must be {\"features\": [i, j, ...], \"weights\": "
                         f"[w1, w2, ...]}}, got {doc!r:.80}")
    features, weights = doc["features"], doc["weights"]
    if not (isinstance(features, list) and isinstance(weights, list)
            and 1 <= len(features) <= MAX_TERMS and len(weights) == len(features)):
        raise ValueError(f"a linear form has 1 to {MAX_TERMS} features and one weight each, "
                         f"got {doc!r:.80}")
    return linear_form(list(zip(features, weights, strict=True)))


def script_sum(parts: Sequence[str]) -> str:
    """``((p1 + p2) + p3) + p4``: a sum BehaviorTree.CPP adds left to right.

    Its script parser groups ``a + b + c`` as ``a + (b + c)`` (checked with behaviortreepy
    0.1.4: ``1e16 + -1e16 + 1.0`` gives 0.0), so a sum of three or more parts is written with
    explicit parentheses; one of two parts needs none."""
    text = parts[0]
    for k, part in enumerate(parts[1:]):
        text = f"{text} + {part}" if k == 0 else f"({text}) + {part}"
    return text


def terms_text(terms: Sequence[tuple[int, float]], names: Sequence[str],
               bias: float | None = None) -> str:
    """As a reader writes a sum: ``-1 + 10 * y - 10 * vy``, ``0.5 * x + vx - angle``."""
    parts: list[str] = []
    if bias is not None and (bias != 0.0 or not terms):
        parts.append(f"{bias:g}")
    for f, w in terms:
        if not parts:
            parts.append(_term(w, names[f], leading=True))
        else:
            parts.append(f"{'-' if w < 0 else '+'} {_term(abs(w), names[f], leading=False)}")
    return " ".join(parts)


def _term(weight: float, name: str, *, leading: bool) -> str:
    if weight == 1.0:
        return name
    if weight == -1.0 and leading:
        return f"-{name}"
    return f"{weight:g} * {name}"


@dataclass(frozen=True)
class FeatureMap:
    """The derived features of a relational learner: columns ``n_features + k`` are
    ``forms[k]`` of the task's ``n_features`` observed features."""

    n_features: int
    forms: tuple[LinearForm, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "forms", tuple(self.forms))
        for form in self.forms:
            if max(form.i, form.j) >= self.n_features:
                raise ValueError(f"linear form {form} reads a feature beyond the task's "
                                 f"{self.n_features}")

    @property
    def width(self) -> int:
        """Columns of an augmented row."""
        return self.n_features + len(self.forms)

    def is_derived(self, column: int) -> bool:
        return column >= self.n_features

    def form(self, column: int) -> LinearForm:
        return self.forms[column - self.n_features]

    def augment(self, features: np.ndarray) -> np.ndarray:
        """Rows of observed features (widened float32 values) with the derived columns
        appended, each computed in double by the floating-point rule."""
        with np.errstate(over="ignore"):
            x = np.asarray(features, dtype=np.float32).astype(np.float64)
        x2 = np.atleast_2d(x)
        if x2.shape[-1] != self.n_features:
            raise ValueError(f"expected {self.n_features} features, got {x2.shape[-1]}")
        derived = [form.value(x2) for form in self.forms]
        out = np.column_stack([x2, *derived]) if derived else x2
        return out if x.ndim == 2 else out[0]

    def names(self, feature_names: Sequence[str]) -> tuple[str, ...]:
        return (*feature_names, *(form.text(feature_names) for form in self.forms))

    def to_json(self) -> dict[str, Any]:
        return {"n_features": self.n_features, "forms": [f.to_json() for f in self.forms]}

    @classmethod
    def from_json(cls, doc: Any) -> FeatureMap:
        if not isinstance(doc, dict) or set(doc) != {"n_features", "forms"}:
            raise ValueError(f"a feature map must be {{\"n_features\", \"forms\"}}, got "
                             f"{doc!r:.80}")
        n_features, forms = doc["n_features"], doc["forms"]
        if type(n_features) is not int or n_features < 0:
            raise ValueError(f"a feature map's n_features must be a non-negative integer, got "
                             f"{n_features!r:.60}")
        if not isinstance(forms, list):
            raise ValueError(f"a feature map's forms must be a list, got {forms!r:.60}")
        return cls(n_features, tuple(LinearForm.from_json(f) for f in forms))

    @classmethod
    def pairs(cls, n_features: int, weights: Sequence[tuple[float, float]] = DEFAULT_WEIGHTS,
              features: Sequence[int] | None = None) -> FeatureMap:
        """Every pair ``i < j`` of ``features`` (all by default) with every weight pair."""
        chosen = list(range(n_features)) if features is None else list(features)
        forms = [LinearForm(i, j, w1, w2) for a, i in enumerate(chosen) for j in chosen[a + 1:]
                 for w1, w2 in weights]
        return cls(n_features, tuple(forms))


def exact_threshold(t: float) -> float:
    """The double ``T`` with ``float32(z) <= t`` exactly when ``z <= T``, for every double ``z``
    (within float32's finite range).

    With ``a`` the largest float32 at or below ``t`` and ``b`` the next float32, ``float32(z)``
    is at most ``a`` exactly when ``z`` is below their midpoint ``m``, or equal to it and the
    tie rounds to ``a`` (round half to even). The midpoint of two float32 values is exact in
    double.
    """
    t = float(t)
    if not math.isfinite(t):
        raise ValueError(f"a threshold must be finite, got {t!r}")
    a = np.float32(t)
    if float(a) > t:
        a = np.nextafter(a, np.float32(-np.inf))
    b = np.nextafter(a, np.float32(np.inf))
    if not np.isfinite(b):
        return float(np.finfo(np.float64).max)
    m = (float(a) + float(b)) / 2.0
    return m if float(np.float32(m)) == float(a) else float(np.nextafter(m, -np.inf))
