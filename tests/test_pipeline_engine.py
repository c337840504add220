"""The pipeline's engine: the anytime ladder (smallest leaf limit first, a stop on the target,
a deadline or a signal), restarts on local cores or a Dask cluster, Box agents (SAC, TD3) and
agents given as ``MODULE:FUNCTION`` callables, all under the smoke budget."""

from __future__ import annotations

import json
import math
import shutil
import sys

import pytest

from ibt.cli import main
from ibt.engine import distil, refine, search
from ibt.engine.agent import callable_agent, sb3_agent
from ibt.engine.keys import tree_key
from ibt.engine.ladder import Settings, run_ladder
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
    """Two cores and a Box task's learners: rungs 2 and 4 are distilled, then refined,
    together; the steps, their order and the BTs are those of one core."""
    from ibt.tasks.catalogue import resolve_task

    agent = sb3_agent(resolve_task("Thruster-v0"), "sac", thruster / "sac.zip")
    run = dict(budget=parse_budget("smoke"), full=True, leaf_limits=(2, 4), progress=False,
               env_modules=("ibt_user_thruster",))
    one = recommend(agent, cache_dir=tmp_path / "one", n_jobs=1, **run)
    two = recommend(agent, cache_dir=tmp_path / "two", n_jobs=2, **run)
    assert one.ladder.steps == two.ladder.steps
    for verb in ("distil", "refine"):  # each rung's learners, the registry's order
        done = [s for s in one.ladder.steps if s.startswith(verb)]
        assert done == [f"{verb} {learner} at {leaves} leaves" for leaves in (2, 4)
                        for learner in ("box", "controller")], one.ladder.steps
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


@pytest.mark.slow
def test_the_trees_that_kept_the_target_refined_on_two_cores_give_the_same_bts(agents,
                                                                             tmp_path):
    """Every learner's tree keeps a low target at the first rung: the refinements that follow
    run alongside on two cores (the first step refines both); the same steps and BTs as one
    core's, one after the other."""
    from ibt.tasks.catalogue import resolve_task

    agent = sb3_agent(resolve_task("ToyCart-v0"), "ppo", agents / "cart.zip")
    run = dict(budget=parse_budget("smoke"), keep=0.01, leaf_limits=(4,), restarts=1,
               progress=False, env_modules=("tests.fixtures.toy_cart",))
    one = recommend(agent, cache_dir=tmp_path / "one", n_jobs=1, **run)
    two = recommend(agent, cache_dir=tmp_path / "two", n_jobs=2, **run)
    refined = [s for s in one.ladder.steps if s.startswith("refine")]
    assert len(refined) >= 2, one.ladder.steps
    assert one.ladder.steps == two.ladder.steps
    assert [c.bt.to_json() for c in one.candidates] == [c.bt.to_json() for c in two.candidates]
    entries = [sorted(str(e.relative_to(c)) for e in c.glob("*/*")) for c in
               (tmp_path / "one", tmp_path / "two")]
    assert entries[0] == entries[1]  # the workers refined the same trees, no other


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


