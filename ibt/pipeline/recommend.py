"""One command from an agent to a recommended BT: ``python -m ibt pipeline TASK ALGO``.

The product side of the engine (:mod:`ibt.engine`): for a user's agent (an SB3 checkpoint,
discrete or Box, or a ``MODULE:FUNCTION`` callable) it climbs the anytime ladder
(:func:`ibt.engine.ladder.run_ladder`: distil at increasing leaf limits, axis-aligned
and relational trees at the same limit, up to the first limit that keeps the target; the
structure search with restarts below it, by bisection; then refine that limit's trees that kept
the target where no smaller limit did), turns every tree into every registered synthesiser's
verified BT and recommends the smallest BT that keeps ``keep`` of the agent's random-normalised
return (or, when none does, the one that keeps most). Every step is cached
(:func:`ibt.cache.store.load_or_compute`, keyed on the agent's digest), so raising the time, the
budget or the leaf limits reruns only what changed; a deadline, Ctrl-C or SIGTERM ends the
ladder between (or inside) steps with the best candidate found so far, marked as stopped.

A relational candidate is recommended only where its BT is strictly smaller than every
axis-aligned one that keeps the target (ties go to the axis-aligned BT, easier to read).

Two sets of held-out episodes, disjoint from the distillation's training and selection episodes
and from refinement's and the search's: the *choice* episodes (the final-evaluation seeds,
:func:`ibt.evaluate.rollouts.final_seeds`) place every candidate on the front and choose the
recommendation; the *confirmation* episodes (the next block of final seeds) then measure the
chosen BT, the agent and the uniform random policy afresh, so the reported retention is not the
maximum of many noisy scores. Files are written by :mod:`ibt.pipeline.outputs`.
"""

from __future__ import annotations

import contextlib
import math
import re
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from ibt.engine import measure
from ibt.engine.agent import RANDOM_SEED, Agent
from ibt.engine.deadline import Deadline
from ibt.engine.keys import bt_digest
from ibt.engine.ladder import Candidate, Ladder, Settings, eligible, run_ladder
from ibt.engine.measure import Returns, held_out
from ibt.engine.plan import Replay
from ibt.evaluate.policies import BTPolicy
from ibt.evaluate.rollouts import retention_norm
from ibt.profiles import Config
from ibt.signals import OverTime, Terminated, check_time, time_cap
from ibt.tasks.task import Task

__all__ = ["DEFAULT_KEEP", "LEAF_LIMITS", "RANDOM_SEED", "Agreement", "Budget", "Candidate",
           "Recommendation", "Returns", "as_facts", "bt_digest", "choose", "held_out",
           "measure_agreement", "most_faithful", "parse_budget", "recommend"]

LEAF_LIMITS = (4, 8, 16, 32)
DEFAULT_KEEP = 0.95
DEFAULT_TIME = 600.0  #: seconds: a coffee break on a small task
DEFAULT_RESTARTS = 3  #: structure-search restarts chosen among on held-out episodes


@dataclass(frozen=True)
class Budget:
    """How much work the pipeline may do: ``smoke`` (CI: seconds), a ``scale`` of the default
    budget (``2x``), or a number of refinement ``episodes`` per leaf limit."""

    text: str = "1x"
    smoke: bool = False
    scale: float = 1.0
    refine_episodes: int | None = None

    @property
    def profile(self) -> str:
        return "smoke" if self.smoke else "paper"


def parse_budget(text: str) -> Budget:
    """``smoke``, ``SCALEx`` (e.g. ``2x``, ``0.5x``) or an integer number of refinement
    episodes per leaf limit (e.g. ``40000``); ``ValueError`` in one line otherwise."""
    text = text.strip().lower()
    if text == "smoke":
        return Budget("smoke", smoke=True)
    scale = re.fullmatch(r"(\d+(?:\.\d+)?)x", text)
    if scale and 0 < float(scale.group(1)) <= 1000:
        return Budget(text, scale=float(scale.group(1)))
    if text.isdigit() and int(text) >= 10:
        return Budget(text, refine_episodes=int(text))
    raise ValueError(f"--budget {text!r}: expected smoke, a scale such as 2x, or refinement "
                     "episodes per leaf limit such as 40000")


