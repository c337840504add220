"""Every committed BT with linear commands or tests of up to four features (format 2) runs in
stock BehaviorTree.CPP exactly as ``ibt`` runs it: the same decision, and for a ``Box`` task the
same command doubles, on the states of its leaf regions, both sides of every threshold, random
states and the states it visits on two final episodes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ibt.bt.document import FORMAT_LINEAR
from ibt.bt.json_io import load_json
from ibt.evaluate.rollouts import final_seeds, rollout
from ibt.export.agreement import agreement_states
from ibt.export.btcpp import to_btcpp_xml
from ibt.export.engine import EngineTree
from ibt.paths import ROOT
from ibt.tasks.catalogue import get_task

HEADLINE = ROOT / "figures" / "headline"
LINEAR = sorted(p for p in HEADLINE.glob("*/bt.json")
                if json.loads(p.read_text())["format"] == FORMAT_LINEAR)


def _task_of(path: Path) -> str:
    import pandas as pd

    table = pd.read_csv(ROOT / "data" / "results" / "headline.csv")
    row = table[table.json_file == path.relative_to(ROOT).as_posix()].iloc[0]
    return str(row.task)


def test_the_headline_holds_bts_that_steer():
    assert LINEAR, "no committed BT of format 2 under figures/headline/"


@pytest.mark.parametrize("path", LINEAR, ids=lambda p: p.parent.name)
def test_the_engine_sends_what_ibt_sends(path):
    task = get_task(_task_of(path))
    bt = load_json(path)
    xml = (path.parent / "bt.xml").read_text()
    assert xml == to_btcpp_xml(bt)  # the committed XML is the one ibt writes
    engine = EngineTree(xml, bt.feature_names, bt.action_names, commands=bt.commands)
    visited: list[np.ndarray] = []

    def act(obs: np.ndarray) -> np.ndarray:
        x = task.features(obs)
        visited.append(x)
        ids = bt.decide(x)
        if bt.commands is None:
            return ids
        wide = x.astype(np.float32).astype(np.float64)
        return bt.commands.evaluate(ids, wide).astype(np.float32)

    rollout(task, act, final_seeds(2), n_envs=2)
    states = np.concatenate([agreement_states(bt, task, n_random=1000, seed=0),
                             np.concatenate(visited)[:2000]]).astype(np.float32)
    wide = states.astype(np.float64)
    ours = bt.decide(states)
    theirs = engine.decide(states)
    assert np.array_equal(ours, theirs)
    if bt.commands is not None:  # the doubles the engine's Script wrote, tick by tick
        sent = bt.commands.evaluate(ours, wide)
        for row, want in zip(states[:1500], sent[:1500], strict=True):
            engine.tick(row)
            got = [engine.blackboard.get_double(k) for k in engine.command_keys[1:]]
            assert got == want.tolist()
