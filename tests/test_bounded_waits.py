"""Every wait has a bound and every stop its true name: a Dask address that never answers fails
within a minute naming ``IBT_DASK_SCHEDULER``; SIGTERM before the first candidate is
"terminated" (143), not "raise --time"; an agent's or an environment's ``sys.exit`` is an error
(exit 2) naming it; the pipeline's baselines and confirmation run under its deadline, whose cap
an environment that swallows exceptions cannot hide (the policy checks it between steps); a
``Discrete(n, start=k)`` environment is refused before any work. Fast: fake clocks, fake
ladders, a silent socket."""

from __future__ import annotations

import socket
import threading
import time

import gymnasium as gym
import numpy as np
import pytest

from ibt.engine import parallel
from ibt.engine.deadline import Deadline
from ibt.engine.ladder import Ladder
from ibt.engine.measure import Returns
from ibt.pipeline import recommend as rec_module
from ibt.signals import OverTime, Terminated, check_time, time_cap
from ibt.tasks.catalogue import get_task

TASK = get_task("CartPole-v1")


@pytest.fixture
def silent_scheduler():
    """A TCP address that accepts connections and never says a word."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    held: list[socket.socket] = []
    stop = threading.Event()

    def accept() -> None:
        server.settimeout(0.2)
        while not stop.is_set():
            try:
                held.append(server.accept()[0])
            except OSError:
                continue

    thread = threading.Thread(target=accept, daemon=True)
    thread.start()
    yield f"tcp://127.0.0.1:{server.getsockname()[1]}"
    stop.set()
    for conn in held:
        conn.close()
    server.close()


def test_a_dask_address_that_never_answers_fails_naming_the_variable(silent_scheduler,
                                                                    monkeypatch):
    pytest.importorskip("dask.distributed")  # imported before the clock starts
    monkeypatch.setenv(parallel.DASK_ENV, silent_scheduler)
    monkeypatch.setattr(parallel, "DASK_TIMEOUT", 2.0)
    began = time.monotonic()
    with pytest.raises(RuntimeError, match=r"IBT_DASK_SCHEDULER=tcp://127\.0\.0\.1:\d+: no "
                                           r"Dask scheduler answered within 2 s"):
        parallel.parallel_map(abs, [(1,), (-2,)], n_jobs=2)
    assert time.monotonic() - began < 20  # the timeout and the thread's 5 s, on a busy machine
    assert parallel.DASK_TIMEOUT <= 60 and parallel.dask_client.__defaults__ == (None,)


def _fake_run(monkeypatch, ladder: Ladder) -> None:
    """``recommend`` with measured baselines and ``ladder`` as the ladder's outcome."""
    def returns_of(cfg, task, what, act, seeds):
        mean = 0.0 if what.get("algo") == "random" else 100.0
        return Returns([mean + i for i in range(len(seeds))], seeds[0], [10] * len(seeds))

    monkeypatch.setattr(rec_module.measure, "returns_of", returns_of)
    monkeypatch.setattr(rec_module, "run_ladder", lambda *a, **k: ladder)


def _agent():
    from ibt.engine.agent import Agent

    return Agent(TASK, "ppo", "agent.zip", "0" * 16)


@pytest.mark.parametrize("stopped, raised", [("terminated", Terminated),
                                             ("interrupted", KeyboardInterrupt)])
def test_a_stop_before_the_first_candidate_keeps_its_name(tmp_path, monkeypatch, stopped,
                                                          raised):
    _fake_run(monkeypatch, Ladder(stopped=stopped))
    with pytest.raises(raised):
        rec_module.recommend(_agent(), cache_dir=tmp_path, progress=False, budget=None)


def test_the_ladder_keeps_back_time_for_the_confirmation(tmp_path, monkeypatch):
    seen: dict[str, Deadline] = {}
    _fake_run(monkeypatch, Ladder(stopped="time"))

    def run_ladder(*args, deadline, **kwargs):
        seen["deadline"] = deadline
        return Ladder(stopped="time")

    monkeypatch.setattr(rec_module, "run_ladder", run_ladder)
    with pytest.raises(ValueError, match="raise --time"):
        rec_module.recommend(_agent(), cache_dir=tmp_path, progress=False, time_limit=60.0)
    inner = seen["deadline"]
    assert inner.seconds is not None and inner.seconds <= 60.0 and inner.grace() == 60.0


