"""The identities in the engine's cache keys (ibt.engine.keys): a document's digest does not
depend on the order of its keys and keeps its committed form (committed cache entries are found
by it), trees that decide alike share one identity, a BT is named by its JSON document, and the
leaves of either kind of tree are counted. Quick: small hand-made trees, no environment."""

from __future__ import annotations

import hashlib
import string

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.tree import DecisionTreeClassifier

from ibt.bt.model import Action, BehaviorTree, Condition, Fallback, Sequence
from ibt.cache.store import tree_digest
from ibt.engine.keys import bt_digest, doc_digest, leaves_of, tree_key

_HEX = set(string.hexdigits.lower())
_plain = st.recursive(
    st.none() | st.booleans() | st.integers(-10**6, 10**6) | st.text(max_size=5)
    | st.floats(allow_nan=False, allow_infinity=False),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=3), inner,
                                                               max_size=3),
    max_leaves=8)


class _DocTree:
    """A tree held as plain data (as command, controller and oblique trees are)."""

    def __init__(self, doc: dict, n_leaves: int) -> None:
        self.doc, self.n_leaves = doc, n_leaves

    def to_doc(self) -> dict:
        return self.doc

    def get_n_leaves(self) -> int:  # a plain-data tree is never counted as a classifier
        raise AssertionError("counted as a classifier")


def _classifier(labels: tuple[int, ...], seed: int = 0) -> DecisionTreeClassifier:
    x = np.arange(len(labels), dtype=np.float32).reshape(-1, 1)
    return DecisionTreeClassifier(random_state=seed).fit(x, np.asarray(labels))


def _bt(threshold: float) -> BehaviorTree:
    root = Fallback((Sequence((Condition(0, "<=", threshold), Action(0))), Action(1)))
    return BehaviorTree(root, ("x",), ("left", "right"))


def test_a_document_digest_keeps_its_committed_form():
    """Sixteen hex digits of SHA-256 over the key-sorted JSON: the cache entries committed under
    data/cache/ are found by exactly this."""
    doc = {"b": 1, "a": [1, 2.5, None, "x"]}
    assert doc_digest(doc) == "cb65921f78e316ea"
    assert doc_digest(doc) == hashlib.sha256(
        b'{"a": [1, 2.5, null, "x"], "b": 1}').hexdigest()[:16]


@settings(max_examples=60, deadline=None)
@given(st.dictionaries(st.text(max_size=4), _plain, max_size=5))
def test_a_document_digest_ignores_the_order_of_its_keys(doc):
    digest = doc_digest(doc)
    assert len(digest) == 16 and set(digest) <= _HEX
    assert doc_digest(dict(reversed(list(doc.items())))) == digest


@settings(max_examples=60, deadline=None)
@given(_plain, _plain)
def test_different_documents_have_different_digests(one, other):
    if one != other and repr(one) != repr(other):
        assert doc_digest([one]) != doc_digest([other])


def test_a_plain_data_tree_is_named_by_its_document_and_counted_by_its_leaves():
    tree = _DocTree({"leaves": [1, 2, 3], "split": 0.5}, 3)
    assert tree_key(tree) == doc_digest({"split": 0.5, "leaves": [1, 2, 3]})
    assert tree_key(tree) != tree_key(_DocTree({"leaves": [1, 2], "split": 0.5}, 2))
    assert leaves_of(tree) == 3 and isinstance(leaves_of(tree), int)


def test_classifiers_that_decide_alike_share_one_key():
    one, same = _classifier((0, 0, 1, 1)), _classifier((0, 0, 1, 1), seed=7)
    other = _classifier((0, 1, 1, 1))
    assert tree_key(one) == tree_digest(one) == tree_key(same)
    assert tree_key(one) != tree_key(other)
    assert len(tree_key(one)) == 16


@settings(max_examples=30, deadline=None)
@given(st.lists(st.integers(0, 2), min_size=1, max_size=12))
def test_a_classifier_is_counted_by_its_leaves(labels):
    tree = _classifier(tuple(labels))
    assert leaves_of(tree) == tree.get_n_leaves() == np.sum(tree.tree_.children_left == -1)


def test_a_bt_is_named_by_its_json_document():
    bt = _bt(0.5)
    assert bt_digest(bt) == hashlib.sha256(bt.to_json().encode()).hexdigest()[:16]
    assert bt_digest(_bt(0.5)) == bt_digest(bt) != bt_digest(_bt(0.25))
