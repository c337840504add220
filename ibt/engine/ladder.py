"""The anytime ladder: distillation smallest leaf limit first, the search by bisection, stopped
by the target, a deadline or a signal.

With the structure search (discrete actions), over the leaf limits (the rungs):

1. **distil** at each rung in increasing order, each learner (axis-aligned, then relational
   at the same limit); stop at the first rung whose best BT keeps the target.
2. **search** by return (the structure search, with restarts, then polished: it refines its
   winner) at the rungs below that one, every rung when none kept the target, in the order of
   a binary search for the smallest rung whose searched BT keeps the target.
3. **refine** by return the distilled trees that kept the target, where no smaller rung did:
   pruning may shrink their BT. Cores beyond the first refinement refine the next ones
   alongside (their steps then read the cache).

Distillation is cheap next to the by-return steps, so on a task where a small tree imitates
the agent well the answer comes in seconds. Refinement is not run before a search: the search
polishes its own winner, and on a task of slow episodes one refinement at the task's budget
costs more than a search restart (LunarLander: 80,000 episodes, about 27 minutes on one
core), so it comes last, where the deadline may leave it out. A search costs the same
episodes at every rung, so a binary search reaches the middle of the ladder in one search
where the smallest-first order would spend the budget on the smallest rungs. The relational
search runs where relational tests are on: its columns are the observed features and the
relational candidates, so it covers the axis-aligned trees too.

Without the search (a Box task's regression trees, or ``search=False``) each rung is
distilled then refined, smallest first, up to the first rung that keeps the target; cores
beyond the learners work ahead, distilling and refining the next rungs alongside.

The ladder is anytime: between steps (each one cached whole) it checks the deadline and the
caller's ``on_step`` callback, and it does not start a step when the longest step of its kind
so far took longer than the time left (it would run past the budget), nor another round of a
search's restarts unless twice the last round (the round, then the polish) fits. A first step
of its kind has no such measure, and a search's length is hard to foretell (its episodes'
length varies several-fold with the task, the agent and the trees it meets), so a step under way
when the budget runs out may go on for its grace (``GRACE_SHARE`` of the budget, at least
``GRACE_MIN`` seconds) and is then cut, like Ctrl-C: the run ends near its budget, whatever the
step. A first search or refinement that would be cut for sure is not started: the least it can
take (its episodes, each as long as the shorter of the agent's and the measured trees' mean
episode, at the seconds a step the run's tree measurements took, or, on a rerun that read them
all from the cache, two episodes of the last tree timed anew; a search's episodes cost more,
as it labels states with the agent and meets better, longer-lived trees) exceeds the time left
and the grace. The last search the bisection can make spends the time left over on further
restarts (up to ``EXTRA_RESTARTS`` times the asked number, until a restart reaches the target),
since nothing after it needs the time. Time still left when the ladder ends, or stops before
a step that would not fit, polishes again the searched BT nearest the target among those
smaller than every BT that keeps it (:mod:`ibt.engine.polish`). Ctrl-C or SIGTERM inside a
step ends that step unfinished (nothing of it is cached) and the ladder returns what it has,
marked as stopped. A rerun with a longer deadline resumes from the cache.

What the clock decided is recorded: the ladder's ``plan`` lists every step done (with a
search's restarts and a polish's seeds) and every stop, in order. Given that plan to replay
(:mod:`ibt.engine.plan`) and no deadline, it runs every planned step and nothing else, so the
same candidates come out on any machine and any number of cores.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Any

from ibt.engine import budgets, distil, measure, polish, refine, search, synthesis
from ibt.engine.agent import Agent
from ibt.engine.deadline import PACE_EPISODES, Deadline, Pace
from ibt.engine.keys import leaves_of, tree_key
from ibt.engine.learners import get_learner, learners_for, rank
from ibt.engine.parallel import parallel_map
from ibt.engine.plan import END, Entry, PlannedStep, PlannedStop, Replay
from ibt.engine.search import SearchInfo
from ibt.evaluate.rollouts import retention_norm
from ibt.profiles import Config
from ibt.signals import STOP_SIGNALS, OverTime, stop_reason, time_cap


@dataclass
class Candidate:
    """One tree of the front (distilled, refined or searched at a leaf limit) and its BTs."""

    leaf_limit: int
    stage: str  # "distilled", "refined", "searched" or "polished" (again, with time left)
    tree: Any
    bts: dict[str, Any]  # synthesiser -> verified BehaviorTree
    mean_return: float  # on the choice episodes (the tree's; every BT decides as it does)
    std_return: float
    retention: float  # random-normalised, %, on the choice episodes
    learner: str = "axis"  # the registered learner whose tree it is (ibt.engine.learners)
    search: SearchInfo | None = None  # how a searched tree's restart was chosen

    @property
    def label(self) -> str:
        """``distilled``, ``refined``, ``searched``, ``polished``, with the learner's name
        where its tests may combine features (``distilled, relational``)."""
        entry = get_learner(self.learner)
        return f"{self.stage}, {self.learner}" if entry.combines_features else self.stage

    @property
    def rank(self) -> int:
        """Its learner's place in the registry (the simpler first)."""
        return rank(self.learner)

    @property
    def relational_tests(self) -> int:
        return int(self.bt.relational_count)

    @property
    def bt_method(self) -> str:
        return synthesis.smallest_bt(self.bts)

    @property
    def bt(self) -> Any:
        return self.bts[self.bt_method]

    @property
    def bt_nodes(self) -> int:
        return int(self.bt.node_count)

    @property
    def leaves(self) -> int:
        return leaves_of(self.tree)

    def row(self) -> dict[str, Any]:
        return {"leaf_limit": self.leaf_limit, "stage": self.stage, "leaves": self.leaves,
                "learner": self.learner,
                "relational": get_learner(self.learner).combines_features,
                "relational_tests": self.relational_tests,
                "bt_nodes": self.bt_nodes, "bt_method": self.bt_method,
                **{f"nodes_{m}": bt.node_count for m, bt in self.bts.items()},
                "mean_return": self.mean_return, "retention_norm": self.retention}


