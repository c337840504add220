"""Decision-tree files: a fitted tree with what it needs to be read again, as plain JSON.

A tree file (``.json``) is one JSON object::

    {"format": "ibt-tree", "format_version": 2,
     "task": "CartPole-v1", "gym_id": "CartPole-v1", "env_modules": [],
     "feature_names": [...], "action_names": [...],
     "info": {"value": ..., "arrays": {...}},      # run facts (algo, method, seed, iterations...)
     "tree": {"value": ..., "arrays": {...}}}      # the fitted DecisionTreeClassifier

``tree`` and ``info`` are documents of :mod:`ibt.distill.tree_codec` (the cache's exact
encoding): the tree read back is the tree written, attribute for attribute
(:func:`ibt.distill.loop.tree_signature` included). Reading never runs code: JSON only, no
class or module named in the file is imported (``task`` and ``env_modules`` are names the
command line resolves; only its ``--env-module`` imports). Duplicate keys, files that are not
regular files or are larger than :data:`MAX_TREE_BYTES`, and trees whose nodes do not form a
tree are refused.

Format 1 (``ibt-tree/1``) was a joblib pickle, which runs code when loaded: it is read only with
``trust_pickle=True``, by the conversion command :data:`CONVERT_HINT` names.

Errors are :class:`TreeFileError` (a ``ValueError``) naming the file and the fix; the command line
turns them into exit code 2 and one line.
"""

from __future__ import annotations

import json
import os
import shlex
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ibt.bt.document import no_duplicate_keys
from ibt.distill.tree_codec import (
    PlainDataError,
    check_tree,
    from_document,
    to_document,
    tree_from_data,
    tree_to_data,
)
from ibt.files import atomic_write_text, check_regular

if TYPE_CHECKING:
    from ibt.tasks.task import Task

TREE_FORMAT = "ibt-tree"
TREE_FORMAT_VERSION = 2
LEGACY_FORMAT = "ibt-tree/1"  # joblib pickles of earlier versions
TREE_SUFFIX = ".json"
PICKLE_SUFFIXES = (".joblib", ".pkl", ".pickle")
MAX_TREE_BYTES = 64 << 20
_KEYS = ("format", "format_version", "task", "gym_id", "env_modules", "feature_names",
         "action_names", "info", "tree")


class TreeFileError(ValueError):
    """A file that is not a readable decision-tree file; the message names it and the fix."""


def convert_command(path: str | Path) -> str:
    """The command that converts a pickled tree file of ``path`` (trusted) into JSON."""
    new = Path(path).with_suffix(TREE_SUFFIX)
    return (f"python -m ibt convert-tree {shlex.quote(str(path))} -o {shlex.quote(str(new))} "
            "--trust-pickle")


def read_regular_file(path: str | Path, limit: int, what: str) -> bytes:
    """The bytes of ``path`` if it is a regular file of at most ``limit`` bytes, else
    ``ValueError`` (a device such as ``/dev/zero`` or a named pipe would never end)."""
    path = Path(path)
    try:
        info = os.stat(path)
    except OSError as err:
        raise ValueError(f"cannot read the {what} {path} ({err.strerror})") from None
    check_regular(path, info, limit, what)
    with open(path, "rb") as fh:  # read at most limit + 1 bytes: the file may grow meanwhile
        data = fh.read(limit + 1)
    if len(data) > limit:
        raise ValueError(f"{path} grew past {limit:,} bytes while read; pass a finished file")
    return data


def parse_json(data: bytes, path: str | Path, what: str) -> Any:
    """Strict JSON: UTF-8, no duplicate keys; ``ValueError`` naming ``path``. (NaN literals
    are read, so that the reader of the document can say which field must be finite.)"""
    try:
        return json.loads(data.decode("utf-8"), object_pairs_hook=no_duplicate_keys)
    except RecursionError:
        raise ValueError(f"{path} is nested too deeply to be a {what}") from None
    except (UnicodeDecodeError, ValueError) as err:
        raise ValueError(f"{path} is not a valid {what}: not strict JSON ({err})") from None


def save_tree_file(path: str | Path, tree: Any, task: Task, info: dict[str, Any]) -> Path:
    """Write a decision tree, its task's names and run facts (``info``; its ``env_modules``: the
    modules that register the task's environment) as one JSON file, atomically."""
    info = dict(info)
    setup = [task.setup_module] if task.setup_module else []
    modules = list(dict.fromkeys([*info.pop("env_modules", []), *setup]))
    return _write(path, tree, {"task": task.name, "gym_id": task.gym_id, "env_modules": modules,
                               "feature_names": list(task.feature_names),
                               "action_names": list(task.action_names)}, info)


def _write(path: str | Path, tree: Any, names: dict[str, Any], info: dict[str, Any]) -> Path:
    doc = {"format": TREE_FORMAT, "format_version": TREE_FORMAT_VERSION, **names,
           "info": to_document(info), "tree": tree_to_data(tree)}
    path = Path(path)
    atomic_write_text(path, json.dumps(doc, indent=1, allow_nan=False) + "\n")
    return path


def _flat(doc: dict[str, Any], tree: Any, info: dict[str, Any]) -> dict[str, Any]:
    """What callers read: the stored fields with the run facts beside them."""
    flat = {**info, **{k: doc[k] for k in _KEYS if k not in ("info", "tree")}}
    flat["tree"] = tree
    return flat


