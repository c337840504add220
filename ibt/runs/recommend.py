"""One command from an agent to a recommended BT: ``python -m ibt pipeline TASK ALGO``.

The steps of the grid and the front, for a user's own checkpoint: distil at several leaf limits
(:data:`LEAF_LIMITS`), refine each tree by return (:func:`ibt.refine.by_return.refine`, budget
:func:`ibt.runs.front.refine_config`), turn every tree into every registered synthesiser's BT
(each verified against its tree, :func:`ibt.synth.imitation.verify`) and keep each tree's
smallest BT. Every step is cached (:func:`ibt.runs.cache.load_or_compute`, the grid's keys with
the checkpoint's digest), so raising the budget or the leaf limits reruns only what changed.

With ``relational`` (the default), each leaf limit is also distilled by ``imitation-bt+rel``
(the same loop with the relational learner of :mod:`ibt.distill.relational`, whose splits may
test ``w1 * x_i + w2 * x_j``) and refined the same way (:mod:`ibt.runs.relational`); such a
candidate is recommended only where its BT is strictly smaller than every axis-aligned one that
keeps the target (ties go to the axis-aligned BT, which is easier to read).

Two sets of held-out episodes, disjoint from the distillation's training and selection episodes
and from refinement's: the *choice* episodes (the final-evaluation seeds,
:func:`ibt.evaluate.rollouts.final_seeds`) place every candidate on the front and choose the
recommendation, the smallest BT that keeps ``keep`` of the agent's random-normalised return
(or, when none does, the one that keeps most); the *confirmation* episodes (the next block of
final seeds) then measure the chosen BT, the agent and the uniform random policy afresh, so the
reported retention is not the maximum of many noisy scores. Files are written by
:mod:`ibt.runs.recommend_files`.
"""

from __future__ import annotations

import hashlib
import math
import re
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from ibt.evaluate.rollouts import FINAL_SEED_BASE, retention_norm, rollout
from ibt.files import file_digest
from ibt.profiles import Config
from ibt.runs.cache import load_or_compute
from ibt.synth.registry import SYNTHESISERS
from ibt.tasks.task import Task

LEAF_LIMITS = (4, 8, 16, 32)
DEFAULT_KEEP = 0.95
SOURCE_METHOD = "imitation-bt"  # the distillation method of every candidate
RANDOM_SEED = 0  # the uniform random policy's generator


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
class Candidate:
    """One tree of the front (distilled or refined at a leaf limit) and its smallest BT."""

    leaf_limit: int
    stage: str  # "distilled" or "refined"
    tree: Any
    bts: dict[str, Any]  # synthesiser -> verified BehaviorTree
    mean_return: float  # on the choice episodes (the tree's; every BT decides as it does)
    std_return: float
    retention: float  # random-normalised, %, on the choice episodes
    relational: bool = False  # distilled by imitation-bt+rel (splits may be relational)

    @property
    def label(self) -> str:
        """``distilled``, ``refined``, or either with ``, relational``."""
        return f"{self.stage}, relational" if self.relational else self.stage

    @property
    def relational_tests(self) -> int:
        """Relational conditions of the candidate's smallest BT."""
        return int(self.bt.relational_count)

    @property
    def bt_method(self) -> str:
        names = list(self.bts)
        return min(names, key=lambda m: (self.bts[m].node_count, names.index(m)))

    @property
    def bt(self) -> Any:
        return self.bts[self.bt_method]

    @property
    def bt_nodes(self) -> int:
        return int(self.bt.node_count)

    @property
    def leaves(self) -> int:
        return int(self.tree.get_n_leaves())

    def row(self) -> dict[str, Any]:
        return {"leaf_limit": self.leaf_limit, "stage": self.stage, "leaves": self.leaves,
                "relational": self.relational, "relational_tests": self.relational_tests,
                "bt_nodes": self.bt_nodes, "bt_method": self.bt_method,
                **{f"nodes_{m}": bt.node_count for m, bt in self.bts.items()},
                "mean_return": self.mean_return, "retention_norm": self.retention}


@dataclass
class Returns:
    """Episode returns of one policy on a set of held-out episodes."""

    returns: list[float]
    first_seed: int

    @property
    def mean(self) -> float:
        return float(np.mean(self.returns))


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

    @property
    def retention(self) -> float:
        """The chosen BT's random-normalised retention (%) on the confirmation episodes."""
        return retention_norm(self.bt.mean, self.agent.mean, self.random.mean)

    @property
    def met(self) -> bool:
        return self.met_on_choice and self.retention >= 100 * self.keep


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