def test_a_reserved_deadline_shares_the_start_and_the_grace():
    now = [100.0]
    outer = Deadline(600.0, clock=lambda: now[0])
    now[0] = 130.0
    inner = outer.reserving(40.0)
    assert inner.seconds == 560.0 and inner.start == 100.0 and inner.elapsed() == 30.0
    assert inner.grace() == outer.grace() == 60.0
    assert Deadline(None).reserving(5.0).seconds is None


def test_baselines_past_the_deadline_and_its_grace_are_cut():
    deadline = Deadline(0.01)
    deadline._grace = 0.2  # as a budget whose grace has run out
    began = time.monotonic()
    with pytest.raises(ValueError, match="ran out while measuring the agent"):
        with rec_module.within(deadline, "measuring the agent and the random policy"):
            time.sleep(5)
    assert time.monotonic() - began < 2


def _swallowing_step() -> None:
    """An environment's step that wraps its work in a bare ``except:``."""
    try:
        time.sleep(0.05)
    except BaseException:  # the hostile environment's own code
        pass


def test_an_environment_that_swallows_exceptions_cannot_hide_the_cap():
    act = rec_module.checked(lambda: (lambda obs: 0))()
    began = time.monotonic()
    with pytest.raises(OverTime), time_cap(0.2):
        while time.monotonic() - began < 5:  # a rollout: the policy acts, the env steps
            act(None)
            _swallowing_step()
    assert time.monotonic() - began < 1.5
    check_time()  # outside the cap nothing is raised


def test_an_agent_that_calls_sys_exit_is_an_error_naming_it():
    from ibt.experts.callable_agent import CallableExpert

    def quitter(obs):
        raise SystemExit(0)

    agent = CallableExpert(TASK, "quitter.py:act", quitter)
    with pytest.raises(ValueError, match=r"agent 'quitter\.py:act': the agent on observation 0 "
                                         r"raised SystemExit: 0; an agent answers"):
        agent.act(np.zeros((1, 4)))


def test_an_environment_that_calls_sys_exit_gives_exit_2_naming_it(tmp_path, monkeypatch,
                                                                   capsys):
    from ibt.cli import main
    from ibt.pipeline import recommend

    def exits(*args, **kwargs):
        raise SystemExit(0)

    monkeypatch.setattr(recommend, "recommend", exits)
    code = main(["pipeline", "CartPole-v1", "ppo", "--budget", "smoke", "--quiet",
                 "-o", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert "environment of CartPole-v1 (or code it runs) called sys.exit(0)" in err[0]
    assert not (tmp_path / "out" / ".ibt-pipeline.json").exists()


class _StartsAtOne(gym.Env):
    def __init__(self) -> None:
        self.observation_space = gym.spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float32)
        self.action_space = gym.spaces.Discrete(2, start=1)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        return np.zeros(2, dtype=np.float32), {}

    def step(self, action):
        assert self.action_space.contains(action)
        return np.zeros(2, dtype=np.float32), 1.0, False, True, {}


def test_actions_numbered_from_one_are_refused_before_any_work(tmp_path, capsys):
    from ibt.cli import main

    if "StartsAtOne-v0" not in gym.registry:
        gym.register(id="StartsAtOne-v0", entry_point=_StartsAtOne, max_episode_steps=5)
    code = main(["pipeline", "StartsAtOne-v0", "callable", "--agent", "x.py:act",
                 "--budget", "smoke", "-o", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert "numbers its actions from 1 (Discrete(2, start=1))" in err[0]
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_a_slow_agent_ends_within_the_time_and_its_grace(tmp_path):
    """50 ms a step: the agent's baseline alone would take minutes; ``--time 20s`` ends by its
    grace (60 s), plus the process's start."""
    from ibt.engine.deadline import GRACE_MIN
    from tests.test_hostile_files import cli

    began = time.monotonic()
    ran = cli(["pipeline", "CartPole-v1", "callable", "--agent",
               "tests.fixtures.hostile_exits:slow_pilot", "--budget", "smoke", "--quiet",
               "--jobs", "1", "--time", "20s", "-o", str(tmp_path / "out")], timeout=600)
    wall = time.monotonic() - began
    assert ran.returncode in (0, 2), ran.stderr
    if ran.returncode == 2:
        assert "raise --time" in ran.stderr and len(ran.stderr.splitlines()) == 1
    assert wall < 20 + GRACE_MIN + 60, wall  # 60 s for the imports on a busy machine
