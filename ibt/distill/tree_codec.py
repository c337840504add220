"""Exact plain-data encoding of values holding fitted scikit-learn decision trees.

One encoding serves the tree files of :mod:`ibt.distill.tree_file` and the cache payloads of
:mod:`ibt.cache.payloads`: a value becomes a JSON-able document, arrays go to pools of one dtype
each, and decoding builds only the types listed here, so reading a document never imports a
module or runs code named in it.

JSON carries ``None``, booleans, integers, strings, lists, string-keyed dicts and finite floats
(their ``repr`` is exact); everything else is a tagged object: ``{"__tuple__": [...]}``,
``{"__float__": "nan" | "inf" | "-inf"}``, ``{"__numpy__": dtype, "value": v}`` for a NumPy
scalar, ``{"__items__": [[k, v], ...]}`` for a dict with other keys, an array reference
``{"__array__": [pool, offset, shape]}``, ``{"__sklearn_tree__": {attribute: value}}`` for a
fitted ``DecisionTreeClassifier`` (its whole ``__dict__``, in order) and
``{"__sklearn_relational_tree__": {attribute: value}}`` for a fitted
:class:`ibt.distill.relational.RelationalTreeClassifier` (the same, its ``feature_map_`` as the
plain JSON of :meth:`ibt.bt.linear.FeatureMap.to_json`),
``{"__sklearn_Tree__": ...}`` for its ``tree_`` (the arguments of ``Tree(n_features, n_classes,
n_outputs)`` and the state ``Tree.__setstate__`` takes, node records split into one array per
field). ``__tree_arrays__`` is reserved for :mod:`ibt.cache.payloads`. The round trip is exact:
:func:`ibt.distill.loop.tree_signature` and every attribute are unchanged.

:func:`to_document` / :func:`from_document` make any such value one self-contained JSON
document (pools as base64 of little-endian bytes); :func:`tree_to_data` / :func:`tree_from_data`
do so for one fitted tree, which :func:`check_tree` checks on reading (exactly a fitted tree's
attributes, a tree of nodes with one parent each, every index in range, every number finite), so
a hostile file cannot make ``predict`` loop, read out of bounds or decide on NaN.
"""

from __future__ import annotations

import base64
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

TAGS = frozenset({"__tuple__", "__float__", "__numpy__", "__array__", "__items__",
                  "__sklearn_tree__", "__sklearn_Tree__", "__tree_arrays__",
                  "__sklearn_relational_tree__"})
_FEATURE_MAP = "feature_map_"  # a relational tree's attribute holding its FeatureMap
_ARRAY_KINDS = "biuf"  # bool, signed and unsigned integers, floats: what np.load reads plainly
_SCALAR_KINDS = "biufU"
_ORDER = {"=": "", "|": "", "<": "le" if np.little_endian else "", ">": "" if np.little_endian
          else "be"}  # a pool's name: kind, item size and (when not native) byte order
_POOL_DTYPES = {"b1": "|b1", "i1": "|i1", "u1": "|u1", "i2": "<i2", "u2": "<u2", "i4": "<i4",
                "u4": "<u4", "i8": "<i8", "u8": "<u8", "f2": "<f2", "f4": "<f4", "f8": "<f8"}


class PlainDataError(ValueError):
    """A document that is not a valid encoding (of the expected schema and version)."""


