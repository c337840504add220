"""BT JSON files (ibt.bt.json_io): what is saved reads back equal, and a reader is refused with
a reason for a missing file, something not a regular file, a file past the size limit (a file
of exactly the limit is read) and a file that is not a valid BT."""

from __future__ import annotations

import os

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ibt.bt import json_io
from ibt.bt.json_io import MAX_BT_BYTES, load_json, save_json
from ibt.bt.model import Action, BehaviorTree, Condition, Fallback, Sequence
from ibt.cli import checks


def _bt(threshold: float, op: str = "<=") -> BehaviorTree:
    root = Fallback((Sequence((Condition(1, op, threshold), Action(0))), Action(1)))
    return BehaviorTree(root, ("x", "y"), ("left", "right"))


@settings(max_examples=30, deadline=None)
@given(st.floats(-1e6, 1e6, allow_nan=False, width=32), st.sampled_from(["<=", ">"]))
def test_a_saved_bt_reads_back_equal(tmp_path_factory, threshold, op):
    path = tmp_path_factory.mktemp("bt") / "bt.json"
    bt = _bt(threshold, op)
    assert save_json(bt, path) == path
    assert path.read_text().endswith("}\n")
    assert load_json(path) == bt and load_json(str(path)) == bt


def test_a_missing_file_is_not_found(tmp_path):
    with pytest.raises(FileNotFoundError, match="no behavior tree at"):
        load_json(tmp_path / "none.json")


def test_a_folder_or_pipe_is_refused_as_not_a_regular_file(tmp_path):
    with pytest.raises(ValueError, match="not a regular file"):
        load_json(tmp_path)
    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)
    with pytest.raises(ValueError, match="not a regular file"):
        load_json(fifo)  # refused before it is opened: no reader waits on a writer


def test_the_size_limit_is_the_cli_s_and_a_file_of_exactly_the_limit_is_read(tmp_path):
    assert MAX_BT_BYTES == checks.MAX_BT_BYTES  # one limit for a BT file, read either way
    text = _bt(0.5).to_json()
    path = tmp_path / "padded.json"
    path.write_text(text + " " * (MAX_BT_BYTES - len(text)))  # JSON allows trailing blanks
    assert path.stat().st_size == MAX_BT_BYTES and load_json(path) == _bt(0.5)
    with path.open("a") as fh:
        fh.write(" ")
    with pytest.raises(ValueError, match="larger than a behavior tree may be"):
        load_json(path)


def test_a_small_limit_applies_the_same_way(tmp_path, monkeypatch):
    text = _bt(0.5).to_json()
    monkeypatch.setattr(json_io, "MAX_BT_BYTES", len(text))
    path = tmp_path / "bt.json"
    path.write_text(text)
    assert load_json(path) == _bt(0.5)
    path.write_text(text + "\n")
    with pytest.raises(ValueError, match=f"larger.*{len(text):,} bytes"):
        load_json(path)


def test_no_more_than_one_byte_past_the_limit_is_read(tmp_path, monkeypatch):
    """A file far past the limit (or one that grows while read) costs the limit, not its
    size: the reader asks for the limit and one byte more, enough to tell it is too large."""
    text = _bt(0.5).to_json()
    monkeypatch.setattr(json_io, "MAX_BT_BYTES", len(text))
    asked = []

    class Recording:
        def __init__(self, fh):
            self.fh = fh

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.fh.close()

        def read(self, size):
            asked.append(size)
            return self.fh.read(size)

    monkeypatch.setattr(json_io, "open", lambda *a, **k: Recording(open(*a, **k)),
                        raising=False)
    path = tmp_path / "bt.json"
    path.write_text(text * 5)
    with pytest.raises(ValueError, match="larger"):
        load_json(path)
    assert asked == [len(text) + 1]


@pytest.mark.parametrize("content", ["", "{", '{"a": 1, "a": 2}', "[]", '{"root": NaN}'])
def test_a_file_that_is_not_a_bt_is_refused_naming_it(tmp_path, content):
    path = tmp_path / "bad.json"
    path.write_text(content)
    with pytest.raises(ValueError, match=r"bad\.json is not a valid behavior tree") as raised:
        load_json(path)
    assert raised.value.__cause__ is None
