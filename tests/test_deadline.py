"""The engine's deadline: a step sure to end past it is not started, one running past
it and its grace is cut, and the pace a first search is foretold by."""

from __future__ import annotations

from dataclasses import replace

from ibt.engine import distil, measure, search
from ibt.engine.deadline import Deadline
from ibt.engine.ladder import Settings, run_ladder
from tests.test_pipeline_engine import _line_agent


def test_a_step_that_would_end_past_the_deadline_is_not_started(agents, tmp_path,
                                                                 monkeypatch):
    import ibt

    now = [0.0]
    original = distil.distil

    def slow_distil(*args, **kwargs):  # each distillation takes 8 s of the fake clock
        now[0] += 8.0
        return original(*args, **kwargs)

    monkeypatch.setattr(distil, "distil", slow_distil)
    cfg = ibt.config("smoke", cache_dir=tmp_path, progress=False)
    ladder = run_ladder(cfg, _line_agent(agents), Settings(keep=1.0, rungs=(4, 8), restarts=1),
                        agent_mean=0.0, random_mean=-10.0,
                        deadline=Deadline(10.0, clock=lambda: now[0]))
    assert ladder.stopped == "time" and ladder.steps == ["distil axis at 4 leaves"]
    assert ladder.skipped[0] == "distil axis at 8 leaves"
    assert 'stopped before "distil axis at 8 leaves"' in ladder.notes[0]


def test_a_step_running_past_the_budget_and_its_grace_is_cut(agents, tmp_path, monkeypatch):
    """A step under way when the budget runs out (a first search, whose length no earlier step
    foretells) is cut once its grace has passed too: the run ends near its budget with what it
    has, marked as stopped by the time budget, nothing of the cut step kept."""
    import time

    import ibt
    from ibt.engine import deadline as deadline_module

    cfg = ibt.config("smoke", cache_dir=tmp_path, progress=False)
    agent = _line_agent(agents)
    distil.distil(cfg, agent, 4, 0, "axis")  # cached: the ladder's first step reads it
    original = distil.distil

    def slow_at_8(cfg, agent, leaves, *args, **kwargs):
        if leaves == 8:
            time.sleep(60)
        return original(cfg, agent, leaves, *args, **kwargs)

    monkeypatch.setattr(distil, "distil", slow_at_8)
    monkeypatch.setattr(deadline_module, "GRACE_MIN", 0.5)
    began = time.monotonic()
    ladder = run_ladder(cfg, agent, Settings(keep=1.0, rungs=(4, 8), restarts=1),
                        agent_mean=0.0, random_mean=-10.0,
                        deadline=Deadline(1.0, clock=lambda: 0.0))  # never passes between steps
    assert time.monotonic() - began < 30
    assert ladder.stopped == "time" and ladder.steps == ["distil axis at 4 leaves"]
    assert ladder.skipped[0] == "distil axis at 8 leaves"
    assert '"distil axis at 8 leaves" was cut 0 s past the time budget' in ladder.notes[-1]
    assert len(list((tmp_path / "distill").glob("*/manifest.json"))) == 1  # nothing of it kept


def test_a_first_search_sure_to_be_cut_is_not_started(agents, tmp_path, monkeypatch):
    """No search has run yet: the least it can take is its episodes, each as long as the
    shorter of the agent's and the measured trees' mean episode, at the seconds a step the run's
    tree measurements took. One sure to run past the budget and its grace is not started; one
    that may fit is, with what it was expected to take in the notes."""
    import ibt
    from ibt.engine import deadline as deadline_module

    cfg = ibt.config("smoke", cache_dir=tmp_path, progress=False)
    agent = _line_agent(agents)
    settings = Settings(keep=1.0, rungs=(4,), restarts=1)
    length = search.search_length(cfg, agent.task, 4, restarts=1, scale=1.0, n_jobs=1)
    original = measure.measure

    def timed_measure(cfg, agent, tree, bts, seeds):  # 10 steps an episode, 0.1 s a step
        return replace(original(cfg, agent, tree, bts, seeds), lengths=[10] * len(seeds),
                       seconds=1.0 * len(seeds))

    monkeypatch.setattr(measure, "measure", timed_measure)
    monkeypatch.setattr(deadline_module, "GRACE_MIN", 0.0)
    least = 10 * 0.1 * length  # 1 s an episode: the real search, seconds, is never cut
    short = run_ladder(cfg, agent, settings, agent_mean=0.0, random_mean=-10.0,
                       deadline=Deadline(least / 1.2, clock=lambda: 0.0))
    assert short.stopped == "time" and short.steps == ["distil axis at 4 leaves"]
    assert short.skipped[0] == "search axis at 4 leaves"
    assert f"at least {least:.0f} s expected: {length:,.0f} episodes of 10 steps at the " \
        "100000 us a step" in short.notes[0], short.notes
    # the agent's episodes are shorter (5 steps): the search may fit, and starts
    ample = run_ladder(cfg, agent, settings, agent_mean=0.0, random_mean=-10.0,
                       deadline=Deadline(least / 1.2, clock=lambda: 0.0), agent_length=5.0)
    assert "search axis at 4 leaves" in ample.steps, ample.notes
    assert any(n.startswith('"search axis at 4 leaves" took') for n in ample.notes)


def test_a_rerun_from_the_cache_times_its_last_tree_for_the_pace(agents, tmp_path,
                                                                 monkeypatch):
    """A rerun that read every measurement from the cache has no timed rollout: its last tree's
    first two choice episodes are rolled out anew (and not cached) for the pace, so a first
    search sure to be cut is still not started."""
    import ibt
    from ibt.engine import deadline as deadline_module

    cfg = ibt.config("smoke", cache_dir=tmp_path, progress=False)
    agent = _line_agent(agents)
    settings = Settings(keep=1.0, rungs=(4,), restarts=1)
    first = run_ladder(cfg, agent, settings, agent_mean=0.0, random_mean=-10.0,
                       on_step=lambda done, step: "enough" if done.steps else None)
    assert first.steps == ["distil axis at 4 leaves"]  # now in the cache
    rolled, calls = measure.rolled, []

    def timed(task, act, seeds):  # 10 steps an episode, 0.1 s a step
        calls.append(seeds)
        return replace(rolled(task, act, seeds), lengths=[10] * len(seeds),
                       seconds=1.0 * len(seeds))

    monkeypatch.setattr(measure, "rolled", timed)
    monkeypatch.setattr(deadline_module, "GRACE_MIN", 0.0)
    length = search.search_length(cfg, agent.task, 4, restarts=1, scale=1.0, n_jobs=1)
    least = 10 * 0.1 * length
    rerun = run_ladder(cfg, agent, settings, agent_mean=0.0, random_mean=-10.0,
                       deadline=Deadline(least / 1.2, clock=lambda: 0.0))
    assert rerun.stopped == "time" and rerun.steps == ["distil axis at 4 leaves"]
    assert calls == [measure.held_out(cfg.final_episodes, 0)[:2]]  # the pace's rollout only
    assert f"at least {least:.0f} s expected" in rerun.notes[0], rerun.notes