def _refine_config(cfg: Config, task: Task, budget: Budget) -> Any:
    from ibt.runs.front import refine_config

    config = refine_config(cfg, task)  # no forced pruning: the tree is already within its limit
    episodes = budget.refine_episodes or max(10, round(config.episodes * budget.scale))
    ratio = episodes / config.episodes
    generations = max(config.cma_generations, math.ceil(config.cma_generations * ratio))
    return replace(config, episodes=episodes, cma_generations=generations)


def distil(cfg: Config, task: Task, algo: str, checkpoint: Path, leaves: int, seed: int,
           relational: bool = False) -> Any:
    """The distillation at ``leaves`` (cached with the grid's key: the checkpoint's digest);
    ``relational``: by ``imitation-bt+rel`` (:func:`ibt.runs.relational.distill_rel`)."""
    if relational:
        from ibt.runs.relational import distill_rel

        return distill_rel(cfg, task, algo, seed, leaves, checkpoint=checkpoint)
    from ibt.distill.loop import distill
    from ibt.experts.expert import load_expert
    from ibt.runs.pipeline import distill_config

    dcfg = distill_config(cfg, task, max_leaf_nodes=leaves)
    params = {"task": task.name, "algo": algo, "seed": seed, "config": dcfg.as_params(),
              "expert_sha256": file_digest(checkpoint)}

    def compute() -> Any:
        return distill(task, load_expert(task, algo, checkpoint), dcfg, seed,
                       progress=cfg.progress)

    return load_or_compute("distill", params, compute, cache_dir=cfg.cache_dir,
                           codec="distillation", refresh=cfg.refresh)


def refined(cfg: Config, task: Task, algo: str, tree: Any, seed: int, budget: Budget) -> Any:
    """The tree refined by return (cached with the front's key,
    :func:`ibt.runs.front.refinement_cached`; relational trees stay relational)."""
    from ibt.distill.relational import RelationalTreeClassifier
    from ibt.refine.relational import best_tree
    from ibt.runs.front import refinement_cached
    from ibt.runs.relational import METHOD as RELATIONAL

    source = RELATIONAL if isinstance(tree, RelationalTreeClassifier) else SOURCE_METHOD
    return best_tree(refinement_cached(cfg, task, algo, seed, source, tree,
                                       _refine_config(cfg, task, budget)))


def synthesised(cfg: Config, task: Task, algo: str, tree: Any, seed: int) -> dict[str, Any]:
    """Every registered synthesiser's BT of ``tree``, each verified against it (cached)."""
    from ibt.runs.grid import tree_digest
    from ibt.synth.imitation import verify

    bts = {}
    for name, synthesiser in SYNTHESISERS.items():
        params: dict[str, Any] = {"task": task.name, "algo": algo, "method": name,
                                  "seed": seed, "source_method": "pipeline",
                                  "tree": tree_digest(tree)}
        if synthesiser.version is not None:
            params["method_version"] = synthesiser.version_number()

        def compute(synthesiser: Any = synthesiser, name: str = name) -> dict[str, Any]:
            bt = synthesiser(tree, task).bt
            checked = verify(bt, tree, task)  # raises NotEquivalentError: nothing is cached
            return {"row": {"method": name, "nodes": bt.node_count, "equivalent": True,
                            "states_checked": checked}, "bt": bt}

        bts[name] = load_or_compute("synthesis", params, compute, cache_dir=cfg.cache_dir,
                                    codec="synthesis", refresh=cfg.refresh)["bt"]
    return bts


def held_out(n: int, block: int) -> list[int]:
    """Block 0: the choice episodes (the final-evaluation seeds); block 1: confirmation."""
    return [FINAL_SEED_BASE + block * n + i for i in range(n)]


def returns_of(cfg: Config, task: Task, what: dict[str, Any], act: Any, block: int) -> Returns:
    """A policy's returns on a block of held-out episodes (cached under ``what``)."""
    seeds = held_out(cfg.final_episodes, block)
    params = {"task": task.name, "episodes": cfg.final_episodes, "first_seed": seeds[0], **what}

    def compute() -> dict[str, Any]:
        return {"returns": [float(r) for r in rollout(task, act(), seeds).returns]}

    kind = "bt-eval" if "bt" in what else "tree-eval" if "tree" in what else "expert-eval"
    doc = load_or_compute(kind, params, compute, cache_dir=cfg.cache_dir, codec="json",
                          refresh=cfg.refresh)
    return Returns(list(doc["returns"]), seeds[0])


def random_act(task: Task) -> Any:
    """The uniform random policy, from its own seeded generator."""
    rng = np.random.default_rng(RANDOM_SEED)
    n = len(task.action_names)
    return lambda obs: rng.integers(n, size=len(obs))


