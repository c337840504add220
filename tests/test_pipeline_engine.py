"""The pipeline's engine: the anytime ladder (smallest leaf limit first, a stop on the target,
a deadline or a signal), restarts on local cores or a Dask cluster, Box agents (SAC, TD3) and
agents given as ``MODULE:FUNCTION`` callables, all under the smoke budget."""

from __future__ import annotations

import json
import math
import shutil
import sys
from dataclasses import replace
from types import SimpleNamespace

import pytest
from hypothesis import given
from hypothesis import strategies as st

from ibt.cli import main
from ibt.engine import budgets, distil, measure, parallel, refine, search
from ibt.engine.agent import callable_agent, sb3_agent
from ibt.engine.deadline import Deadline
from ibt.engine.keys import tree_key
from ibt.engine.ladder import Settings, bisection, run_ladder
from ibt.pipeline.recommend import choose, parse_budget, recommend
from tests.test_recommend import FILES, _candidate

pytestmark = pytest.mark.skipif(shutil.which("dot") is None, reason="needs graphviz's dot")
TOY_LINE = ("tests.fixtures.toy_line",)  # what a worker process imports to find ToyLine-v0
LINE = ["--env-module", *TOY_LINE]
SMOKE = ["--budget", "smoke", "--quiet"]

AGENT_SOURCE = '''
"""A hand-written agent for ToyLine-v0: step towards the middle."""


def act(obs):
    return 0 if obs[0] > 0.1 else 2 if obs[0] < -0.1 else 1
'''


def _line_agent(agents):
    from ibt.tasks.catalogue import resolve_task

    return sb3_agent(resolve_task("ToyLine-v0"), "ppo", agents / "line.zip")


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


@pytest.mark.parametrize("n_jobs, restarts, rounds, polishes", [
    (1, 3, 1.0, 1.0), (2, 3, 1.5, 1.5), (2, 2, 1.0, 1.0), (4, 3, 1.0, 1.0), (2, 5, 1.0, 1.0)])
def test_a_search_is_expected_to_run_its_first_round_and_its_polishes(n_jobs, restarts,
                                                                      rounds, polishes):
    """The least a search runs under a deadline: its first round (3 restarts on 2 cores share
    them, 1.5 restarts' time; on 1 core, one restart), the polishes of that round's best,
    and the choice episodes scoring both, in one core's episodes."""
    import ibt
    from ibt.tasks.catalogue import resolve_task

    cfg = ibt.config("paper")
    task = resolve_task("LunarLander-v3")
    config = budgets.search_config(cfg, task, 8, 1.0)
    choice = min(search.RESTART_CHOICE_FACTOR * config.selection_episodes, 1_500)
    assert search.search_length(cfg, task, 8, restarts=restarts, scale=1.0, n_jobs=n_jobs) == (
        rounds * config.episodes + polishes * budgets.polish_config(cfg, config).episodes
        + (rounds + polishes) * choice)




def test_ctrl_c_after_the_first_candidate_leaves_a_complete_marked_report(
        agents, tmp_path, monkeypatch, capsys):
    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(refine, "refine", interrupted)
    out = tmp_path / "out"
    argv = ["pipeline", "ToyLine-v0", "ppo", *LINE, "--checkpoint", str(agents / "line.zip"),
            "-o", str(out), *SMOKE]
    assert main(argv) == 130
    assert "stopped by Ctrl-C" in capsys.readouterr().out
    report = (out / "report.md").read_text()
    assert "> **Stopped early** (Ctrl-C)" in report
    assert "Ctrl-C stopped it" in report and "refine axis at 4 leaves" in report
    assert all((out / name).stat().st_size > 0 for name in FILES)


def test_max_nodes_bounds_the_recommendation():
    small, big = _candidate(3, 50.0), _candidate(9, 99.0)
    assert choose([small, big], 0.95) == (big, True)
    assert choose([small, big], 0.95, max_nodes=5) == (small, False)
    with pytest.raises(ValueError, match="no BT of at most 2 nodes"):
        choose([small, big], 0.95, max_nodes=2)


