"""The registry of learners: one entry per way the interactive loop grows a tree.

A learner is what the distillation stage (:mod:`ibt.engine.distil`) fits at a leaf limit:
``axis`` (scikit-learn's CART), ``relational`` (splits may test ``w1 * x_i + w2 * x_j``,
:mod:`ibt.distill.relational`), ``box`` (a regression tree on a ``Box`` task, its leaves
merged into named commands, :mod:`ibt.distill.continuous`), ``oblique`` and ``controller``
(:mod:`ibt.engine.controller_learners`). Each entry says which action space it accepts, its
cache kind and payload codec, and how the engine builds its settings, runs its loop, reads the
stage's tree from a cached run, refines that tree by return, lays out its BT where the
registered synthesisers do not, and measures it. The ladder (:mod:`ibt.engine.ladder`) tries,
at each rung, every registered learner that accepts the agent's actions, in registry order
(the simplest first; a tie in BT size goes to the earlier one); the studies and the pipeline
name a learner by its entry's name, and the engine finds the learner of a tree by its class
(:func:`learner_of_tree`).

Adding a learner is one module holding its tree fit and its :class:`Learner` entry
(``ibt/engine/learner_<name>.py`` for a built-in one), one line in :data:`BUILT_IN` (or a
:func:`register_learner` call from a user's environment module) and its tests. A new learner is
cached under the kinds :data:`LEARNER_DISTIL` and :data:`LEARNER_REFINE`, keyed on its name and
``version``; the code guard (:mod:`ibt.cache.guard`) counts every ``engine/learner_*.py`` among
those kinds' sources, so no cache module changes. A learner registered from a user's
environment module is seen in worker processes too, since a worker imports those modules before
it runs a stage.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from importlib import import_module
from typing import Any

from ibt.engine import budgets
from ibt.engine.agent import Agent
from ibt.profiles import Config

DISCRETE = "discrete"  #: a learner of trees whose leaves are action indices
BOX = "box"  #: a learner of trees whose leaves are command vectors (``Box`` actions)
LEARNER_DISTIL = "learner-distil"  #: the distillation kind of learners without a kind of their own
LEARNER_REFINE = "learner-refine"  #: the refinement kind of learners without a kind of their own


def _no_params() -> dict[str, Any]:
    return {}


@dataclass(frozen=True)
class Learner:
    """One learner and how every stage of the engine uses it.

    ``settings(cfg, agent, method, overrides)``: the loop's settings (``method``: the loop's
    method where the caller names one; ``overrides`` of the task's budget, e.g.
    ``max_leaf_nodes``), whose ``as_params()`` goes into the key; ``fit(cfg, agent, settings,
    seed)``: the distillation run, the cached payload (``codec``); ``tree(cfg, agent, run,
    seed)``: the stage's tree of a run; ``refine(cfg, agent, tree, seed, scale, episodes)``:
    that tree refined by return (``scale`` of the task's budget, or ``episodes``);
    ``key_params()``: more key parameters (the learner's own settings); ``lay_out(agent,
    tree, seed)``: its tree's BTs by name (``{name: BehaviorTree}``, each verified), where the
    registered synthesisers do not make them (None: they do); ``trees``: the qualified names
    of the classes of its stage trees (how :func:`learner_of_tree` finds it); ``measured_as_bt``:
    its trees are rolled out through their smallest BT (a tree that does not act as a
    :class:`ibt.evaluate.policies.TreePolicy` would); ``version``: its code version in the
    keys of :data:`LEARNER_DISTIL` and :data:`LEARNER_REFINE`."""

    name: str
    actions: str  # DISCRETE or BOX: the action space it accepts
    kind: str  # its distillation's cache kind: its own (ibt.cache.store.CODE_VERSIONS) or
    #            LEARNER_DISTIL
    codec: str  # its run's payload codec (ibt.cache.payloads.CODECS)
    settings: Callable[[Config, Agent, str | None, dict[str, Any]], Any]
    fit: Callable[[Config, Agent, Any, int], Any]
    tree: Callable[[Config, Agent, Any, int], Any]
    refine: Callable[[Config, Agent, Any, int, float, int | None], Any]
    key_params: Callable[[], dict[str, Any]] = _no_params
    min_features: int = 1  # a task with fewer observed features is not offered it
    combines_features: bool = False  # a test may read several features (off with relational=False)
    searched: bool = False  # its trees seed the structure search (discrete actions)
    description: str = ""
    lay_out: Callable[[Agent, Any, int], dict[str, Any]] | None = None
    trees: tuple[str, ...] = ()
    measured_as_bt: bool = False
    version: int = 1

    def params(self) -> dict[str, Any]:
        """Its key parameters beside the run's: :meth:`key_params`, and under the shared
        kind :data:`LEARNER_DISTIL` its name and version."""
        shared = ({"learner": self.name, "learner_version": self.version}
                  if self.kind == LEARNER_DISTIL else {})
        return {**self.key_params(), **shared}

    def accepts(self, agent: Agent, combined: bool = True) -> bool:
        """Whether the ladder offers it ``agent`` (``combined``: learners whose tests combine
        features are on)."""
        return ((self.actions == BOX) == agent.continuous
                and agent.task.n_features >= self.min_features
                and (combined or not self.combines_features))


LEARNERS: dict[str, Learner] = {}


def register_learner(learner: Learner) -> Learner:
    """Add (or replace) a learner, after the ones registered before it; returns it."""
    LEARNERS.pop(learner.name, None)
    LEARNERS[learner.name] = learner
    return learner


def get_learner(name: str) -> Learner:
    """The registered learner ``name``; ``ValueError`` lists the known ones."""
    try:
        return LEARNERS[name]
    except KeyError:
        raise ValueError(f"unknown learner {name!r}; choose from {', '.join(LEARNERS)}") from None


def learners_for(agent: Agent, combined: bool = True) -> tuple[str, ...]:
    """The learners the ladder tries on ``agent``, in registry order."""
    return tuple(name for name, learner in LEARNERS.items() if learner.accepts(agent, combined))


def rank(name: str) -> int:
    """A learner's place in the registry: the simpler first (the pipeline's tie-break)."""
    return list(LEARNERS).index(name)


def learner_of_tree(tree: Any) -> Learner | None:
    """The registered learner whose stage trees are of ``tree``'s class (None: a classifier of
    the ``axis`` or ``relational`` learners, whose trees every synthesiser takes)."""
    cls = type(tree)
    name = f"{cls.__module__}.{cls.__qualname__}"
    return next((entry for entry in LEARNERS.values() if name in entry.trees), None)


def refinement_cached(cfg: Config, learner: Learner, params: dict[str, Any],
                      compute: Callable[[], dict[str, Any]]) -> dict[str, Any]:
    """A learner's refinement (a JSON document) cached under :data:`LEARNER_REFINE`, keyed on
    ``params`` (task, seed, source tree, settings) with the learner's name and version."""
    from ibt.cache.store import load_or_compute

    return load_or_compute(LEARNER_REFINE, {"learner": learner.name,
                                            "learner_version": learner.version, **params},
                           compute, cache_dir=cfg.cache_dir, codec="json", refresh=cfg.refresh)