#: on the ladder's last search, with a deadline, restarts go on up to this many times the
#: asked number while another round and the polish fit in the time left and none reached the
#: target
EXTRA_RESTARTS = 4


@dataclass(frozen=True)
class Settings:
    """What the ladder may do: the target, the rungs, restarts and the budgets' scale."""

    keep: float
    rungs: tuple[int, ...]
    seed: int = 0
    relational: bool = True
    restarts: int = 3
    n_jobs: int = 1
    scale: float = 1.0  # of every stage's episode budget
    refine_episodes: int | None = None  # per tree, where given (else the scaled budget)
    max_nodes: int | None = None  # the recommended BT's bound
    search: bool = True
    full: bool = False  # every rung and every step, whatever kept the target (benchmarks)
    env_modules: tuple[str, ...] = ()
    learners: tuple[str, ...] = ()  # the learners tried (none given: every registered one that
    # accepts the agent, ibt.engine.learners.learners_for)


@dataclass
class Ladder:
    """What the ladder did: the candidates in the order made, and why it ended."""

    candidates: list[Candidate] = field(default_factory=list)
    stopped: str | None = None  # "time", "interrupted" or the callback's reason; None: done
    steps: list[str] = field(default_factory=list)  # the steps done, in order
    skipped: list[str] = field(default_factory=list)  # the steps left undone by a stop
    notes: list[str] = field(default_factory=list)
    plan: list[Entry] = field(default_factory=list)  # the steps and stops (ibt.engine.plan)


class Stopped(Exception):
    """Raised between steps when the deadline passed or the callback asked to stop."""


def eligible(c: Candidate, settings: Settings) -> bool:
    return settings.max_nodes is None or c.bt_nodes <= settings.max_nodes


def keeps(c: Candidate, settings: Settings) -> bool:
    return eligible(c, settings) and c.retention >= 100 * settings.keep