@pytest.mark.parametrize("extra, says", [
    (["--time", "0"], "--time: a duration must be more than 0"),
    (["--time", "soon"], "--time: expected a duration such as 90s"),
    (["--max-nodes", "0"], "--max-nodes"),
    (["--restarts", "1000"], "--restarts"),
    (["--agent", "x.py:act"], "--agent is for algo callable"),
])
def test_new_options_are_checked_in_one_line(agents, tmp_path, capsys, extra, says):
    out = tmp_path / "out"
    argv = ["pipeline", "ToyLine-v0", "ppo", *LINE, "--checkpoint", str(agents / "line.zip"),
            "-o", str(out), *SMOKE, *extra]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert says in err and len(err.splitlines()) == 1
    assert not (out / "report.md").exists()


def test_restarts_on_a_dask_cluster_choose_the_same_bt_as_local_cores(agents, tmp_path,
                                                                     monkeypatch):
    distributed = pytest.importorskip("distributed")
    agent = _line_agent(agents)
    run = dict(budget=parse_budget("smoke"), leaf_limits=(4,), restarts=2, n_jobs=2,
               full=True, progress=False, env_modules=("tests.fixtures.toy_line",))
    local = recommend(agent, cache_dir=tmp_path / "local", **run)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        monkeypatch.setenv("IBT_DASK_SCHEDULER", cluster.scheduler_address)
        remote = recommend(agent, cache_dir=tmp_path / "dask", **run)
    searched = [c for c in local.candidates if c.search is not None]
    assert searched and all(len(c.search.seeds) == 2 for c in searched)
    assert [c.bt.to_json() for c in local.candidates] == [
        c.bt.to_json() for c in remote.candidates]
    assert local.chosen.bt.to_json() == remote.chosen.bt.to_json()


def test_a_callable_agent_gets_the_six_files(tmp_path, capsys):
    (tmp_path / "line_agent.py").write_text(AGENT_SOURCE)
    out = tmp_path / "out"
    spec = f"{tmp_path / 'line_agent.py'}:act"
    assert main(["pipeline", "ToyLine-v0", "callable", "--agent", spec, *LINE, "-o", str(out),
                 *SMOKE, "--leaves", "4"]) == 0
    assert "recommended a" in capsys.readouterr().out
    assert all((out / name).stat().st_size > 0 for name in FILES)
    report = (out / "report.md").read_text()
    assert "callable agent" in report and spec in report


def test_a_callable_agent_is_identified_by_its_source(tmp_path):
    from ibt.tasks.catalogue import import_env_module, resolve_task

    import_env_module("tests.fixtures.toy_line")
    path = tmp_path / "agent.py"
    path.write_text(AGENT_SOURCE)
    first = callable_agent(resolve_task("ToyLine-v0"), f"{path}:act").digest
    path.write_text(AGENT_SOURCE.replace("0.1", "0.3"))
    assert callable_agent(resolve_task("ToyLine-v0"), f"{path}:act").digest != first


# --- Box agents ---------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def thruster(tmp_path_factory):
    """A user's Box task (Thruster-v0) with tiny SAC and TD3 agents (seconds; quality does
    not matter here)."""
    import gymnasium as gym
    from stable_baselines3 import SAC, TD3
    from stable_baselines3.common.logger import Logger

    from tests.test_env_module_box import ENV_SOURCE

    folder = tmp_path_factory.mktemp("thruster")
    (folder / "ibt_user_thruster.py").write_text(ENV_SOURCE)
    sys.path.insert(0, str(folder))
    import ibt_user_thruster  # noqa: F401

    for name, algo, steps, rate in (("sac", SAC, 200, 3e-4), ("td3", TD3, 1000, 3e-3)):
        model = algo("MlpPolicy", gym.make("Thruster-v0"), learning_starts=50, batch_size=32,
                     seed=0, device="cpu", policy_kwargs={"net_arch": [16]},
                     learning_rate=rate)
        model.set_logger(Logger(None, []))  # no empty /tmp/SB3-<date> folder
        model.learn(steps)
        model.save(folder / f"{name}.zip")
    yield folder
    sys.path.remove(str(folder))


