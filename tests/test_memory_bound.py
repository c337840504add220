"""Bounded memory: the decision-list beam lists a bounded number of action orders (none once
its work budget is spent, not every ordering of the actions left), the relational learner pairs
at most :data:`ibt.distill.relational.MAX_PAIRED_FEATURES` features (so its columns grow
linearly with the features), and the pipeline finishes under a 3 GB address-space limit on a
1,000-feature task and on a ``Box`` agent given as a callable (``tests.fixtures.wide_and_box``).
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys

import numpy as np
import pytest

from ibt.bt.linear import DEFAULT_WEIGHTS
from ibt.distill.relational import MAX_PAIRED_FEATURES, candidate_map, fit_relational_tree
from ibt.synth.decision_list_search import BEAM_WIDTH, CandidateSearch
from tests.test_hostile_files import ROOT

LIMIT = 3 << 30  # bytes of address space


def _search(answer):
    search = object.__new__(CandidateSearch)
    search.espresso_list = lambda paths, context, order: answer
    return search


def test_the_beam_lists_no_orders_once_its_budget_is_spent():
    # 12 actions: every order of them would be 479,001,600 tuples (the 22 GB of a Box agent)
    assert _search(None)._beam_orders([], (), tuple(range(12))) == []


def test_the_beam_lists_at_most_two_orders_per_prefix_kept():
    orders = _search([((), 0)])._beam_orders([], (), tuple(range(12)))
    assert len(orders) == 2 * BEAM_WIDTH and all(sorted(o) == list(range(12)) for o in orders)


def test_the_relational_candidates_grow_linearly_with_the_features():
    rng = np.random.default_rng(0)
    x = rng.uniform(-1, 1, (2_000, 1_000))
    y = (x[:, 3] + x[:, 700] > 0).astype(int)
    cap = MAX_PAIRED_FEATURES * (MAX_PAIRED_FEATURES - 1) // 2 * len(DEFAULT_WEIGHTS)
    assert len(candidate_map(x).forms) == cap
    tree = fit_relational_tree(x, y, max_leaf_nodes=4)  # the pair the axis tree points to
    assert tree.score(x, y) > 0.95
    small = x[:, :25]  # every catalogue task has at most 25 features: all pairs, as before
    assert len(candidate_map(small).forms) == 25 * 24 // 2 * len(DEFAULT_WEIGHTS)


def _limited() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (LIMIT, LIMIT))


@pytest.mark.slow
@pytest.mark.parametrize("task, agent", [("Wide-v0", "wide_agent"), ("Drift-v0", "box_agent")],
                         ids=["1000-features", "box-callable"])
def test_the_pipeline_runs_under_3_gb(tmp_path, task, agent):
    path = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    ran = subprocess.run(
        [sys.executable, "-m", "ibt", "pipeline", task, "callable", "--agent",
         f"tests.fixtures.wide_and_box:{agent}", "--env-module", "tests.fixtures.wide_and_box",
         "--budget", "smoke", "--quiet", "--jobs", "1", "-o", str(tmp_path / "out")],
        capture_output=True, text=True, cwd=ROOT, timeout=900, preexec_fn=_limited,
        env={**os.environ, "PYTHONPATH": path})
    assert ran.returncode == 0, ran.stderr[-2000:]
    assert "recommended a" in ran.stdout