def bt_digest(bt: Any) -> str:
    return hashlib.sha256(bt.to_json().encode()).hexdigest()[:16]


def choose(candidates: list[Candidate], keep: float) -> tuple[Candidate, bool]:
    """The smallest BT keeping ``keep`` (ties: axis-aligned, then higher retention), else the
    best retention (ties: fewer nodes, then axis-aligned); and whether the target was met."""
    meeting = [c for c in candidates if c.retention >= 100 * keep]
    if meeting:
        return min(meeting, key=lambda c: (c.bt_nodes, c.relational, -c.retention)), True
    return max(candidates, key=lambda c: (c.retention, -c.bt_nodes, not c.relational)), False


def recommend(task: Task, algo: str, checkpoint: str | Path, *, keep: float = DEFAULT_KEEP,
              budget: Budget | None = None, leaf_limits: tuple[int, ...] = LEAF_LIMITS,
              seed: int = 0, episodes: int | None = None, cache_dir: str | Path,
              progress: bool = True, argv: list[str] | None = None,
              env_modules: tuple[str, ...] = (), relational: bool = True) -> Recommendation:
    """Distil, refine, synthesise and evaluate; the recommended BT and everything measured."""
    from ibt.evaluate.policies import BTPolicy, TreePolicy
    from ibt.experts.expert import load_expert

    budget = budget or Budget()
    checkpoint = Path(checkpoint)
    cfg = pipeline_config(budget, Path(cache_dir), episodes, progress)
    quiet = replace(cfg, progress=False)
    digest = file_digest(checkpoint)
    expert = load_expert(task, algo, checkpoint)  # checks spaces before any long work
    agent_key = {"algo": algo, "expert_sha256": digest}
    random_key = {"algo": "random", "policy": "uniform", "rng_seed": RANDOM_SEED}
    agent_choice = returns_of(quiet, task, agent_key, lambda: expert.act, 0).mean
    random_choice = returns_of(quiet, task, random_key, lambda: random_act(task), 0).mean
    learners = (False, True) if relational and task.n_features >= 2 else (False,)
    steps = [(L, stage, rel) for rel in learners for L in leaf_limits
             for stage in ("distilled", "refined")]
    bar = tqdm(steps, desc=f"pipeline {task.name}/{algo}", unit="tree", disable=not progress)
    candidates: list[Candidate] = []
    trees: dict[tuple[int, bool], Any] = {}
    for leaves, stage, rel in bar:
        bar.set_postfix_str(f"{stage}{' relational' if rel else ''} at {leaves} leaves")
        if stage == "distilled":
            tree = trees[leaves, rel] = distil(cfg, task, algo, checkpoint, leaves, seed,
                                               rel).best_tree
        else:
            tree = refined(cfg, task, algo, trees[leaves, rel], seed, budget)
        bts = synthesised(quiet, task, algo, tree, seed)
        ret = returns_of(quiet, task, {"tree": _tree_key(tree)},
                         lambda tree=tree: TreePolicy(task, tree).act, 0)
        candidates.append(Candidate(leaves, stage, tree, bts, ret.mean,
                                    float(np.std(ret.returns)),
                                    retention_norm(ret.mean, agent_choice, random_choice), rel))
    chosen, met = choose(candidates, keep)
    bt = chosen.bt
    return Recommendation(
        task, algo, checkpoint, digest, keep, budget, tuple(leaf_limits), seed,
        cfg.final_episodes, candidates, chosen, met,
        agent=returns_of(quiet, task, agent_key, lambda: expert.act, 1),
        bt=returns_of(quiet, task, {"bt": bt_digest(bt)}, lambda: BTPolicy(task, bt).act, 1),
        random=returns_of(quiet, task, random_key, lambda: random_act(task), 1),
        agent_choice=agent_choice, random_choice=random_choice, argv=list(argv or []),
        env_modules=tuple(env_modules), cache_dir=Path(cache_dir))


def _tree_key(tree: Any) -> str:
    from ibt.runs.grid import tree_digest

    return tree_digest(tree)


def as_facts(rec: Recommendation) -> dict[str, Any]:
    """The recommendation as plain data (for ``report.md`` and tests)."""
    return {"task": rec.task.name, "algo": rec.algo, "keep": rec.keep,
            "budget": asdict(rec.budget), "leaf_limits": list(rec.leaf_limits),
            "seed": rec.seed, "episodes": rec.episodes, "met": rec.met,
            "met_on_choice": rec.met_on_choice, "retention": rec.retention,
            "chosen": {k: v for k, v in rec.chosen.row().items()},
            "agent_return": rec.agent.mean, "bt_return": rec.bt.mean,
            "random_return": rec.random.mean}