@dataclass
class Recommendation:
    """What the pipeline found: the front, the chosen candidate, and the confirmation."""

    task: Task
    algo: str
    checkpoint: Path
    checkpoint_sha256: str
    keep: float
    budget: Budget
    leaf_limits: tuple[int, ...]
    seed: int
    episodes: int  # per set of held-out episodes
    candidates: list[Candidate]
    chosen: Candidate
    met_on_choice: bool  # some candidate kept `keep` on the choice episodes
    agent: Returns  # confirmation episodes, as the two below
    bt: Returns
    random: Returns
    agent_choice: float  # the agent's and the random policy's mean on the choice episodes
    random_choice: float
    argv: list[str] = field(default_factory=list)
    env_modules: tuple[str, ...] = ()
    cache_dir: Path | None = None
    ladder: Ladder = field(default_factory=Ladder)  # steps done, why it stopped, what was left
    time_limit: float | None = None  # seconds
    elapsed: float = 0.0  # seconds the ladder ran
    max_nodes: int | None = None
    restarts: int = 1
    replayed: str | None = None  # the plan file this run replayed (ibt.engine.plan), if any
    agreement: Agreement | None = None  # every candidate's action agreement with the agent

    @property
    def time_stop(self) -> str:
        """Why a run stopped by its time budget did: the budget ran out, or what was left of it
        would not cover the next step (the ladder stops there, well before the budget's end,
        rather than start a step it would have to cut)."""
        if self.time_limit is not None and self.elapsed < 0.95 * self.time_limit:
            return (f"what was left of its --time budget ({self.time_limit - self.elapsed:.0f} "
                    "s) would not cover the next step")
        return "its --time budget ran out"

    @property
    def faithful(self) -> Candidate:
        """The candidate whose BT agrees most with the agent (:func:`most_faithful`); the
        chosen one where agreement was not measured."""
        if self.agreement is None:
            return self.chosen
        return most_faithful(self.candidates, self.agreement.shares)

    def agreement_of(self, candidate: Candidate) -> float | None:
        """``candidate``'s share of agreement with the agent (None: not measured)."""
        if self.agreement is None:
            return None
        at = next(i for i, c in enumerate(self.candidates) if c is candidate)  # not by value
        return self.agreement.shares[at]

    @property
    def stopped(self) -> str | None:
        """Why the ladder ended before its last step (``time``, ``interrupted``), or None."""
        return self.ladder.stopped

    @property
    def retention(self) -> float:
        """The chosen BT's random-normalised retention (%) on the confirmation episodes."""
        return retention_norm(self.bt.mean, self.agent.mean, self.random.mean)

    @property
    def met(self) -> bool:
        return self.met_on_choice and self.retention >= 100 * self.keep


AGREEMENT_STATES = 20_000  #: at most this many of the agent's visited states are compared
BOX_TOLERANCE = 0.05  #: a Box action agrees within this share of each dimension's range


@dataclass(frozen=True)
class Agreement:
    """How often each candidate's BT sends the agent's action on the states the agent visits
    in the confirmation episodes (held out from every step of the search): ``shares[i]`` is
    candidate ``i``'s; ``random`` the uniform random policy's, for scale. On a Box task an
    action agrees when every dimension is within :data:`BOX_TOLERANCE` of its range of the
    agent's (both clipped to the Box)."""

    shares: list[float]
    random: float
    states: int
    episodes: int
    tolerance: float | None = None  # Box tasks: the share of each dimension's range


def visited_states(task: Task, act: Any, seeds: list[int], limit: int = AGREEMENT_STATES
                   ) -> tuple[np.ndarray, np.ndarray, int]:
    """The observations the policy ``act`` visits on ``seeds`` (whole episodes, started while
    fewer than ``limit`` states were seen, then cut at ``limit``), its actions there, and the
    episodes they come from."""
    from ibt.evaluate.rollouts import rollout

    seen: list[np.ndarray] = []
    sent: list[np.ndarray] = []

    def record(obs: np.ndarray, actions: np.ndarray) -> None:
        seen.append(np.array(obs))
        sent.append(np.array(actions))

    done = rollout(task, act, seeds, budget=limit, on_step=record)
    return np.concatenate(seen)[:limit], np.concatenate(sent)[:limit], len(done.returns)