@pytest.mark.parametrize("algo", ["sac", "td3"])
def test_a_box_agent_gets_the_six_files_with_named_commands(thruster, tmp_path, algo):
    out = tmp_path / algo
    assert main(["pipeline", "Thruster-v0", algo, "--checkpoint", str(thruster / f"{algo}.zip"),
                 "--env-module", "ibt_user_thruster", "-o", str(out), *SMOKE,
                 "--leaves", "2,4"]) == 0
    assert all((out / name).stat().st_size > 0 for name in FILES)
    doc = json.loads((out / "bt.json").read_text())
    assert doc["commands"]["dimensions"] == ["a0"] or len(doc["commands"]["dimensions"]) == 1
    report = (out / "report.md").read_text()
    assert "structure search is for discrete actions" in report


def test_a_box_ladders_blocks_of_rungs_on_two_cores_give_the_same_steps_and_bts(thruster,
                                                                               tmp_path):
    """Two cores and one learner: rungs 2 and 4 are distilled, then refined, together; the
    steps, their order and the BTs are those of one core."""
    from ibt.tasks.catalogue import resolve_task

    agent = sb3_agent(resolve_task("Thruster-v0"), "sac", thruster / "sac.zip")
    run = dict(budget=parse_budget("smoke"), full=True, leaf_limits=(2, 4), progress=False,
               env_modules=("ibt_user_thruster",))
    one = recommend(agent, cache_dir=tmp_path / "one", n_jobs=1, **run)
    two = recommend(agent, cache_dir=tmp_path / "two", n_jobs=2, **run)
    assert one.ladder.steps == two.ladder.steps == [
        f"{verb} box at {leaves} leaves" for leaves in (2, 4) for verb in ("distil", "refine")]
    assert [c.bt.to_json() for c in one.candidates] == [c.bt.to_json() for c in two.candidates]


def test_a_rungs_learners_distilled_on_two_cores_give_the_same_trees(agents, tmp_path):
    from ibt.tasks.catalogue import resolve_task

    agent = sb3_agent(resolve_task("ToyCart-v0"), "ppo", agents / "cart.zip")
    run = dict(budget=parse_budget("smoke"), keep=1.01, leaf_limits=(4,), restarts=1,
               progress=False, env_modules=("tests.fixtures.toy_cart",))
    one = recommend(agent, cache_dir=tmp_path / "one", n_jobs=1, **run)
    two = recommend(agent, cache_dir=tmp_path / "two", n_jobs=2, **run)
    assert one.ladder.steps[:2] == ["distil axis at 4 leaves", "distil relational at 4 leaves"]
    assert one.ladder.steps == two.ladder.steps
    assert [c.bt.to_json() for c in one.candidates] == [c.bt.to_json() for c in two.candidates]