class PlainEncoder:
    """Values to JSON-able documents; arrays go to ``pools`` (``None``: arrays refused).

    Arrays are appended, flattened, to one pool per dtype (an npz member each), and referenced
    as ``{"__array__": [pool, offset, shape]}``: a run's hundreds of small arrays cost a few
    members and compress together.
    """

    def __init__(self, pools: dict[str, list[np.ndarray]] | None):
        self.pools = pools
        self.sizes: dict[str, int] = {}

    def array(self, value: np.ndarray) -> dict[str, Any]:
        if self.pools is None:
            raise TypeError("a JSON payload cannot hold an array")
        if value.dtype.kind not in _ARRAY_KINDS or value.dtype.fields is not None:
            raise TypeError(f"cannot store an array of dtype {value.dtype} as plain data")
        pool = f"{value.dtype.kind}{value.dtype.itemsize}{_ORDER[value.dtype.byteorder]}"
        offset = self.sizes.get(pool, 0)
        self.pools.setdefault(pool, []).append(np.ascontiguousarray(value).reshape(-1))
        self.sizes[pool] = offset + value.size
        return {"__array__": [pool, offset, list(value.shape)]}

    def encode(self, value: Any) -> Any:
        from sklearn.tree import DecisionTreeClassifier
        from sklearn.tree._tree import Tree

        if value is None or type(value) in (bool, str):
            return value
        if isinstance(value, np.generic):
            if value.dtype.kind not in _SCALAR_KINDS:
                raise TypeError(f"cannot store a NumPy {value.dtype} scalar as plain data")
            return {"__numpy__": value.dtype.str, "value": self.encode(value.item())}
        kind = type(value)
        if kind is int:
            return value
        if kind is float:
            if math.isfinite(value):
                return value
            return {"__float__": "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")}
        if kind is list:
            return [self.encode(v) for v in value]
        if kind is tuple:
            return {"__tuple__": [self.encode(v) for v in value]}
        if kind is dict:
            if all(type(k) is str and k not in TAGS for k in value):
                return {k: self.encode(v) for k, v in value.items()}
            return {"__items__": [[self.encode(k), self.encode(v)] for k, v in value.items()]}
        if kind is np.ndarray:
            return self.array(value)
        if kind is DecisionTreeClassifier:
            return {"__sklearn_tree__": {k: self.encode(v) for k, v in vars(value).items()}}
        from ibt.distill.relational import RelationalTreeClassifier

        if kind is RelationalTreeClassifier:
            return {"__sklearn_relational_tree__": {
                k: (v.to_json() if k == _FEATURE_MAP else self.encode(v))
                for k, v in vars(value).items()}}
        if kind is Tree:
            state = value.__getstate__()
            nodes = state["nodes"]
            return {"__sklearn_Tree__": {
                "n_features": int(value.n_features), "n_outputs": int(value.n_outputs),
                "n_classes": self.array(np.asarray(value.n_classes)),
                "state": {k: ({"fields": {f: self.array(np.ascontiguousarray(nodes[f]))
                                          for f in nodes.dtype.names}} if k == "nodes"
                              else self.encode(v)) for k, v in state.items()}}}
        return self.encode_other(value)

    def encode_other(self, value: Any) -> Any:
        """A value of a type this codec does not know: a ``TypeError`` (subclasses add types
        under the reserved tags of :data:`TAGS`)."""
        kind = type(value)
        raise TypeError(f"cannot store a {kind.__module__}.{kind.__qualname__} as plain data")