def agreement_share(task: Task, agent_actions: np.ndarray, actions: np.ndarray) -> float:
    """The share of rows where ``actions`` are the agent's: equal indices, or on a Box task
    every dimension within :data:`BOX_TOLERANCE` of its range (both clipped to the Box)."""
    if not task.continuous:
        return float(np.mean(np.asarray(actions).reshape(-1) ==
                             np.asarray(agent_actions).reshape(-1)))
    low, high = np.asarray(task.action_low), np.asarray(task.action_high)
    a = np.clip(np.asarray(agent_actions, dtype=np.float64).reshape(-1, len(low)), low, high)
    b = np.clip(np.asarray(actions, dtype=np.float64).reshape(-1, len(low)), low, high)
    return float(np.mean((np.abs(a - b) <= BOX_TOLERANCE * (high - low)).all(axis=1)))


def measure_agreement(agent: Agent, candidates: list[Candidate], seeds: list[int]
                      ) -> Agreement:
    """Every candidate's :class:`Agreement` with ``agent`` on the states it visits on
    ``seeds`` (each candidate through its smallest BT: all of a tree's BTs decide alike)."""
    task = agent.task
    obs, agent_actions, episodes = visited_states(task, checked(lambda: agent.load().act)(),
                                                  seeds)
    shares = [agreement_share(task, agent_actions, bt_policy(task, c.bt)(obs))
              for c in candidates]
    random = agreement_share(task, agent_actions, agent.random_act()(obs))
    return Agreement(shares, random, len(obs), episodes,
                     BOX_TOLERANCE if task.continuous else None)


def most_faithful(candidates: list[Candidate], shares: list[float]) -> Candidate:
    """The candidate of highest agreement (ties: fewer BT nodes, higher retention, the
    simpler learner, the earlier)."""
    best = max(range(len(candidates)), key=lambda i: (
        shares[i], -candidates[i].bt_nodes, candidates[i].retention, -candidates[i].rank, -i))
    return candidates[best]


def bt_policy(task: Task, bt: Any) -> Callable[[np.ndarray], np.ndarray]:
    """``act`` of a BT on raw observations: action indices, or a Box task's command vectors."""
    if task.continuous:
        from ibt.synth.commands import CommandBTPolicy

        return CommandBTPolicy(task, bt).act
    return BTPolicy(task, bt).act


def pipeline_config(budget: Budget, cache_dir: Path, episodes: int | None, progress: bool
                    ) -> Config:
    """The run configuration: the ``paper`` (or ``smoke``) profile's budgets, scaled, with the
    cache in ``cache_dir``."""
    import ibt

    cfg = ibt.config(budget.profile, cache_dir=cache_dir, progress=progress)
    changes: dict[str, Any] = {"labels_scale": cfg.labels_scale * budget.scale}
    if episodes is not None:
        changes["final_episodes"] = episodes
    return replace(cfg, **changes)


def choose(candidates: list[Candidate], keep: float, max_nodes: int | None = None
           ) -> tuple[Candidate, bool]:
    """The smallest BT keeping ``keep`` (ties: the simpler learner, the registry's order:
    axis-aligned first; then higher retention), else the best retention (ties: fewer nodes,
    then the simpler learner); and whether the target was met.
    Only BTs of at most ``max_nodes`` nodes count; ``ValueError`` when there is none."""
    pool = [c for c in candidates if max_nodes is None or c.bt_nodes <= max_nodes]
    if not pool:
        smallest = min((c.bt_nodes for c in candidates), default=None)
        raise ValueError(f"no BT of at most {max_nodes} nodes was found (the smallest has "
                         f"{smallest}); raise --max-nodes or give more --time")
    meeting = [c for c in pool if c.retention >= 100 * keep]
    if meeting:
        return min(meeting, key=lambda c: (c.bt_nodes, c.rank, -c.retention)), True
    return max(pool, key=lambda c: (c.retention, -c.bt_nodes, -c.rank)), False


class DegenerateAgent(ValueError):
    """The agent does no better than the uniform random policy: nothing worth distilling."""


def agent_lead(agent: Returns, random: Returns, task: Task) -> str | None:
    """``DegenerateAgent`` where the agent's returns are the random policy's (to the last
    digit: retention would divide by nothing); a warning for the report where its lead is
    within two standard errors (retention is then mostly noise); None otherwise."""
    a, r = np.asarray(agent.returns), np.asarray(random.returns)
    lead = float(a.mean() - r.mean())
    said = (f"the agent's mean return on {task.name} is {a.mean():.2f} against the random "
            f"policy's {r.mean():.2f} over {len(a)} held-out episodes")
    if lead <= 1e-9 * max(1.0, abs(float(r.mean()))):
        raise DegenerateAgent(f"{said}: it does no better than the random policy, so there is "
                              "nothing to distil; train it longer or check that its reward "
                              "depends on its actions")
    noise = 2 * math.sqrt(a.var() / len(a) + r.var() / len(r))
    if lead <= noise:
        return (f"{said}, a lead within two standard errors ({noise:.2f}): retention "
                "figures are mostly noise; use more `--episodes` or a better-trained agent")
    return None


