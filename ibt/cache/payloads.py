"""Plain-data payloads of the cache: exact codecs whose reading never runs code.

Every cache payload (:mod:`ibt.cache.store`) is bytes made by one codec of :data:`CODECS`:

==============  ======  ==========================================================================
codec           file    what it stores
==============  ======  ==========================================================================
json            .json   a JSON value (sorted keys; numbers, strings, lists, objects)
csv             .csv    a ``pandas.DataFrame`` (no index)
distillation    .npz    an :class:`ibt.distill.loop.Distillation` (its fitted trees included)
refinement      .npz    an :class:`ibt.refine.by_return.Refinement` (its ``TreeArrays``)
synthesis       .json   ``{"row": dict, "bt": BehaviorTree}`` (``ibt.engine.synthesis.synthesised``)
==============  ======  ==========================================================================

An ``.npz`` payload is written by ``np.savez_compressed`` and read by ``np.load(...,
allow_pickle=False)``: its member ``meta`` is one JSON string with the schema name, the schema
version and the value; every array of the value is appended, flattened, to the pool of its dtype
(members ``i8``, ``f8``, ``u1``, ...: plain numeric arrays) and written in the document as a
reference ``{"__array__": [pool, offset, shape]}``. A synthesis payload is one JSON document: the
schema, the row and the BT in the format of ``data/trees/``
(:meth:`ibt.bt.model.BehaviorTree.to_dict`).

Values are encoded exactly by :mod:`ibt.distill.tree_codec` (shared with the tree files of
:mod:`ibt.distill.tree_file`), extended here by :class:`TreeArrays`
(:func:`difference` of a value and its decoded copy is ``None``): JSON
carries ``None``, booleans, integers, strings, lists, string-keyed dicts and finite floats (their
``repr`` is exact); everything else is a tagged object: ``{"__tuple__": [...]}``,
``{"__float__": "nan" | "inf" | "-inf"}``, ``{"__numpy__": dtype, "value": v}`` for a NumPy
scalar, ``{"__items__": [[k, v], ...]}`` for a dict with other keys, an array reference,
``{"__sklearn_tree__": {attribute: value}}`` for a fitted ``DecisionTreeClassifier`` (its whole
``__dict__``, in order), ``{"__sklearn_Tree__": ...}`` for its ``tree_`` (the arguments of
``Tree(n_features, n_classes, n_outputs)`` and the state ``Tree.__setstate__`` takes, node
records split into one array per field) and ``{"__tree_arrays__": {field: value}}`` for a
:class:`ibt.refine.tree_arrays.TreeArrays`. Decoding builds only these types: a payload names no
class or function to import. A type outside this list is a ``TypeError`` when writing, so a new
field that the format cannot hold exactly fails at once, not on a later read.

A payload whose schema or version is not the one this code writes is a :class:`PayloadError`
(for the cache: a miss). Bump :data:`SCHEMA_VERSIONS` when a format changes.
"""

from __future__ import annotations

import importlib
import io
import json
import math
from collections.abc import Callable
from dataclasses import dataclass, fields, is_dataclass
from typing import Any

import numpy as np
import pandas as pd

from ibt.distill.tree_codec import PlainDataError, PlainDecoder, PlainEncoder

#: The schema version of each plain payload written here (the cache's key does not hold it:
#: a payload of another version is a miss, recomputed).
SCHEMA_VERSIONS: dict[str, int] = {"ibt-distillation": 1, "ibt-refinement": 1,
                                   "ibt-synthesis": 1, "ibt-evolution": 1}
META = "meta"  # the npz member holding the JSON document
PayloadError = PlainDataError  # bytes that are not a payload of the expected schema and version


# --- encoding -------------------------------------------------------------------------------

class _Encoder(PlainEncoder):
    """:class:`ibt.distill.tree_codec.PlainEncoder` and :class:`TreeArrays`."""

    def encode_other(self, value: Any) -> Any:
        from ibt.refine.tree_arrays import TreeArrays

        if type(value) is TreeArrays:
            return {"__tree_arrays__": {f.name: self.encode(getattr(value, f.name))
                                        for f in fields(value)}}
        return super().encode_other(value)


class _Decoder(PlainDecoder):
    """:class:`ibt.distill.tree_codec.PlainDecoder` and :class:`TreeArrays`."""

    def decode_other(self, tag: str, body: Any) -> Any:
        from ibt.refine.tree_arrays import TreeArrays

        if tag == "__tree_arrays__":
            return TreeArrays(**{k: self.decode(v) for k, v in body.items()})
        return super().decode_other(tag, body)


