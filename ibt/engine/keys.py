"""The identities the engine's cache keys hold: a tree's, a BT's, a plain document's.

A key names what decides a result, never where it came from: two trees that decide alike share
one identity (:func:`ibt.cache.store.tree_digest` of a classifier's decision function, the
digest of a command tree's arrays), and a BT is named by its JSON document.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any

from ibt.cache.store import tree_digest


def doc_digest(doc: Any) -> str:
    """The identity of a plain-data document (a command tree's arrays)."""
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:16]


def tree_key(tree: Any) -> str:
    """The identity of any tree a stage returns: a classifier's (relational ones included) by
    its decision function, a tree held as plain data (command, controller and oblique trees:
    a ``to_doc`` method) by its document."""
    return doc_digest(tree.to_doc()) if hasattr(tree, "to_doc") else tree_digest(tree)


def bt_digest(bt: Any) -> str:
    """A BT's identity in cache keys: the digest of its JSON document."""
    return hashlib.sha256(bt.to_json().encode()).hexdigest()[:16]


def leaves_of(tree: Any) -> int:
    """The leaves of any tree a stage returns."""
    return int(tree.n_leaves if hasattr(tree, "to_doc") else tree.get_n_leaves())
