"""The headline BTs (``ibt.runs.headline`` chooses, ``ibt.views.headline`` writes): chosen by
their rule from the committed results, and the committed files are the BTs those results
evaluated."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from ibt.runs import headline
from ibt.views import headline as files

ROOT = Path(__file__).resolve().parent.parent
RESULTS = ROOT / "data" / "results"


def _runs(**columns) -> pd.DataFrame:
    n = len(next(iter(columns.values())))
    base = {"task": ["T"] * n, "expert": ["dqn"] * n, "method": ["m"] * n, "seed": range(n),
            "episodes": [1000] * n}
    return pd.DataFrame({**base, **columns})


ANCHOR = pd.DataFrame([{"source": "small", "task": "T", "leaves": 4, "nodes": 7,
                        "mean_return": 10.0},
                       {"source": "best", "task": "T", "leaves": 8, "nodes": 15,
                        "mean_return": 20.0}])


def test_the_smallest_keeping_95_and_the_best_at_the_best_published_size():
    runs = _runs(bt_nodes=[5, 9, 7, 30], tree_leaves=[2, 4, 3, 12],
                 retention_norm=[90.0, 96.0, 95.0, 99.0], mean_return=[1.0, 5.0, 4.0, 9.0])
    picked = headline.select(runs, ["T"], ANCHOR).set_index("what")
    # Expect: 7 nodes is the smallest at >= 95 % (5 keeps less); the best anchor is the 8-leaf
    # one, and the 12-leaf run is too large for it
    assert picked.loc[headline.SMALLEST, "bt_nodes"] == 7
    assert picked.loc[headline.AT_PUBLISHED, "bt_nodes"] == 9
    assert (picked["anchor"] == "best").all() and (picked["anchor_leaves"] == 8).all()


def test_none_keeping_95_is_said_and_1000_episodes_win_over_100():
    runs = _runs(bt_nodes=[5, 9, 3], tree_leaves=[2, 4, 2], retention_norm=[80.0, 90.0, 99.0],
                 mean_return=[1.0, 2.0, 50.0], episodes=[1000, 1000, 100])
    picked = headline.select(runs, ["T"], ANCHOR).set_index("what")
    # Expect: the 100-episode run is not looked at while 1,000-episode ones exist
    assert picked.loc[headline.CLOSEST, "bt_nodes"] == 9
    assert picked.loc[headline.AT_PUBLISHED, "episodes"] == 1000


def test_the_committed_headline_is_what_the_rule_picks_from_the_committed_results():
    committed = pd.read_csv(RESULTS / "headline.csv")
    again = headline.headline_table(RESULTS)
    keys = ["task", "expert", "what", "method", "seed", "leaf_limit", "bt_nodes", "episodes"]
    assert committed[keys].astype(str).values.tolist() == again[keys].astype(str).values.tolist()
    for column in ("mean_return", "std_return", "retention_norm", "anchor_return"):
        assert np.allclose(committed[column], again[column], equal_nan=True), column


def test_the_lead_bt_file_is_the_one_its_1000_episodes_evaluated():
    # Expect: the LunarLander BT written under figures/headline/ has the digest of the protocol
    # cache entry whose mean return and share the CSV reports
    from ibt.bt.json_io import load_json
    from ibt.engine.keys import bt_digest

    row = pd.read_csv(RESULTS / "headline.csv").query("task == 'LunarLander-v3'").iloc[0]
    bt = load_json(ROOT / row.json_file)
    assert bt.node_count == row.bt_nodes
    digest = bt_digest(bt)
    found = []  # a protocol entry (a summary), or a returns entry (every episode's return)
    for kind in ("protocol", "returns"):
        for d in (ROOT / "data" / "cache" / kind).iterdir():
            params = json.loads((d / "manifest.json").read_text())["params"]
            if params.get("bt") == digest and params.get("episodes", 1000) == row.episodes:
                payload = json.loads((d / "payload.json").read_text())
                if kind == "returns":
                    returns = payload["returns"]
                    payload = {"mean_return": sum(returns) / len(returns),
                               "share_at_threshold": sum(r >= 200 for r in returns)
                               / len(returns)}
                found.append(payload)
    assert len(found) == 1
    assert found[0]["mean_return"] == pytest.approx(row.mean_return)
    assert found[0]["share_at_threshold"] == pytest.approx(row.share_200)


def test_smoke_reads_the_committed_cache_under_the_paper_budgets(tmp_path):
    import ibt

    smoke = ibt.config("smoke", data_dir=tmp_path, figures_dir=tmp_path, paper_dir=tmp_path)
    lookup = files.lookup_config(smoke)
    assert lookup.profile == "paper" and lookup.cache_dir == ROOT / "data" / "cache"
    assert (lookup.figures_dir, lookup.data_dir) == (tmp_path, tmp_path)  # outputs: scratch
    paper = replace(smoke, profile="paper")
    assert files.lookup_config(paper) is paper  # the paper profile reads its own cache


def test_a_bt_the_headline_no_longer_lists_is_retired_and_nothing_else(tmp_path):
    """Only folders the last headline listed lose their files, and only the files the
    headline writes; a user's file keeps its folder, an unlisted folder is untouched."""
    for name in ("kept", "old", "mixed", "users"):
        (tmp_path / name).mkdir()
        for file in files.HEADLINE_FILES:
            (tmp_path / name / file).write_text("x")
    (tmp_path / "mixed" / "notes.txt").write_text("mine")
    gone = files.retire(tmp_path, ["kept", "old", "mixed", "../users", "missing"], ["kept"])
    assert gone == ["mixed", "old"]
    assert not (tmp_path / "old").exists()
    assert sorted(p.name for p in (tmp_path / "mixed").iterdir()) == ["notes.txt"]
    assert len(list((tmp_path / "kept").iterdir())) == len(files.HEADLINE_FILES)
    assert len(list((tmp_path / "users").iterdir())) == len(files.HEADLINE_FILES)