class PlainDecoder:
    """Documents of :class:`PlainEncoder` back to values (``arrays``: the npz's members)."""

    def __init__(self, arrays: Mapping[str, np.ndarray] | None):
        self.arrays = arrays

    def array(self, doc: Any) -> np.ndarray:
        ref = doc.get("__array__") if isinstance(doc, dict) and len(doc) == 1 else None
        if not (isinstance(ref, list) and len(ref) == 3 and isinstance(ref[0], str)
                and type(ref[1]) is int and isinstance(ref[2], list)):
            raise PlainDataError(f"expected an array reference, got {doc!r:.60}")
        pool, offset, shape = ref
        if self.arrays is None or pool not in self.arrays or self.arrays[pool].ndim != 1:
            raise PlainDataError(f"no array pool {pool!r:.60} in the payload")
        size = math.prod(shape)
        if offset < 0 or offset + size > len(self.arrays[pool]):
            raise PlainDataError(f"array reference {ref} lies outside its pool")
        return self.arrays[pool][offset:offset + size].reshape(shape).copy()

    def decode(self, doc: Any) -> Any:
        if doc is None or type(doc) in (bool, int, float, str):
            return doc
        if type(doc) is list:
            return [self.decode(v) for v in doc]
        if type(doc) is not dict:
            raise PlainDataError(f"unexpected {type(doc).__name__} in a payload")
        tags = sorted(TAGS & set(doc))
        if not tags:
            return {k: self.decode(v) for k, v in doc.items()}
        tag = tags[0]
        if set(doc) != ({tag, "value"} if tag == "__numpy__" else {tag}):
            raise PlainDataError(f"malformed tagged value with keys {sorted(doc)}")
        body = doc[tag]
        if tag == "__tuple__":
            return tuple(self.decode(v) for v in body)
        if tag == "__float__":
            if body not in ("nan", "inf", "-inf"):
                raise PlainDataError(f"unknown float {body!r:.60}")
            return float(body)
        if tag == "__numpy__":
            dtype = np.dtype(body)
            if dtype.kind not in _SCALAR_KINDS:
                raise PlainDataError(f"unexpected NumPy scalar dtype {body!r:.60}")
            return dtype.type(self.decode(doc["value"]))
        if tag == "__items__":
            return {self.decode(k): self.decode(v) for k, v in body}
        if tag == "__array__":
            return self.array(doc)
        if tag == "__sklearn_tree__":
            from sklearn.tree import DecisionTreeClassifier

            model = DecisionTreeClassifier.__new__(DecisionTreeClassifier)
            model.__dict__.update({k: self.decode(v) for k, v in body.items()})
            return model
        if tag == "__sklearn_relational_tree__":
            from ibt.bt.linear import FeatureMap
            from ibt.distill.relational import RelationalTreeClassifier

            relational = RelationalTreeClassifier.__new__(RelationalTreeClassifier)
            try:
                relational.__dict__.update({
                    k: (FeatureMap.from_json(v) if k == _FEATURE_MAP else self.decode(v))
                    for k, v in body.items()})
            except (TypeError, ValueError, KeyError) as err:
                if isinstance(err, PlainDataError):
                    raise
                raise PlainDataError(f"a relational tree's feature map is invalid ({err})"
                                     ) from None
            if _FEATURE_MAP not in relational.__dict__:
                raise PlainDataError("a relational tree without its feature map")
            return relational
        if tag == "__sklearn_Tree__":
            return self._tree(body)
        return self.decode_other(tag, body)

    def decode_other(self, tag: str, body: Any) -> Any:
        """The value of a reserved tag this codec does not build (subclasses add types)."""
        raise PlainDataError(f"unexpected tag {tag!r:.60} here")

    def _tree(self, body: dict[str, Any]) -> Any:
        from sklearn.tree._tree import NODE_DTYPE, Tree

        state = dict(body["state"])
        columns = state["nodes"]["fields"]
        if list(columns) != list(NODE_DTYPE.names):
            raise PlainDataError(f"tree node fields {list(columns)!r:.60} are not "
                                 f"scikit-learn's {list(NODE_DTYPE.names)}")
        count = len(self.array(columns[NODE_DTYPE.names[0]]))
        nodes = np.zeros(count, dtype=NODE_DTYPE)
        for name, ref in columns.items():
            nodes[name] = self.array(ref)
        state = {k: (nodes if k == "nodes" else self.decode(v)) for k, v in state.items()}
        if isinstance(state.get("values"), np.ndarray):
            state["values"] = np.ascontiguousarray(state["values"])
        tree = Tree(int(body["n_features"]),
                    np.asarray(self.array(body["n_classes"]), dtype=np.intp),
                    int(body["n_outputs"]))
        tree.__setstate__(state)
        return tree


def to_document(value: Any) -> dict[str, Any]:
    """Any encodable value as one JSON-able document ``{"value": ..., "arrays": {pool: b64}}``
    (arrays as base64 of their little-endian bytes: exact, whatever the floats)."""
    pools: dict[str, list[np.ndarray]] = {}
    doc = PlainEncoder(pools).encode(value)
    encoded = {}
    for name, parts in pools.items():
        if name not in _POOL_DTYPES:
            raise TypeError(f"cannot store an array pool {name!r} in a JSON document")
        array = np.concatenate(parts).astype(_POOL_DTYPES[name])
        encoded[name] = base64.b64encode(array.tobytes()).decode("ascii")
    return {"value": doc, "arrays": encoded}


