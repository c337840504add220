"""``make figures`` run twice leaves the tree as it was: a notebook's scrubbed outputs do not
depend on how the kernel interleaved stdout and stderr, progress bars leave nothing, and the
wall-time record is rewritten only when it no longer describes this machine."""

from __future__ import annotations

import json

import nbformat
from hypothesis import given, settings
from hypothesis import strategies as st

from ibt import notebooks


def _notebook(outputs: list[dict]) -> nbformat.NotebookNode:
    nb = nbformat.v4.new_notebook()
    cell = nbformat.v4.new_code_cell("work()", id="work")
    cell.outputs = [nbformat.from_dict(o) for o in outputs]
    nb.cells = [cell]
    return nb


def _stream(name: str, text: str) -> dict:
    return {"output_type": "stream", "name": name, "text": text}


def _scrubbed(tmp_path, outputs: list[dict], name: str = "nb.ipynb") -> str:
    path = tmp_path / name
    nbformat.write(_notebook(outputs), path)
    notebooks.scrub(path)
    return path.read_text()


def test_streams_are_joined_per_name_in_a_fixed_order_and_bars_go(tmp_path):
    # Expect: within a run of stream outputs, stdout then stderr, each joined; a progress bar
    # (carriage returns) and its closing newline dropped; a display output keeps its place
    figure = {"output_type": "display_data", "data": {"text/plain": "figure"}, "metadata": {}}
    text = _scrubbed(tmp_path, [
        _stream("stderr", "50%|#####     |\r100%|##########|"), _stream("stdout", "a\n"),
        _stream("stderr", "\n"), _stream("stderr", "careful\n"), _stream("stdout", "b\n"),
        figure, _stream("stdout", "c\n")])
    outputs = json.loads(text)["cells"][0]["outputs"]
    assert [(o["output_type"], o.get("name"), "".join(o.get("text", "")) or None)
            for o in outputs] == [
        ("stream", "stdout", "a\nb\n"), ("stream", "stderr", "careful\n"),
        ("display_data", None, None), ("stream", "stdout", "c\n")]
    assert nbformat.validate(nbformat.reads(text, as_version=4)) is None


@settings(max_examples=40, deadline=None)
@given(st.lists(st.sampled_from(["stdout", "stderr"]), min_size=1, max_size=8), st.randoms())
def test_any_interleaving_of_the_same_streams_scrubs_to_the_same_file(tmp_path_factory, names,
                                                                      rng):
    # Law: each stream's pieces in their own order, interleaved any way -> the same notebook
    pieces = [_stream(name, f"{name} {i}\n") for i, name in enumerate(names)]
    shuffled = pieces[:]
    rng.shuffle(shuffled)
    by_name = {n: [p for p in pieces if p["name"] == n] for n in ("stdout", "stderr")}
    interleaved = [by_name[p["name"]].pop(0) for p in shuffled]  # per-stream order kept
    folder = tmp_path_factory.mktemp("nb")
    assert _scrubbed(folder, pieces, "a.ipynb") == _scrubbed(folder, interleaved, "b.ipynb")


def test_a_scrubbed_notebook_scrubs_to_itself(tmp_path):
    # Expect: scrubbing is idempotent (a rerun of make figures rewrites nothing)
    first = _scrubbed(tmp_path, [_stream("stdout", "a\n"), _stream("stderr", "w\n"),
                                 _stream("stdout", "b\n")])
    notebooks.scrub(tmp_path / "nb.ipynb")
    assert (tmp_path / "nb.ipynb").read_text() == first


def test_the_time_record_is_rewritten_only_when_it_no_longer_holds(tmp_path, monkeypatch):
    # Expect: written when absent; a rerun within the tolerance leaves the file byte for byte;
    # a time beyond it, another machine or an unreadable record gets a fresh record
    path = notebooks.record_time(200.0, data_dir=tmp_path)
    first = path.read_text()
    assert json.loads(first)["seconds"] == 200.0
    for seconds in (200.0 / notebooks.RECORD_TOLERANCE, 150.0, 290.0,
                    200.0 * notebooks.RECORD_TOLERANCE):
        assert notebooks.record_stands(seconds, tmp_path)
        notebooks.record_time(seconds, data_dir=tmp_path)
        assert path.read_text() == first, seconds
    notebooks.record_time(400.0, data_dir=tmp_path)
    assert json.loads(path.read_text())["seconds"] == 400.0
    monkeypatch.setattr(notebooks, "_machine", lambda: "riscv64, 64 cores")
    notebooks.record_time(390.0, data_dir=tmp_path)
    assert json.loads(path.read_text())["machine"] == "riscv64, 64 cores"
    path.write_text("{not json")
    notebooks.record_time(390.0, data_dir=tmp_path)
    assert json.loads(path.read_text())["seconds"] == 390.0


def test_record_time_refuses_a_time_that_is_not_a_number(capsys):
    assert notebooks.main(["record-time", "soon"]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
