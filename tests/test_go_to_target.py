"""Issue 26's first done-when: on the go-to-target task of a user's module (position and target
on a line, a PPO agent), ``python -m ibt pipeline`` with default settings recommends a
relational BT of at most 15 nodes that keeps at least 95 % of the agent."""

from __future__ import annotations

import json
import shutil

import pytest

from ibt.cli import main

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(shutil.which("dot") is None, reason="needs graphviz's dot")]


def test_the_default_pipeline_recommends_a_small_relational_bt(tmp_path):
    from tests.fixtures.go_to_target import CHECKPOINT

    out = tmp_path / "out"
    argv = ["pipeline", "GoToTarget-v0", "ppo", "--env-module", "tests.fixtures.go_to_target",
            "--checkpoint", str(CHECKPOINT), "-o", str(out), "--quiet"]
    assert main(argv) == 0
    from ibt.bt.json_io import load_json

    bt = load_json(out / "bt.json")
    report = (out / "report.md").read_text()
    assert "**Target met**" in report
    assert bt.node_count <= 15 and bt.relational_count >= 1
    assert "relational **(recommended)**" in report
    assert "position - target" in report  # the test as a reader writes it
    json.loads((out / "bt.json").read_text())