def _check_names(doc: dict[str, Any], path: Path) -> None:
    for key in ("task", "gym_id"):
        if not isinstance(doc.get(key), str):
            raise TreeFileError(f"{path}: {key!r} is not a string; distil it again")
    for key in ("env_modules", "feature_names", "action_names"):
        values = doc.get(key)
        if not isinstance(values, list) or not all(isinstance(v, str) for v in values):
            raise TreeFileError(f"{path}: {key!r} is not a list of names; distil it again")


def _check_fit(doc: dict[str, Any], path: Path) -> None:
    tree, names, actions = doc["tree"], doc["feature_names"], doc["action_names"]
    fmap = getattr(tree, "feature_map_", None)  # a relational tree reads its observed features
    reads = tree.n_features_in_ if fmap is None else fmap.n_features
    if reads != len(names) or not set(map(int, tree.classes_)) <= set(
            range(len(actions))):
        raise TreeFileError(f"{path} is inconsistent: its tree reads {reads} "
                            f"features and predicts {sorted(map(int, tree.classes_))}, but it "
                            f"names {len(names)} features and {len(actions)} actions; distil it "
                            "again")


def load_tree_file(path: str | Path, *, trust_pickle: bool = False) -> dict[str, Any]:
    """A tree file, checked: ``{"tree": DecisionTreeClassifier, "task": ..., "feature_names":
    ..., "action_names": ..., "env_modules": ..., **info}``.

    A pickle (``.joblib``, format 1) is refused with the conversion command unless
    ``trust_pickle`` (it runs code when read: only files from a trusted source).
    """
    path = Path(path)
    if path.suffix.lower() in PICKLE_SUFFIXES:
        if not trust_pickle:
            raise TreeFileError(f"{path} is a pickled tree file (it would run code when read); "
                                f"if you trust its source, convert it once: "
                                f"`{convert_command(path)}`")
        return _load_pickle(path)
    data = read_regular_file(path, MAX_TREE_BYTES, "decision-tree file")
    not_ours = f"{path} is not a decision-tree file written by `python -m ibt distill`"
    if data[:1] == b"\x80" or data[:2] == b"PK":  # a pickle or a zip under another suffix
        raise TreeFileError(f"{not_ours} (binary: a pickle or an archive); "
                            f"{'convert a trusted pickle with `' + convert_command(path) + '`'}")
    try:
        doc = parse_json(data, path, "decision-tree file")
    except ValueError as err:
        raise TreeFileError(str(err)) from None
    if not isinstance(doc, dict) or doc.get("format") != TREE_FORMAT:
        raise TreeFileError(f"{not_ours} (no \"format\": \"{TREE_FORMAT}\")")
    if doc.get("format_version") != TREE_FORMAT_VERSION:
        raise TreeFileError(f"{path} is a tree file of format version "
                            f"{doc.get('format_version')!r:.60}; this version reads "
                            f"{TREE_FORMAT_VERSION}: distil it again")
    missing = [k for k in _KEYS if k not in doc]
    if missing:
        raise TreeFileError(f"{not_ours} (missing {', '.join(missing)}); distil it again")
    _check_names(doc, path)
    try:
        tree = tree_from_data(doc["tree"])
        info = from_document(doc["info"])
    except PlainDataError as err:
        raise TreeFileError(f"{path} holds no valid decision tree ({err}); distil it "
                            "again") from None
    if not isinstance(info, dict) or not all(isinstance(k, str) for k in info):
        raise TreeFileError(f"{path}: 'info' is not an object; distil it again")
    flat = _flat(doc, tree, info)
    _check_fit(flat, path)
    return flat


def _load_pickle(path: Path) -> dict[str, Any]:
    """A format-1 joblib tree file. RUNS THE FILE'S CODE: only for trusted files."""
    from sklearn.tree import DecisionTreeClassifier

    read_regular_file(path, MAX_TREE_BYTES, "decision-tree file")  # no device, no pipe
    not_ours = f"{path} is not a decision-tree file written by `python -m ibt distill`"
    try:
        import joblib

        doc = joblib.load(path)
    except Exception as err:  # joblib raises many kinds on a damaged file
        raise TreeFileError(f"{not_ours} ({type(err).__name__})") from None
    keys = ("tree", "task", "feature_names", "action_names")
    if not isinstance(doc, dict) or any(k not in doc for k in keys):
        raise TreeFileError(not_ours)
    if doc.get("format", LEGACY_FORMAT) != LEGACY_FORMAT:
        raise TreeFileError(f"{path} is a {doc['format']!r:.60} file; expected {LEGACY_FORMAT}")
    if type(doc["tree"]) is not DecisionTreeClassifier or not hasattr(doc["tree"], "tree_"):
        raise TreeFileError(f"{not_ours} (it holds no fitted decision tree)")
    doc = {**doc, "env_modules": list(doc.get("env_modules", [])),
           "gym_id": doc.get("gym_id", doc["task"])}
    _check_names(doc, path)
    try:
        check_tree(doc["tree"])
    except PlainDataError as err:
        raise TreeFileError(f"{path} holds no valid decision tree ({err})") from None
    _check_fit(doc, path)
    return doc


def convert_tree_file(source: str | Path, target: str | Path) -> dict[str, Any]:
    """Rewrite a trusted format-1 pickle ``source`` as a JSON tree file ``target`` (the same
    tree, names and run facts; nothing is resolved or imported); returns what was written."""
    doc = load_tree_file(source, trust_pickle=True)
    names = {k: doc[k] for k in _KEYS if k not in ("format", "format_version", "info", "tree")}
    info = {k: v for k, v in doc.items() if k not in _KEYS}
    _write(target, doc["tree"], names, info)
    return doc