def recommend(agent: Agent, *, keep: float = DEFAULT_KEEP, budget: Budget | None = None,
              leaf_limits: tuple[int, ...] = LEAF_LIMITS, seed: int = 0,
              episodes: int | None = None, cache_dir: str | Path, progress: bool = True,
              argv: list[str] | None = None, env_modules: tuple[str, ...] = (),
              relational: bool = True, time_limit: float | None = DEFAULT_TIME,
              max_nodes: int | None = None, restarts: int = DEFAULT_RESTARTS,
              n_jobs: int = 1, full: bool = False, search: bool = True,
              replay: Replay | None = None) -> Recommendation:
    """Climb the ladder for ``agent`` within ``time_limit`` seconds; the recommended BT (among
    those of at most ``max_nodes`` nodes) and everything measured. ``replay``: a plan's steps
    (:mod:`ibt.engine.plan`) instead, every one and nothing else, with no time limit."""
    budget = budget or Budget()
    task = agent.task
    cfg = pipeline_config(budget, Path(cache_dir), episodes, progress)
    quiet = replace(cfg, progress=False)
    time_limit = None if replay is not None else time_limit
    deadline = Deadline(time_limit)
    choice, confirm = held_out(cfg.final_episodes, 0), held_out(cfg.final_episodes, 1)
    agent_key = {"algo": agent.algo, "expert_sha256": agent.digest}  # measure.agent_returns'
    random_key = {"algo": "random", "policy": "uniform", "rng_seed": RANDOM_SEED}  # and random's
    with within(deadline, "measuring the agent and the random policy"):
        agent_choice = measure.returns_of(quiet, task, agent_key,
                                          checked(lambda: agent.load().act), choice)
        random_choice = measure.returns_of(quiet, task, random_key, checked(agent.random_act),
                                           choice)
    baselines = deadline.elapsed()  # the confirmation measures them again, and the BT
    warning = agent_lead(agent_choice, random_choice, task)
    settings = Settings(keep, tuple(sorted(set(leaf_limits))), seed, relational, restarts,
                        n_jobs, budget.scale, budget.refine_episodes, max_nodes,
                        search=search, env_modules=tuple(env_modules), full=full)
    bar = tqdm(desc=f"pipeline {task.name}/{agent.algo}", unit="step", disable=not progress,
               bar_format="{desc}: {n_fmt} steps [{elapsed}] {postfix}")

    def on_step(ladder: Ladder, name: str) -> None:
        best = [c for c in ladder.candidates if eligible(c, settings)]
        shown = ""
        if best:
            top, met = choose(best, keep)
            below = "" if met else " (below target)"
            shown = f"best {top.bt_nodes} nodes at {top.retention:.1f} %{below}; "
        bar.set_postfix_str(f"{shown}now: {name}")
        bar.update(1 if ladder.steps else 0)

    lengths = agent_choice.lengths
    with ticking(bar):
        ladder = run_ladder(cfg, agent, settings, agent_mean=agent_choice.mean,
                            random_mean=random_choice.mean,
                            deadline=deadline.reserving(CONFIRMATION_RESERVE * baselines),
                            on_step=on_step, replay=replay,
                            agent_length=sum(lengths) / len(lengths) if lengths else None)
    if warning:
        ladder.notes.insert(0, warning)
    from ibt.distill.relational import MAX_PAIRED_FEATURES

    if relational and len(task.feature_names) > MAX_PAIRED_FEATURES:
        ladder.notes.append(
            f"{task.name} has {len(task.feature_names):,} features: the relational trees "
            f"test pairs among at most {MAX_PAIRED_FEATURES} of them (in distillation those an "
            "axis-aligned tree on the same labels uses most; in the structure search the "
            "first by index), so that memory grows linearly with the features")
    bar.close()
    elapsed = deadline.elapsed()
    if not ladder.candidates:
        if ladder.stopped in ("interrupted", "terminated"):
            raise KeyboardInterrupt if ladder.stopped == "interrupted" else Terminated
        raise ValueError("no candidate was finished in the time given: raise --time")
    chosen, met = choose(ladder.candidates, keep, max_nodes)
    bt = chosen.bt
    with within(deadline, "confirming the recommended BT"):
        confirmed = (
            measure.returns_of(quiet, task, agent_key, checked(lambda: agent.load().act),
                               confirm),
            measure.returns_of(quiet, task, {"bt": bt_digest(bt)},
                               checked(lambda: bt_policy(task, bt)), confirm),
            measure.returns_of(quiet, task, random_key, checked(agent.random_act), confirm))
    with within(deadline, "measuring every BT's agreement with the agent"):
        agreement = measure_agreement(agent, ladder.candidates, confirm)
    return Recommendation(
        task, agent.algo, Path(agent.source), agent.digest, keep, budget, settings.rungs, seed,
        cfg.final_episodes, ladder.candidates, chosen, met,
        agent=confirmed[0], bt=confirmed[1], random=confirmed[2],
        agent_choice=agent_choice.mean, random_choice=random_choice.mean,
        argv=list(argv or []), env_modules=tuple(env_modules), cache_dir=Path(cache_dir),
        ladder=ladder, time_limit=time_limit, elapsed=elapsed, max_nodes=max_nodes,
        restarts=restarts, agreement=agreement,
        replayed=replay.source if replay is not None else None)