# --- the built-in learners' adapters -----------------------------------------------------------


def _loop_settings(fixed: str | None) -> Callable[[Config, Agent, str | None, dict[str, Any]],
                                                  Any]:
    """The interactive loop's settings (:func:`ibt.engine.budgets.distill_config`) under the
    caller's method (Imitation-BT's by default) or, where ``fixed``, that one."""
    def settings(cfg: Config, agent: Agent, method: str | None, overrides: dict[str, Any]
                 ) -> Any:
        return budgets.distill_config(cfg, agent.task, fixed or method or "imitation-bt",
                                      **overrides)

    return settings


def loop_fit(make: Callable[[Any, int], Any]) -> Callable[[Config, Agent, Any, int], Any]:
    """The ``fit`` of a learner the interactive loop runs with a tree fit of its own:
    ``make(settings, seed)`` gives its :class:`ibt.distill.loop.Learner` (how it labels, fits,
    acts and mixes), run by :func:`ibt.distill.loop.interactive_loop`; the run is a
    :class:`ibt.distill.loop.Distillation` (codec ``distillation``, for trees it encodes)."""
    def fit(cfg: Config, agent: Agent, config: Any, seed: int) -> Any:
        from ibt.distill.loop import interactive_loop

        return interactive_loop(agent.task, agent.load(), config, seed, make(config, seed),
                                progress=cfg.progress)

    return fit


def _loop_fit(cfg: Config, agent: Agent, config: Any, seed: int) -> Any:
    """The interactive loop of a classification tree (the method's tree fit:
    :data:`ibt.distill.loop.METHODS`): a :class:`ibt.distill.loop.Distillation`."""
    from ibt.distill.loop import distill

    return distill(agent.task, agent.load(), config, seed, progress=cfg.progress)