def from_document(data: Any) -> Any:
    """The value of a :func:`to_document` document (:class:`PlainDataError` if not one)."""
    if not isinstance(data, dict) or set(data) != {"value", "arrays"} \
            or not isinstance(data["arrays"], dict):
        raise PlainDataError("expected an object with 'value' and 'arrays'")
    arrays = {}
    for name, text in data["arrays"].items():
        if name not in _POOL_DTYPES or not isinstance(text, str):
            raise PlainDataError(f"unknown array pool {name!r:.60}")
        dtype = np.dtype(_POOL_DTYPES[name])
        try:
            raw = base64.b64decode(text.encode("ascii"), validate=True)
            arrays[name] = np.frombuffer(raw, dtype=dtype).astype(dtype.newbyteorder("="))
        except ValueError as err:
            raise PlainDataError(f"array pool {name!r:.60} is not base64 of {name} values "
                                 f"({err})") from None
    try:
        return PlainDecoder(arrays).decode(data["value"])
    except PlainDataError:
        raise
    except Exception as err:  # sklearn's Tree.__setstate__ refuses inconsistent node arrays
        raise PlainDataError(f"undecodable ({type(err).__name__}: {err})") from None


def _tree_types() -> tuple[type, ...]:
    from sklearn.tree import DecisionTreeClassifier

    from ibt.distill.relational import RelationalTreeClassifier

    return (DecisionTreeClassifier, RelationalTreeClassifier)


def tree_to_data(model: Any) -> dict[str, Any]:
    """A fitted ``DecisionTreeClassifier`` (or relational tree) as one JSON-able document
    (:func:`to_document`)."""
    if type(model) not in _tree_types() or not hasattr(model, "tree_"):
        raise TypeError("expected a fitted sklearn DecisionTreeClassifier")
    return to_document(model)


def tree_from_data(data: Any) -> Any:
    """The fitted tree of a :func:`tree_to_data` document, its structure checked: node arrays
    of one length, children after their parent (no cycle), features and classes in range."""
    model = from_document(data)
    if type(model) not in _tree_types() or not hasattr(model, "tree_"):
        raise PlainDataError("the document holds no fitted decision tree")
    check_tree(model)
    return model


_FITTED = ("n_features_in_", "n_outputs_", "classes_", "n_classes_", "max_features_", "tree_")


def _integer(value: Any) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool | np.bool_)


def _check_estimator(model: Any) -> None:
    """:class:`PlainDataError` unless ``model``'s attributes are exactly a fitted single-output
    classifier's: its parameters valid, no attribute that is not one of scikit-learn's (a file
    could otherwise shadow a method such as ``predict``), the fitted ones of the right types."""
    from sklearn.tree import DecisionTreeClassifier

    params = set(DecisionTreeClassifier().get_params())
    extra = {_FEATURE_MAP} if _FEATURE_MAP in vars(model) else set()
    missing = sorted((params | set(_FITTED)) - set(vars(model)))
    unknown = sorted(set(vars(model)) - params - set(_FITTED) - extra)
    if missing or unknown:
        problem = (f"lacks {missing[0]!r}" if missing
                   else f"has the unknown attribute {unknown[0]!r:.60}")
        raise PlainDataError(f"the decision tree {problem}")
    try:
        model._validate_params()
    except ValueError as err:
        raise PlainDataError(f"{' '.join(str(err).split())[:200]}") from None
    classes = model.classes_
    if not (isinstance(classes, np.ndarray) and classes.ndim == 1 and classes.dtype.kind in "iu"
            and len(classes) >= 1 and bool(np.all(np.diff(classes) > 0))):
        raise PlainDataError("its classes_ are not increasing integers")
    counts = [model.n_features_in_, model.n_outputs_, model.n_classes_, model.max_features_]
    if not all(_integer(v) for v in counts) or model.n_outputs_ != 1 \
            or model.n_classes_ != len(classes) \
            or not 1 <= model.max_features_ <= model.n_features_in_:
        raise PlainDataError("its n_features_in_, n_outputs_, n_classes_ or max_features_ "
                             "are not the integers of a fitted single-output tree")