def encode(value: Any) -> Any:
    """``value`` as a JSON-able document (no arrays): see the module docstring."""
    return _Encoder(None).encode(value)


def decode(doc: Any) -> Any:
    """The value of a document of :func:`encode`."""
    return _Decoder(None).decode(doc)


# --- whole payloads -------------------------------------------------------------------------

def _fields_of(value: Any, cls: type) -> dict[str, Any]:
    if type(value) is not cls:
        raise TypeError(f"expected a {cls.__qualname__}, got {type(value).__qualname__}")
    return {f.name: getattr(value, f.name) for f in fields(cls)}


def _check_schema(doc: Any, schema: str) -> None:
    if not isinstance(doc, dict) or doc.get("schema") != schema:
        found = doc.get("schema") if isinstance(doc, dict) else type(doc).__name__
        raise PayloadError(f"expected schema {schema!r}, found {found!r}")
    if doc.get("schema_version") != SCHEMA_VERSIONS[schema]:
        raise PayloadError(f"{schema} version {doc.get('schema_version')!r} (this code reads "
                           f"{SCHEMA_VERSIONS[schema]})")


def dumps_npz(schema: str, value: Any) -> bytes:
    """An npz payload of ``value`` under ``schema``."""
    pools: dict[str, list[np.ndarray]] = {}
    doc = {"schema": schema, "schema_version": SCHEMA_VERSIONS[schema],
           "value": _Encoder(pools).encode(value)}
    arrays = {name: np.concatenate(parts) for name, parts in pools.items()}
    buffer = io.BytesIO()
    members: dict[str, Any] = {META: np.array(json.dumps(doc, allow_nan=False)), **arrays}
    np.savez_compressed(buffer, allow_pickle=False, **members)
    return buffer.getvalue()


def loads_npz(schema: str, data: bytes) -> Any:
    """The value of an npz payload of ``schema`` (``np.load(allow_pickle=False)``)."""
    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as npz:
            arrays = {name: npz[name] for name in npz.files}
    except Exception as err:  # a damaged zip raises BadZipFile, OSError, ValueError, EOFError...
        raise PayloadError(f"not a readable npz ({type(err).__name__}: {err})") from None
    if META not in arrays or arrays[META].dtype.kind != "U" or arrays[META].ndim != 0:
        raise PayloadError(f"the npz has no {META!r} document")
    try:
        doc = json.loads(str(arrays.pop(META)[()]))
    except ValueError as err:
        raise PayloadError(f"its {META!r} is not JSON ({err})") from None
    _check_schema(doc, schema)
    return _Decoder(arrays).decode(doc["value"])


def _dataclass_codec(schema: str, cls_path: str) -> tuple[Callable[[Any], bytes],
                                                          Callable[[bytes], Any]]:
    def resolve() -> type:
        module, _, name = cls_path.rpartition(".")
        return getattr(importlib.import_module(module), name)

    def dumps(value: Any) -> bytes:
        return dumps_npz(schema, _fields_of(value, resolve()))

    def loads(data: bytes) -> Any:
        cls = resolve()
        values = loads_npz(schema, data)
        names = [f.name for f in fields(cls)]
        found = list(values) if isinstance(values, dict) else type(values).__name__
        if found != names:
            raise PayloadError(f"{schema} holds {found}, expected the fields {names}")
        return cls(**values)

    return dumps, loads


def dumps_synthesis(value: Any) -> bytes:
    """A synthesis payload: ``{"row": dict, "bt": BehaviorTree}`` as one JSON document."""
    from ibt.bt.model import BehaviorTree

    if type(value) is not dict or list(value) != ["row", "bt"] \
            or type(value["bt"]) is not BehaviorTree or type(value["row"]) is not dict:
        raise TypeError("a synthesis payload is {'row': dict, 'bt': BehaviorTree}")
    doc = {"schema": "ibt-synthesis", "schema_version": SCHEMA_VERSIONS["ibt-synthesis"],
           "row": encode(value["row"]), "bt": value["bt"].to_dict()}
    return (json.dumps(doc, indent=1, allow_nan=False) + "\n").encode()


def loads_synthesis(data: bytes) -> dict[str, Any]:
    from ibt.bt.model import BehaviorTree

    try:
        doc = json.loads(data)
    except ValueError as err:
        raise PayloadError(f"not JSON ({err})") from None
    _check_schema(doc, "ibt-synthesis")
    return {"row": decode(doc["row"]), "bt": BehaviorTree.from_dict(doc["bt"])}


def _dumps_json(value: Any) -> bytes:
    return json.dumps(value, indent=1, sort_keys=True, default=str).encode()