def run_ladder(cfg: Config, agent: Agent, settings: Settings, *, agent_mean: float,
               random_mean: float, deadline: Deadline | None = None,
               on_step: Callable[[Ladder, str], str | None] | None = None,
               agent_length: float | None = None, replay: Replay | None = None) -> Ladder:
    """Climb the ladder; ``agent_mean``/``random_mean`` are the choice episodes' baselines
    (``agent_length``: the agent's mean steps an episode there, where known).
    ``on_step(ladder, next_step)`` runs before every step; a string it returns stops the
    ladder with that reason. ``replay``: a plan's steps (:mod:`ibt.engine.plan`), run every
    one and nothing else, instead of the clock's decisions (give no deadline)."""
    deadline = deadline or Deadline(None)
    out = Ladder()
    learners = settings.learners or learners_for(agent, settings.relational)
    choice = measure.held_out(cfg.final_episodes, 0)
    took: dict[str, float] = {}  # each kind of step's longest wall time (distil, refine, search)
    pace = Pace(agent_length)  # the run's tree measurements: seconds a step, steps an episode
    running: list[str] = []  # the step under way (what a signal cuts short)

    def halt(reason: str, name: str) -> Stopped:
        """The stop before the step ``name``, recorded in the plan."""
        out.plan.append(PlannedStop(reason, name))
        return Stopped(reason)

    def step(name: str, make: Callable[[], Any], leaves: int, stage: str, learner: str,
             info: Any = None, episodes: float = 0.0, seeds: tuple[int, ...] = ()) -> Any:
        """Run one cached step, then measure its tree; ``episodes``: its least length in
        episodes of one core's wall time (a search's, a refinement's), for the deadline;
        ``seeds``: a polish's, for the plan."""
        planned = replay.take(name) if replay is not None else None
        if replay is not None and not isinstance(planned, PlannedStep):
            out.plan += [planned] if planned is not None else []  # a recorded stop
            raise Stopped(END)
        if deadline.passed():
            raise halt("time", name)
        kind = name.split()[0]
        left = deadline.left()
        if kind in took and took[kind] > left:
            out.notes.append(f"the ladder stopped before \"{name}\": the longest {kind} step "
                             f"took {took[kind]:.0f} s and {left:.0f} s of the budget were left")
            raise halt("time", name)
        gated = bool(episodes) and kind not in took and deadline.seconds is not None
        if gated and not pace.steps and out.candidates:  # every measurement read from the cache
            last = out.candidates[-1]
            pace.add(measure.rolled(agent.task, measure.policy(agent, last.tree, last.bts)[1],
                                   choice[:PACE_EPISODES]))
        least = pace.least(episodes) if gated else 0.0
        if least > left + deadline.grace():
            out.notes.append(f"the ladder stopped before \"{name}\": it would not end within the "
                             f"budget and its grace (at least {least:.0f} s expected: "
                             f"{pace.said(episodes)}; {left:.0f} s were left and "
                             f"{deadline.grace():.0f} s of grace)")
            raise halt("time", name)
        reason = on_step(out, name) if on_step is not None else None
        if reason:
            raise halt(reason, name)
        began, running[:] = deadline.clock(), [name]
        with time_cap(deadline.left() + deadline.grace()):
            made = make()
        seconds = deadline.clock() - began
        if least:
            out.notes.append(f"\"{name}\" took {seconds:.0f} s (at least {least:.0f} s were "
                             "expected from its episodes)")
        took[kind] = max(took.get(kind, 0.0), seconds)
        running.clear()
        tree, info = made if isinstance(made, tuple) else (made, info)
        out.plan.append(PlannedStep(name, kind, stage, learner, leaves, seeds or (
            info.seeds if isinstance(info, SearchInfo) else (settings.seed,))))
        if tree is None:  # nothing better found (a polish again)
            out.steps.append(name)
            return None
        bts = synthesis.synthesise(cfg, agent, tree, settings.seed)
        ret = measure.measure(cfg, agent, tree, bts, choice)
        pace.add(ret)
        out.candidates.append(Candidate(
            leaves, stage, tree, bts, ret.mean, ret.std,
            _retention(ret.mean, agent_mean, random_mean), learner, info))
        out.steps.append(name)
        return tree

    def guarded(climb: Callable[[], None]) -> str | None:
        """Run ``climb``; why it stopped (None: it ended), a cut step noted."""
        try:
            climb()
        except Stopped as stop:
            return str(stop)
        except STOP_SIGNALS as err:  # Ctrl-C or SIGTERM inside a step: that step is not cached
            out.plan.append(PlannedStop(stop_reason(err), running[0] if running else ""))
            return stop_reason(err)
        except OverTime:  # a step ran past its grace: cut, as by Ctrl-C
            out.plan.append(PlannedStop("time", running[0] if running else ""))
            out.notes.append(f"\"{running[0] if running else 'a step'}\" was cut "
                             f"{deadline.grace():.0f} s past the time budget, unfinished (what "
                             "of it was done, such as a search's finished restarts, is cached): "
                             "a rerun with a longer --time lets it finish")
            return "cut"
        return None

    plan = _plan(settings, learners, agent.continuous)
    if settings.search and not agent.continuous:
        target = random_mean + settings.keep * (agent_mean - random_mean)
        out.stopped = guarded(partial(_search_ladder, out, step, cfg, agent, settings, learners,
                                      deadline, target, replay))
        if out.stopped in (None, "time", END) and not settings.full and (
                deadline.seconds is not None or replay is not None):
            spare = guarded(partial(polish.spare_time, out, step, cfg, agent, settings, replay))
            out.stopped = out.stopped if spare in (None, "time", END) else spare
    else:
        out.stopped = guarded(partial(_imitation_ladder, out, step, cfg, agent, settings,
                                      learners))
        if agent.continuous:
            out.notes.append("the structure search is for discrete actions: a Box task's "
                             "trees are distilled and refined (commands and thresholds)")
    out.stopped = "time" if out.stopped == "cut" else out.stopped
    if replay is not None and out.stopped in (None, END):  # every planned step was run
        out.stopped = None
        replay.check_finished()
    if out.stopped:
        out.skipped = running + [s for s in plan if s not in out.steps and s not in running]
    return out