def _best_tree(cfg: Config, agent: Agent, run: Any, seed: int) -> Any:
    return run.best_tree


def _refine_classifier(source: str) -> Callable[[Config, Agent, Any, int, float, int | None],
                                                Any]:
    """A classification tree refined by return, keyed on its distillation method ``source``
    (:func:`ibt.engine.refine.refinement_cached`)."""
    def refine(cfg: Config, agent: Agent, tree: Any, seed: int, scale: float,
               episodes: int | None) -> Any:
        from ibt.engine.refine import refinement_cached
        from ibt.refine.relational import best_tree

        config = budgets.scaled_refine_config(cfg, agent.task, scale, episodes)
        return best_tree(refinement_cached(cfg, agent.task, agent.algo, seed, source, tree,
                                           config))

    return refine


def _relational_params() -> dict[str, Any]:
    return {"learner": budgets.learner_params()}


def box_method(agent: Agent) -> str:
    """Critic-weighted imitation for SAC and TD3 agents (their critic scores any action);
    plain DAgger for the others."""
    return "imitation-bt" if agent.algo in ("sac", "td3") else "dagger"


def _box_settings(cfg: Config, agent: Agent, method: str | None, overrides: dict[str, Any]
                  ) -> Any:
    """The task's continuous budget at a leaf limit; a Box distillation takes that one
    override only."""
    overrides = dict(overrides)
    leaves = overrides.pop("max_leaf_nodes", None)
    if overrides:
        raise TypeError(f"a Box distillation takes max_leaf_nodes only, not {sorted(overrides)}")
    return budgets.box_config(cfg, agent.task, method or box_method(agent), leaves)


def _box_fit(cfg: Config, agent: Agent, config: Any, seed: int) -> dict[str, Any]:
    """The loop with a regression tree: ``iterations``, ``best_index``, ``tree`` (a
    :func:`ibt.distill.continuous.regressor_doc`), ``wall_seconds``."""
    from ibt.distill.continuous import distill_box, regressor_doc

    run = distill_box(agent.task, agent.load(), config, seed, progress=cfg.progress)
    return {"iterations": run.iterations, "best_index": run.best_index,
            "tree": regressor_doc(run.best_tree), "wall_seconds": run.wall_seconds}


def _box_tree(cfg: Config, agent: Agent, run: dict[str, Any], seed: int) -> Any:
    """The run's regression tree, its leaves merged into named commands
    (:func:`ibt.engine.commands.commands`): command arrays."""
    from ibt.engine.commands import commands
    from ibt.refine.commands import CommandArrays

    return CommandArrays.from_doc(commands(cfg, agent, run["tree"], seed)["arrays"])


def _box_refine(cfg: Config, agent: Agent, tree: Any, seed: int, scale: float,
                episodes: int | None) -> Any:
    """A command tree refined by return: thresholds and commands' values
    (:func:`ibt.engine.refine.command_refinement`)."""
    from ibt.engine.refine import command_refinement

    config = budgets.scaled_refine_config(cfg, agent.task, scale, episodes, commands=True)
    return command_refinement(cfg, agent, tree, seed, config).best


for _entry in (
    Learner("axis", DISCRETE, "distill", "distillation", _loop_settings(None), _loop_fit,
            _best_tree, _refine_classifier("imitation-bt"), searched=True,
            description="scikit-learn's CART: each test reads one feature"),
    Learner("relational", DISCRETE, "distill-rel", "distillation",
            _loop_settings(budgets.RELATIONAL), _loop_fit, _best_tree,
            _refine_classifier(budgets.RELATIONAL), key_params=_relational_params,
            min_features=2, combines_features=True, searched=True,
            description="splits may test w1 * x_i + w2 * x_j where they beat every "
                        "axis-aligned one"),
    Learner("box", BOX, "box-distill", "json", _box_settings, _box_fit, _box_tree,
            _box_refine, trees=("ibt.refine.commands.CommandArrays",), measured_as_bt=True,
            description="a regression tree whose leaves are merged into named commands"),
):
    register_learner(_entry)

#: the built-in learners defined in modules of their own, each registering its entries on
#: import, after the ones above (whichever module is imported first)
BUILT_IN = ("ibt.engine.controller_learners",)
for _module in BUILT_IN:
    import_module(_module)