TICK = 1.0  #: seconds between redraws of the pipeline's bar while a step runs


@contextlib.contextmanager
def ticking(bar: Any, every: float = TICK) -> Iterator[None]:
    """Redraw ``bar`` every ``every`` seconds while the block runs, so its clock goes on
    during a long step (a distillation on other cores shows no bar of its own); nothing for a
    disabled bar."""
    if bar.disable:
        yield
        return
    import threading

    done = threading.Event()

    def tick() -> None:
        while not done.wait(every):
            bar.refresh()

    thread = threading.Thread(target=tick, name="pipeline-bar", daemon=True)
    thread.start()
    try:
        yield
    finally:
        done.set()
        thread.join()


#: the ladder's budget keeps back this many times the baselines' time for the confirmation (the
#: agent and the random policy again, and the BT, on as many episodes)
CONFIRMATION_RESERVE = 2.0


@contextlib.contextmanager
def within(deadline: Deadline, doing: str) -> Iterator[None]:
    """The block ends by the deadline and its grace (:func:`ibt.signals.time_cap`), else a
    ``ValueError`` saying what it was ``doing`` (every finished measurement is cached)."""
    try:
        with time_cap(deadline.left() + deadline.grace()):
            yield
    except OverTime:
        raise ValueError(f"--time {deadline.seconds:.0f}s and its grace of "
                         f"{deadline.grace():.0f} s ran out while {doing}: raise --time (every "
                         "finished step is cached, so a rerun resumes)") from None


def checked(make: Callable[[], Callable[..., Any]]) -> Callable[[], Callable[..., Any]]:
    """A factory of ``make()``'s policy that first checks the run's time cap
    (:func:`ibt.signals.check_time`): a policy acts between the environment's steps, where an
    environment that swallows exceptions cannot hide the cap."""
    def factory() -> Callable[..., Any]:
        act = make()

        def act_in_time(*args: Any) -> Any:
            check_time()
            return act(*args)

        return act_in_time

    return factory


def as_facts(rec: Recommendation) -> dict[str, Any]:
    """The recommendation as plain data (for ``report.md`` and tests)."""
    return {"task": rec.task.name, "algo": rec.algo, "keep": rec.keep,
            "budget": asdict(rec.budget), "leaf_limits": list(rec.leaf_limits),
            "seed": rec.seed, "episodes": rec.episodes, "met": rec.met,
            "met_on_choice": rec.met_on_choice, "retention": rec.retention,
            "chosen": {k: v for k, v in rec.chosen.row().items()},
            "agent_return": rec.agent.mean, "bt_return": rec.bt.mean,
            "random_return": rec.random.mean, "stopped": rec.stopped,
            "steps": list(rec.ladder.steps), "skipped": list(rec.ladder.skipped),
            "max_nodes": rec.max_nodes, "restarts": rec.restarts,
            "agreement": rec.agreement_of(rec.chosen),
            "faithful": {**rec.faithful.row(), "agreement": rec.agreement_of(rec.faithful)}}