def test_a_searchs_restarts_stop_between_rounds_and_resume_from_the_cache(agents, tmp_path):
    import ibt

    cfg = ibt.config("smoke", cache_dir=tmp_path, progress=False)
    agent = _line_agent(agents)
    sources = [distil.distil(cfg, agent, 4, 0, "axis")]
    rounds: list[float] = []
    _, cut = search.search(cfg, agent, sources, 4, 0, restarts=3,
                           next_round=lambda seconds: rounds.append(seconds) and False)
    assert cut.seeds == (0,) and len(rounds) == 1 and len(cut.choice_means) == 1
    _, whole = search.search(cfg, agent, sources, 4, 0, restarts=3)
    assert whole.seeds == (0, 1, 2) and whole.choice_means[0] == cut.choice_means[0]
    # time to spare: rounds go on past `restarts` up to `most`; without a deadline they do not
    _, more = search.search(cfg, agent, sources, 4, 0, restarts=3, n_jobs=2, most=5,
                            env_modules=TOY_LINE,
                            next_round=lambda seconds: True, enough=math.inf)
    assert more.seeds == (0, 1, 2, 3, 4) and more.choice_means[:3] == whole.choice_means
    _, capped = search.search(cfg, agent, sources, 4, 0, restarts=3, most=5)
    assert capped.seeds == (0, 1, 2)
    # 3 restarts on 2 cores: one round of 3, not a round of 2 and a round of 1
    rounds.clear()
    _, folded = search.search(cfg, agent, sources, 4, 0, restarts=3, n_jobs=2,
                              env_modules=TOY_LINE,
                              next_round=lambda seconds: rounds.append(seconds) and False)
    assert folded.seeds == (0, 1, 2) and len(rounds) == 1
    # the asked restarts' best are polished, and the choice is made among them, polished
    assert folded.polished == tuple(sorted(folded.seeds, key=lambda s: -folded.choice_means[s]))
    assert folded.seeds[folded.chosen] == folded.polished[
        max(range(3), key=lambda k: folded.polished_means[k])]
    assert (folded.polished, folded.polished_means) == (whole.polished, whole.polished_means)
    assert len(more.polished) == 3 and more.polished[0] == max(
        more.seeds, key=lambda s: more.choice_means[s])
    # ... and stop at the first restart that reached the target, never before the asked
    # restarts, on any number of cores
    for jobs in (1, 2):
        _, reached = search.search(cfg, agent, sources, 4, 0, restarts=3, n_jobs=jobs, most=5,
                                   env_modules=TOY_LINE,
                                   next_round=lambda seconds: True, enough=-math.inf)
        assert reached.seeds == (0, 1, 2)
    second = sorted(more.choice_means)[-2]  # reached first by the best or the second best
    _, reached = search.search(cfg, agent, sources, 4, 0, restarts=1, n_jobs=2, most=5,
                               env_modules=TOY_LINE,
                               next_round=lambda seconds: True, enough=second)
    assert reached.choice_means[-1] >= second > max(reached.choice_means[:-1], default=-1e9)


@pytest.mark.parametrize("n_jobs, items, processes, wall", [
    (2, 3, 3, 1.5), (2, 2, 2, 1.0), (1, 3, 1, 3.0), (2, 4, 2, 2.0), (4, 5, 5, 1.25),
    (4, 9, 4, 3.0), (2, 1, 2, 1.0)])
def test_a_round_of_fewer_than_twice_the_cores_runs_a_process_each(n_jobs, items, processes,
                                                                    wall):
    """3 restarts on 2 cores share them as 3 processes (1.5 rounds' time), not 2 and then 1."""
    assert parallel.processes(n_jobs, items) == processes
    assert parallel.wall(items, n_jobs) == wall


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



def test_the_relational_search_starts_from_the_relational_trees_too(agents, tmp_path,
                                                                     monkeypatch):
    """The relational search's seed trees: the rung's and the largest rung's distilled trees
    of both learners, axis-aligned first (its candidate columns come from the first)."""
    import ibt
    from ibt.distill.relational import feature_map_of
    from ibt.tasks.catalogue import resolve_task

    seeded: list[list] = []
    original = search.search

    def recorded(cfg, agent, sources, *args, **kwargs):
        seeded.append(list(sources))
        return original(cfg, agent, sources, *args, **kwargs)

    monkeypatch.setattr(search, "search", recorded)
    cfg = ibt.config("smoke", cache_dir=tmp_path, progress=False)
    agent = sb3_agent(resolve_task("ToyCart-v0"), "ppo", agents / "cart.zip")
    ladder = run_ladder(cfg, agent, Settings(keep=1.01, rungs=(2, 4), restarts=1),
                        agent_mean=0.0, random_mean=-10.0)
    distilled = {(c.leaf_limit, c.learner): c.tree for c in ladder.candidates
                 if c.stage == "distilled"}
    first = seeded[0]  # the bisection's first probe: rung 2 of (2, 4)
    assert feature_map_of(first[0]) is None  # axis-aligned first
    assert any(feature_map_of(t) is not None for t in first)  # relational ones too
    expected = [distilled[(rung, name)] for name in ("axis", "relational") for rung in (2, 4)]
    assert [tree_key(t) for t in first] == list(dict.fromkeys(
        tree_key(t) for t in expected))
    assert any(c.stage == "searched" for c in ladder.candidates)


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

