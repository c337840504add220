"""The anytime ladder of the pipeline's engine: the smallest leaf limit first, the
bisection of the rungs, a stop on the target or between steps, the spare time of its
last step (extra restarts, polishing again)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
from hypothesis import given
from hypothesis import strategies as st

from ibt.engine import search
from ibt.engine.deadline import Deadline
from ibt.engine.ladder import Settings, bisection, run_ladder
from ibt.pipeline.recommend import parse_budget, recommend
from tests.test_pipeline_engine import _line_agent


def test_the_ladder_stops_at_the_first_limit_that_keeps_the_target(agents, tmp_path):
    rec = recommend(_line_agent(agents), budget=parse_budget("smoke"), keep=0.01,
                    leaf_limits=(16, 4, 8), cache_dir=tmp_path, progress=False)
    assert rec.ladder.steps == ["distil axis at 4 leaves", "refine axis at 4 leaves"]
    assert rec.stopped is None and rec.met_on_choice
    assert {c.leaf_limit for c in rec.candidates} == {4}


def test_a_stop_between_steps_keeps_what_was_done(agents, tmp_path):
    import ibt

    cfg = ibt.config("smoke", cache_dir=tmp_path, progress=False)
    agent = _line_agent(agents)
    settings = Settings(keep=1.0, rungs=(4, 8), restarts=1)
    ladder = run_ladder(cfg, agent, settings, agent_mean=0.0, random_mean=-10.0,
                        on_step=lambda done, step: "enough" if done.steps else None)
    assert ladder.stopped == "enough" and ladder.steps == ["distil axis at 4 leaves"]
    assert "distil axis at 8 leaves" in ladder.skipped and len(ladder.candidates) == 1
    ticks = iter([0.0, 5.0])  # the deadline passes before the first step
    late = run_ladder(cfg, agent, settings, agent_mean=0.0, random_mean=-10.0,
                      deadline=Deadline(1.0, clock=lambda: next(ticks, 5.0)))
    assert late.stopped == "time" and late.candidates == []


@given(st.lists(st.integers(1, 10_000), min_size=1, max_size=12, unique=True),
       st.integers(0, 12))
def test_the_searches_bisect_the_rungs_for_the_smallest_that_keeps(rungs, first_kept):
    """Where keeping the target is monotone in the leaf limit, the probes find the smallest
    rung that keeps it (none: every probe failed) in at most ceil(log2(n + 1)) searches."""
    rungs = sorted(rungs)
    kept = set(rungs[first_kept:])
    probed: list[tuple[int, bool]] = []
    bisection(rungs, lambda r, last: probed.append((r, last)) or r in kept)
    assert len(probed) <= math.ceil(math.log2(len(rungs) + 1))
    assert min(kept & {r for r, _ in probed}, default=None) == min(kept, default=None)
    # "last" is said of the final probe only, and always where that probe failed
    assert not any(last for _, last in probed[:-1])
    final, last = probed[-1]
    assert last or final in kept


@pytest.mark.parametrize("seconds, rungs, most", [(3600.0, (4,), 8), (None, (4,), None),
                                                   (3600.0, (4, 8), None)])
def test_only_the_ladders_last_step_spends_spare_time_on_restarts(agents, tmp_path, monkeypatch,
                                                                  seconds, rungs, most):
    """The bisection's last search, with a deadline and nothing after it, may run up to
    ``EXTRA_RESTARTS`` times the restarts; a search with a probe after it may not."""
    import ibt

    asked: list[int | None] = []
    original = search.search

    def recorded(*args, **kwargs):
        asked.append(kwargs.pop("most"))
        enough = kwargs.pop("enough")
        assert (enough is None) == (asked[-1] is None)  # extra restarts stop at the target
        return original(*args, **kwargs)

    monkeypatch.setattr(search, "search", recorded)
    cfg = ibt.config("smoke", cache_dir=tmp_path, progress=False)
    run_ladder(cfg, _line_agent(agents), Settings(keep=1.01, rungs=rungs, restarts=2,
                                                  relational=False),
               agent_mean=0.0, random_mean=-10.0, deadline=Deadline(seconds))
    assert asked[0] == most


def test_the_restarts_help_states_the_ladders_extra_restarts(capsys):
    from ibt.cli import build_parser
    from ibt.engine.ladder import EXTRA_RESTARTS

    with pytest.raises(SystemExit):
        build_parser().parse_args(["pipeline", "--help"])
    assert f"up to {EXTRA_RESTARTS}K" in " ".join(capsys.readouterr().out.split())


def test_time_left_over_polishes_again_the_searched_bt_nearest_the_target(agents, tmp_path):
    """The ladder done with time left and no BT keeping the target: the searched BT is polished
    again from the seeds after the search's restarts, kept only where that beat it on the
    search's choice episodes, at most ``AGAIN_ROUNDS`` times; without a deadline, never."""
    import ibt
    from ibt.engine import polish
    from ibt.pipeline.outputs import ladder_text

    cfg = ibt.config("smoke", cache_dir=tmp_path, progress=False)
    agent = _line_agent(agents)
    settings = Settings(keep=1.0, rungs=(4,), restarts=1)
    bare = run_ladder(cfg, agent, settings, agent_mean=0.0, random_mean=-10.0)
    assert bare.steps == ["distil axis at 4 leaves", "search axis at 4 leaves"]
    ladder = run_ladder(cfg, agent, settings, agent_mean=0.0, random_mean=-10.0,
                        deadline=Deadline(3600.0))
    again = ladder.steps[2:]
    assert ladder.steps[:2] == bare.steps and 1 <= len(again) <= polish.AGAIN_ROUNDS
    assert set(again) == {"polish again axis at 4 leaves"} and ladder.stopped is None
    notes = [n for n in ladder.notes if n.startswith("polished again")]
    searched = next(c for c in ladder.candidates if c.stage == "searched")
    after = searched.search.seeds[-1] + 1  # the seeds after the search's restarts
    assert notes[0].startswith(f"polished again at leaf limit 4 from seeds [{after}]: "), notes
    polished = [c for c in ladder.candidates if c.stage == "polished"]
    assert len(polished) == sum(n.endswith("the best kept") for n in notes)
    assert len(notes) == len(again) and (len(again) == polish.AGAIN_ROUNDS
                                         or notes[-1].endswith("none kept"))
    said = "\n".join(ladder_text(SimpleNamespace(ladder=ladder, time_limit=3600.0, elapsed=1.0,
                                                 candidates=ladder.candidates, max_nodes=None)))
    assert "With time left over, the searched BT nearest the target" in said
    assert f"Note: {notes[0]}." in said