def check_tree(model: Any) -> None:
    """:class:`PlainDataError` unless ``model``'s nodes form a tree that ``predict`` can walk."""
    _check_estimator(model)
    try:
        t = model.tree_
        n, left, right = t.node_count, np.asarray(t.children_left), np.asarray(t.children_right)
        feature, n_features = np.asarray(t.feature), int(model.n_features_in_)
        classes = np.asarray(model.classes_)
    except Exception as err:
        raise PlainDataError(f"not a fitted decision tree ({type(err).__name__})") from None
    index = np.arange(n)
    leaf = left == -1
    ok = (n >= 1 and len(left) == len(right) == len(feature) == n
          and bool(np.all(leaf == (right == -1)))
          and bool(np.all((left[~leaf] > index[~leaf]) & (left[~leaf] < n)))
          and bool(np.all((right[~leaf] > index[~leaf]) & (right[~leaf] < n)))
          and bool(np.all((feature[~leaf] >= 0) & (feature[~leaf] < n_features)))
          and int(t.n_features) == n_features and np.asarray(t.value).shape[0] == n
          and int(t.n_outputs) == 1 and np.asarray(t.n_classes).tolist() == [len(classes)]
          and np.asarray(t.value).shape[-1] == len(classes) >= 1)
    if not ok:
        raise PlainDataError("its nodes do not form a decision tree (children before their "
                             "parent, out of range, or sizes that disagree)")
    children = np.sort(np.concatenate([left[~leaf], right[~leaf]]))
    if not np.array_equal(children, index[1:]):  # every node but the root has one parent
        shared = children[np.flatnonzero(np.diff(children) == 0)]
        which = (f"node {int(shared[0])} has two parents" if shared.size
                 else "a node is reached from no parent")
        raise PlainDataError(f"its nodes do not form a decision tree ({which})")
    odd = np.flatnonzero(leaf & ((feature != _UNDEFINED) | (np.asarray(t.threshold)
                                                            != _UNDEFINED)))
    if odd.size:  # what every walker of the arrays takes for a leaf
        raise PlainDataError(f"node {int(odd[0])} is a leaf but has a feature or threshold "
                             f"(scikit-learn's leaves have {_UNDEFINED} for both)")
    _check_finite(t)
    fmap = getattr(model, _FEATURE_MAP, None)
    beyond = np.flatnonzero(~leaf & (np.abs(np.asarray(t.threshold)) > _FLOAT32_MAX))
    if beyond.size:  # fitted on float32 features: a threshold is a midpoint of two of them
        node = int(beyond[0])
        raise PlainDataError(f"node {node} has the threshold {float(t.threshold[node])!r}, "
                             "beyond the float32 range of the values it tests")
    if fmap is not None and getattr(fmap, "width", None) != n_features:
        raise PlainDataError(f"the relational tree reads {n_features} columns, its feature "
                             "map defines a different number")
    forms = () if fmap is None else fmap.forms
    for k, form in enumerate(forms):
        if not math.isfinite(_FLOAT32_MAX * (abs(form.w1) + abs(form.w2))):
            raise PlainDataError(f"the weights of derived column {n_features - len(forms) + k} "
                                 f"({form.w1!r}, {form.w2!r}) are too large: a linear form must "
                                 "stay finite on every float32 observation")


_FLOAT32_MAX = float(np.finfo(np.float32).max)
_UNDEFINED = -2  # scikit-learn's TREE_UNDEFINED: the feature and threshold of a leaf
_NODE_NUMBERS = ("threshold", "impurity", "weighted_n_node_samples")


def _check_finite(t: Any) -> None:
    """:class:`PlainDataError` naming the first node whose threshold, impurity, weight or
    class values are not finite numbers (NaN and infinity decide nothing: a NaN threshold sends
    every state right, so the tree would not decide as the tree that was fitted)."""
    nodes = t.__getstate__()["nodes"]
    values = np.asarray(t.value, dtype=np.float64).reshape(len(nodes), -1)
    for name in _NODE_NUMBERS:
        bad = np.flatnonzero(~np.isfinite(nodes[name]))
        if bad.size:
            node = int(bad[0])
            raise PlainDataError(f"node {node} has the {name.replace('_', ' ')} "
                                 f"{float(nodes[name][node])!r}; every number of a tree must be "
                                 "finite")
    bad = np.flatnonzero(~np.isfinite(values).all(axis=1))
    if bad.size:
        raise PlainDataError(f"node {int(bad[0])} has a class value that is not finite "
                             f"({values[bad[0]].tolist()}); every number of a tree must be finite")