def _imitation_ladder(out: Ladder, step: Callable[..., Any], cfg: Config, agent: Agent,
                      settings: Settings, learners: tuple[str, ...]) -> None:
    """Without the structure search (a Box task, or ``search=False``): at each rung, distil
    then refine each learner; stop at the first rung that keeps the target.

    Cores beyond the learners work ahead: the rungs go in blocks of ``n_jobs // learners``
    (a Box task's one learner on two cores: 4 and 8, then 16 and 32), the block's first steps
    distilling, then refining, all of its trees at once; its other steps read them from the
    cache. The same steps in the same order, the same trees: only the wall time changes (a
    block's larger rung is done alongside even where the smaller one keeps the target)."""
    rungs = list(settings.rungs)
    width = max(1, settings.n_jobs // len(learners))
    for block in (rungs[i:i + width] for i in range(0, len(rungs), width)):
        for leaves in block:
            for learner in learners:
                tag = f"{learner} at {leaves} leaves"
                ahead = leaves == block[0] and learner == learners[0]
                tree = step(f"distil {tag}", partial(_distil_block, cfg, agent, block, settings,
                                                     learners) if ahead else partial(
                    distil.distil, cfg, agent, leaves, settings.seed, learner),
                    leaves, "distilled", learner)
                step(f"refine {tag}", partial(_refine_block, cfg, agent, block, settings,
                                              learners, tree) if ahead else partial(
                    refine.refine, cfg, agent, learner, tree, settings.seed, settings.scale,
                    settings.refine_episodes), leaves, "refined", learner,
                    episodes=_refine_length(cfg, agent, settings))
            if _kept_at(out, leaves, settings) and not settings.full:
                return


def _search_ladder(out: Ladder, step: Callable[..., Any], cfg: Config, agent: Agent,
                   settings: Settings, learners: tuple[str, ...], deadline: Deadline,
                   target: float, replay: Replay | None = None) -> None:
    """With the structure search: distil at each rung (smallest first, stopping at the first
    that keeps the target); search the rungs below it (every rung when none kept the target)
    in bisection order; then, where no smaller rung kept the target, refine the trees that
    kept it (pruning may shrink their BT). ``target``: the mean return that keeps it."""
    distilled: dict[int, dict[str, Any]] = {}
    kept = None
    for leaves in settings.rungs:
        first = partial(_distil_block, cfg, agent, [leaves], settings, learners)
        distilled[leaves] = {
            learner: step(f"distil {learner} at {leaves} leaves", first if i == 0 else partial(
                distil.distil, cfg, agent, leaves, settings.seed, learner),
                leaves, "distilled", learner)
            for i, learner in enumerate(learners)}
        if _kept_at(out, leaves, settings) and not settings.full:
            kept = leaves
            break
    keepers = [(kept, c.learner) for c in out.candidates
               if c.leaf_limit == kept and keeps(c, settings)]
    learner = search_learner(learners)
    below = [r for r in settings.rungs if r in distilled and (kept is None or r < kept)
             and learner is not None]
    seeded = [name for name in learners if get_learner(name).searched]  # its seed trees
    relational = learner is not None and get_learner(learner).combines_features
    largest = max(distilled)

    def probe(leaves: int, last: bool = False) -> bool:
        sources = _distinct([distilled[rung][name] for name in seeded
                             for rung in (leaves, largest)])
        # the ladder's last step (no probe follows, nothing to refine after it) spends the
        # time left on further restarts, until one reaches the target
        final = last and kept is None and deadline.seconds is not None
        most = EXTRA_RESTARTS * settings.restarts if final else None
        name = f"search {learner} at {leaves} leaves"
        planned = replay.peek(name) if replay is not None else None  # its restarts, no clock
        exactly = {"exactly": len(planned.seeds)} if planned is not None else {}
        step(name, partial(
            search.search, cfg, agent, sources, leaves, settings.seed,
            restarts=settings.restarts, relational=relational,
            scale=settings.scale, n_jobs=settings.n_jobs, env_modules=settings.env_modules,
            # another round, then the polishes of the best restarts (one polish measured on
            # LunarLander at 0.6-0.7 of a round; 3 sharing 2 cores about one round), must fit
            # in the time left
            next_round=lambda seconds: 2 * seconds <= deadline.left(), most=most,
            enough=target if final else None, **exactly),
            leaves, "searched", learner, episodes=search.search_length(
                cfg, agent.task, leaves, restarts=settings.restarts, scale=settings.scale,
                n_jobs=settings.n_jobs))
        info = out.candidates[-1].search
        done = len(info.seeds) if info is not None else settings.restarts
        if done < settings.restarts:
            out.notes.append(f"the search at {leaves} leaves ran {done} of its "
                             f"{settings.restarts} restarts: another round and the polish after "
                             "it would not have fitted in the time left")
        return _kept_at(out, leaves, settings)

    if settings.full:
        for leaves in below:
            probe(leaves)
        keepers = [(leaves, name) for leaves in distilled for name in learners]
    else:
        bisection(below, probe)
        if any(_kept_at(out, leaves, settings) for leaves in below):
            keepers = []  # a smaller rung kept the target
    ahead = [(name, distilled[leaves][name]) for leaves, name in keepers[:settings.n_jobs]]
    for i, (leaves, name) in enumerate(keepers):
        make = partial(refine.refine, cfg, agent, name, distilled[leaves][name], settings.seed,
                       settings.scale, settings.refine_episodes)
        step(f"refine {name} at {leaves} leaves", partial(_alongside, make, cfg, agent,
                                                          settings, ahead) if i == 0 else make,
             leaves, "refined", name, episodes=_refine_length(cfg, agent, settings))


def _distil_block(cfg: Config, agent: Agent, block: list[int], settings: Settings,
                  learners: tuple[str, ...]) -> Any:
    """The first learner's tree at the block's first rung, every learner's at every rung of
    the block distilled alongside on the local cores (their steps then read the cache)."""
    jobs = [(leaves, learner) for leaves in block for learner in learners]
    if settings.n_jobs > 1 and len(jobs) > 1:
        parallel_map(distil.distil, [(cfg, agent, leaves, settings.seed, learner,
                                      settings.env_modules) for leaves, learner in jobs],
                     n_jobs=min(settings.n_jobs, len(jobs)), progress=cfg.progress)
    return distil.distil(cfg, agent, block[0], settings.seed, learners[0])


def _refine_block(cfg: Config, agent: Agent, block: list[int], settings: Settings,
                  learners: tuple[str, ...], tree: Any) -> Any:
    """``tree`` (the first learner's at the block's first rung) refined, every distilled
    tree of the block refined alongside on the local cores (their steps then read the cache)."""
    jobs = [(leaves, learner) for leaves in block for learner in learners]
    quiet = replace(cfg, progress=False)
    trees = [(learner, distil.distil(quiet, agent, leaves, settings.seed, learner))
             for leaves, learner in jobs] if settings.n_jobs > 1 and len(jobs) > 1 else []  # cached
    return _alongside(partial(refine.refine, cfg, agent, learners[0], tree, settings.seed,
                              settings.scale, settings.refine_episodes), cfg, agent, settings,
                      trees)


def _alongside(first: Callable[[], Any], cfg: Config, agent: Agent, settings: Settings,
               trees: list[tuple[str, Any]]) -> Any:
    """``first()`` (a refinement among ``trees``, ``(learner, tree)`` pairs), after every tree
    of ``trees`` is refined at once on the local cores and cached: the same refinements, the
    steps that follow read them from the cache."""
    if settings.n_jobs > 1 and len(trees) > 1:
        parallel_map(refine.refine, [(cfg, agent, learner, t, settings.seed, settings.scale,
                                      settings.refine_episodes, settings.env_modules)
                                     for learner, t in trees],
                     n_jobs=min(settings.n_jobs, len(trees)), progress=cfg.progress)
    return first()


def _refine_length(cfg: Config, agent: Agent, settings: Settings) -> float:
    """A refinement's episodes (one tree's, one core; a block's trees share the cores)."""
    return budgets.scaled_refine_config(cfg, agent.task, settings.scale,
                                        settings.refine_episodes, agent.continuous).episodes


def search_learner(learners: tuple[str, ...]) -> str | None:
    """The learner whose structure search runs (None: no learner's trees are searched): the
    last of those whose trees seed it, in registry order, seeded with all of theirs. Where
    relational tests are on that is the relational search: its columns are the observed
    features and the relational candidates, so it searches every axis-aligned tree too, at
    the same budget; one search a rung instead of two."""
    searched = [name for name in learners if get_learner(name).searched]
    return searched[-1] if searched else None


def bisection(rungs: list[int], probe: Callable[[int, bool], bool]) -> None:
    """A binary search for the smallest rung whose probe keeps the target (``probe(rung,
    last)`` runs it and says whether it kept; ``last``: no probe can follow it). A search costs
    the same episodes at every rung, so on a task whose episodes are slow (LunarLander: 10-20
    minutes a search on two cores) a budget of a few searches reaches the middle of the ladder
    instead of its smallest rungs."""
    lo, hi = 0, len(rungs) - 1
    while lo <= hi:
        mid = (lo + hi) // 2
        if probe(rungs[mid], lo == hi):
            hi = mid - 1
        else:
            lo = mid + 1


def _retention(mean: float, agent_mean: float, random_mean: float) -> float:
    """Random-normalised retention (%); NaN where the agent is no better than random (the
    report says so instead of dividing by nothing)."""
    if agent_mean - random_mean <= 1e-9:
        return float("nan")
    return retention_norm(mean, agent_mean, random_mean)


def _kept_at(ladder: Ladder, leaves: int, settings: Settings) -> bool:
    return any(c.leaf_limit == leaves and keeps(c, settings) for c in ladder.candidates)


def _distinct(trees: list[Any]) -> list[Any]:
    seen: dict[str, Any] = {}
    for tree in trees:
        seen.setdefault(tree_key(tree), tree)
    return list(seen.values())


def _plan(settings: Settings, learners: tuple[str, ...], continuous: bool) -> list[str]:
    """Every step the ladder could take, in order (what a stop leaves undone)."""
    if settings.search and not continuous:
        searched = search_learner(learners)
        return [f"distil {learner} at {leaves} leaves" for leaves in settings.rungs
                for learner in learners] + [
            f"search {searched} at {leaves} leaves" for leaves in settings.rungs
            if searched is not None]
    return [f"{verb} {learner} at {leaves} leaves" for leaves in settings.rungs
            for learner in learners for verb in ("distil", "refine")]