def _loads_json(data: bytes) -> Any:
    return json.loads(data)


def _dumps_csv(frame: pd.DataFrame) -> bytes:
    return frame.to_csv(index=False, lineterminator="\n").encode()


def _loads_csv(data: bytes) -> pd.DataFrame:
    return pd.read_csv(io.BytesIO(data))


@dataclass(frozen=True)
class Codec:
    """How one kind of payload becomes bytes (``payload.<suffix>``) and back."""

    name: str
    suffix: str
    dumps: Callable[[Any], bytes]
    loads: Callable[[bytes], Any]


_distillation = _dataclass_codec("ibt-distillation", "ibt.distill.loop.Distillation")
_refinement = _dataclass_codec("ibt-refinement", "ibt.refine.by_return.Refinement")
_evolution = _dataclass_codec("ibt-evolution", "ibt.refine.structure.Evolution")
#: Every codec of the cache, by the name ``load_or_compute(codec=...)`` and manifests use.
CODECS: dict[str, Codec] = {
    "json": Codec("json", "json", _dumps_json, _loads_json),
    "csv": Codec("csv", "csv", _dumps_csv, _loads_csv),
    "distillation": Codec("distillation", "npz", *_distillation),
    "refinement": Codec("refinement", "npz", *_refinement),
    "evolution": Codec("evolution", "npz", *_evolution),
    "synthesis": Codec("synthesis", "json", dumps_synthesis, loads_synthesis),
}


def codec(name: str) -> Codec:
    try:
        return CODECS[name]
    except KeyError:
        raise ValueError(f"unknown codec {name!r}; expected one of {', '.join(CODECS)}") from None


# --- exact comparison -----------------------------------------------------------------------

def _same_float(a: float, b: float) -> bool:
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return a == b and math.copysign(1.0, a) == math.copysign(1.0, b)


def _array_difference(a: np.ndarray, b: np.ndarray, where: str) -> str | None:
    if a.dtype != b.dtype or a.shape != b.shape:
        return f"{where}: array {a.dtype}{a.shape} != {b.dtype}{b.shape}"
    if a.dtype.names:
        for name in a.dtype.names:
            found = _array_difference(np.ascontiguousarray(a[name]),
                                      np.ascontiguousarray(b[name]), f"{where}[{name!r}]")
            if found:
                return found
        return None
    if np.ascontiguousarray(a).tobytes() != np.ascontiguousarray(b).tobytes():
        return f"{where}: arrays differ"
    return None


def difference(a: Any, b: Any, where: str = "value") -> str | None:
    """Where ``a`` and ``b`` first differ (types, dict order and float bits included), or None.

    Arrays are compared byte for byte (structured ones field by field), fitted scikit-learn
    trees by their whole ``__dict__`` and ``tree_`` state, dataclasses field by field.
    """
    from sklearn.tree import DecisionTreeClassifier
    from sklearn.tree._tree import Tree

    if type(a) is not type(b):
        return f"{where}: {type(a).__qualname__} != {type(b).__qualname__}"
    if isinstance(a, np.ndarray):
        return _array_difference(a, b, where)
    if isinstance(a, float | np.floating):
        return None if _same_float(float(a), float(b)) else f"{where}: {a!r} != {b!r}"
    if isinstance(a, dict):
        if list(a) != list(b):
            return f"{where}: keys {list(a)} != {list(b)}"
        for key in a:
            found = difference(a[key], b[key], f"{where}[{key!r}]")
            if found:
                return found
        return None
    if isinstance(a, list | tuple):
        if len(a) != len(b):
            return f"{where}: length {len(a)} != {len(b)}"
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            found = difference(x, y, f"{where}[{i}]")
            if found:
                return found
        return None
    if isinstance(a, Tree):
        return difference({"n_features": a.n_features, "n_classes": np.asarray(a.n_classes),
                           "n_outputs": a.n_outputs, **a.__getstate__()},
                          {"n_features": b.n_features, "n_classes": np.asarray(b.n_classes),
                           "n_outputs": b.n_outputs, **b.__getstate__()}, f"{where}.tree_")
    if is_dataclass(a) and not isinstance(a, type):
        return difference({f.name: getattr(a, f.name) for f in fields(a)},
                          {f.name: getattr(b, f.name) for f in fields(b)}, where)
    if hasattr(a, "__dict__") and (type(a).__module__.startswith("sklearn.")
                                   or isinstance(a, DecisionTreeClassifier)):
        return difference(dict(vars(a)), dict(vars(b)), where)  # relational trees too
    return None if a == b else f"{where}: {a!r} != {b!r}"
