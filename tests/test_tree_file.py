"""Decision-tree files are plain JSON: exact round trips, pickles only by explicit trust,
and the command line's signals and temporary files."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import joblib
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.tree import DecisionTreeClassifier

from ibt.cache.payloads import difference
from ibt.cli import main, sweep_temp_files
from ibt.distill.loop import tree_signature
from ibt.distill.tree_file import (
    TREE_FORMAT,
    TREE_FORMAT_VERSION,
    TreeFileError,
    load_tree_file,
    save_tree_file,
)
from ibt.tasks.catalogue import get_task

ROOT = Path(__file__).parents[1]
CARTPOLE = get_task("CartPole-v1")


def _fit(seed: int, n: int, leaves: int | None, labels: list[int]) -> DecisionTreeClassifier:
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, 4)).astype(np.float32)
    y = np.array(labels)[rng.integers(0, len(labels), size=n)]
    return DecisionTreeClassifier(max_leaf_nodes=leaves, random_state=seed).fit(x, y)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**16), n=st.integers(2, 200), leaves=st.none() | st.integers(2, 30),
       labels=st.sampled_from([[0], [1], [0, 1]]))
def test_a_tree_file_holds_the_tree_exactly(tmp_path_factory, seed, n, leaves, labels):
    tree = _fit(seed, n, leaves, labels)
    path = tmp_path_factory.mktemp("t") / "tree.json"
    info = {"algo": "ppo", "seed": seed, "iterations": [{"selection_mean": np.float64(0.5),
                                                         "leaves": 3}]}
    save_tree_file(path, tree, CARTPOLE, info)
    doc = load_tree_file(path)
    assert tree_signature(doc["tree"]) == tree_signature(tree)
    assert difference(doc["tree"], tree) is None
    assert difference(doc["iterations"], info["iterations"]) is None
    assert (doc["task"], doc["algo"]) == ("CartPole-v1", "ppo")
    raw = json.loads(path.read_text())
    assert (raw["format"], raw["format_version"]) == (TREE_FORMAT, TREE_FORMAT_VERSION)


def test_a_pickle_is_read_only_when_trusted_and_converts_exactly(tmp_path, capsys):
    tree = _fit(1, 300, 8, [0, 1])
    old = tmp_path / "old.joblib"
    joblib.dump({"format": "ibt-tree/1", "tree": tree, "task": "CartPole-v1",
                 "gym_id": "CartPole-v1", "env_modules": [],
                 "feature_names": list(CARTPOLE.feature_names),
                 "action_names": list(CARTPOLE.action_names), "algo": "dqn"}, old)
    with pytest.raises(TreeFileError, match="convert-tree"):
        load_tree_file(old)
    new = tmp_path / "new.json"
    assert main(["convert-tree", str(old), "-o", str(new), "--trust-pickle"]) == 0
    doc = load_tree_file(new)
    assert tree_signature(doc["tree"]) == tree_signature(tree) and doc["algo"] == "dqn"
    capsys.readouterr()
    # a trusted pickle is also read directly, and decides as its conversion
    assert main(["evaluate", str(old), "--episodes", "2", "--trust-pickle"]) == 0
    from_pickle = capsys.readouterr().out
    assert main(["evaluate", str(new), "--episodes", "2"]) == 0
    assert capsys.readouterr().out == from_pickle


def test_a_bt_file_in_capitals_is_a_bt(tmp_path, capsys):
    bt = ROOT / "data" / "trees" / "CartPole-v1" / "dqn" / "imitation-bt.json"
    upper = tmp_path / "UPPER.JSON"
    upper.write_text(bt.read_text())
    assert main(["evaluate", str(upper), "--task", "CartPole-v1", "--episodes", "1"]) == 0
    assert capsys.readouterr().out.startswith("CartPole-v1: mean return")


def test_stale_temporary_files_are_swept_and_fresh_ones_kept(tmp_path):
    out = tmp_path / "bt.json"
    stale, fresh = tmp_path / ".bt.json.ab12cd34.json", tmp_path / ".bt.json.ef34gh.json"
    other = tmp_path / ".other.json.ab12cd.json"
    for path in (stale, fresh, other):
        path.write_text("partial")
    os.utime(stale, (time.time() - 3600, time.time() - 3600))
    os.utime(other, (time.time() - 3600, time.time() - 3600))
    assert sweep_temp_files(out) == [stale]
    assert fresh.exists() and other.exists() and not stale.exists()


def test_sigterm_exits_143_with_one_line_and_leaves_no_file(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    env = {**os.environ, "SDL_VIDEODRIVER": "dummy"}
    proc = subprocess.Popen([sys.executable, "-m", "ibt", "distill", "CartPole-v1", "ppo", "-o",
                             str(out / "tree.json"), "--quiet"], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(4)  # well into the work (imports take ~2 s)
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 143, stderr
    assert len(stderr.splitlines()) == 1 and stderr.startswith("terminated (SIGTERM)")
    assert list(out.iterdir()) == []


def test_sigterm_inside_an_import_is_sent_again_and_raised_after_it(tmp_path, monkeypatch):
    """Raised inside an import, the stop could cross a C extension's initialisation and abort
    the process; there the handler sends the signal again instead, and raises outside one."""
    import importlib

    from ibt.signals import Terminated

    cli_main = importlib.import_module("ibt.cli.main")  # ``ibt.cli.main`` names its function

    (tmp_path / "frame_of_an_import.py").write_text("import sys\nFRAME = sys._getframe()\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    import frame_of_an_import  # its module code ran inside the import machinery

    sent: list[tuple[int, int]] = []
    monkeypatch.setattr(os, "kill", lambda pid, signum: sent.append((pid, signum)))
    cli_main._terminate(signal.SIGTERM, frame_of_an_import.FRAME)  # no raise
    deadline = time.monotonic() + 5.0
    while not sent and time.monotonic() < deadline:
        time.sleep(cli_main.REDELIVERY_S)
    assert sent == [(os.getpid(), signal.SIGTERM)]
    with pytest.raises(Terminated):
        cli_main._terminate(signal.SIGTERM, sys._getframe())
