"""The per-task settings a catalogue entry carries: plain, frozen, hashable values.

Each setting belongs to one step of the data flow (distillation budget, expert hyperparameters,
refinement budget, quality bar, animation clip, front target), but its *values* are facts about
a task, so they live in the task's catalogue entry (:mod:`ibt.tasks.builtin`) and the steps read
them from the :class:`~ibt.tasks.task.Task` they are given. Nothing here imports a compute
library: the catalogue is importable anywhere, cheaply.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

DEFAULT_MAX_LEAF_NODES = 16  #: the leaf limit of tasks without a budget (a readable BT)
DEFAULT_MAX_EPISODE_STEPS = 1_000  #: where an environment that sets no episode limit is cut
ALGOS = ("dqn", "ppo", "a2c", "sac", "td3")  #: the expert algorithms (Stable-Baselines3)
DISCRETE_ALGOS = ("dqn", "ppo", "a2c")  #: those the discrete tasks' experts are trained with
CONTINUOUS_ALGOS = ("sac", "td3", "ppo")  #: those that act in a Box (continuous actions)
BOX_MAX_LEAF_NODES = 8  #: the default leaf limit of a continuous task (a readable BT)
NET_ARCH = (64, 64)  #: the paper's 2x64 MLP
ZOO_DQN_NET = (256, 256)  #: the zoo's DQN network, where 2x64 missed the bar


@dataclass(frozen=True)
class TaskBudget:
    """Distillation settings shared by every method: tree size, label and selection budgets."""

    max_leaf_nodes: int | None = DEFAULT_MAX_LEAF_NODES
    max_depth: int | None = None
    ccp_alpha: float = 0.0
    labels_per_iteration: int = 1000
    # fewer iterations than the paper's 50 where the environment is too slow for the full grid
    max_iterations: int | None = None
    # more held-out episodes per candidate tree where returns are noisy: the best of 50 trees
    # on few episodes is often a lucky one (the profile's count is multiplied by this)
    selection_scale: int = 1


@dataclass(frozen=True)
class Hyperparams:
    """How one (task, algo) expert is trained (``kwargs`` go to the SB3 constructor; a string
    ``lin_X`` is the zoo's linear schedule from X to 0)."""

    timesteps: int
    n_envs: int = 1
    # VecNormalize: True normalises observations and rewards (the zoo's ``normalize: true``);
    # "reward" only rewards, for observations VecNormalize cannot scale (MultiDiscrete)
    normalize: bool | str = False
    kwargs: tuple[tuple[str, Any], ...] = ()
    source: str = "ours"  # "zoo:<file>" or "ours"
    net_arch: tuple[int, ...] = NET_ARCH
    train_env: tuple[tuple[str, Any], ...] = ()  # env kwargs used while training only
    policy_kwargs: tuple[tuple[str, Any], ...] = ()  # the zoo's policy_kwargs beside net_arch


def hp(timesteps: float, n_envs: int = 1, normalize: bool | str = False, source: str = "ours",
       net_arch: tuple[int, ...] = NET_ARCH, train_env: dict[str, Any] | None = None,
       policy_kwargs: dict[str, Any] | None = None, **kwargs: Any) -> Hyperparams:
    """A :class:`Hyperparams` row written like the zoo's YAML (keyword arguments)."""
    return Hyperparams(int(timesteps), n_envs, normalize, tuple(sorted(kwargs.items())), source,
                       net_arch, tuple(sorted((train_env or {}).items())),
                       tuple(sorted((policy_kwargs or {}).items())))


REFINE_STAGES = ("cma", "leaves", "prune", "shrink")


@dataclass(frozen=True)
class RefineConfig:
    """Everything that determines a refinement (with the source tree and the seed)."""

    stages: tuple[str, ...] = ("cma", "leaves", "prune", "cma")
    episodes: int = 20_000  # hard budget of refinement episodes over all stages
    cma_generations: int = 60  # per CMA stage (stops early when the budget runs out)
    cma_episodes: int = 16  # episodes per candidate and generation
    cma_popsize: int | None = None  # None: CMA-ES's default, 4 + 3 ln(n)
    cma_sigma: float = 0.3  # initial step, in spreads of each threshold's feature
    sweep_episodes: int = 40  # episodes per candidate in the leaf and prune sweeps
    sweep_rounds: int = 8  # at most this many accepted changes per sweep stage
    prune_tolerance: float = 0.0  # a cut may cost this much mean return (task units)
    max_leaves: int | None = None  # prune (by least loss) until the tree is this small
    selection_episodes: int = 100  # held-out episodes choosing among the stages' results
    n_envs: int = 64  # environments stepped side by side

    def __post_init__(self) -> None:
        unknown = [s for s in self.stages if s not in REFINE_STAGES]
        if unknown:
            raise ValueError(f"unknown refinement stage(s) {unknown}; expected {REFINE_STAGES}")
        for name in ("episodes", "cma_episodes", "sweep_episodes", "selection_episodes",
                     "n_envs"):
            if getattr(self, name) < 1:
                raise ValueError(f"RefineConfig.{name} must be positive, got "
                                 f"{getattr(self, name)}")
        if self.cma_sigma <= 0:
            raise ValueError(f"RefineConfig.cma_sigma must be positive, got {self.cma_sigma}")
        if self.max_leaves is not None and self.max_leaves < 1:
            raise ValueError(f"RefineConfig.max_leaves must be at least 1, got "
                             f"{self.max_leaves}")

    def as_params(self) -> dict[str, Any]:
        """The config as cache parameters (plain JSON values)."""
        out = asdict(self)
        out["stages"] = list(self.stages)
        return out


LEAF_RULES = ("vote", "score")  # EvolveConfig.leaf_rule


@dataclass(frozen=True)
class EvolveConfig:
    """Everything that determines a structure search by return (:mod:`ibt.refine.structure`,
    with the seed trees and the seed); then ``refine_episodes`` of CMA-ES and pruning
    (:mod:`ibt.refine.by_return`) polish the winner under the same leaf limit."""

    max_leaves: int = 16
    episodes: int = 60_000  # hard budget of refinement episodes
    mu: int = 6  # parents kept each generation
    lam: int = 18  # children per generation
    generation_episodes: int = 12  # episodes per tree and generation (all trees share them)
    sigma: float = 0.3  # threshold steps, in spreads of the feature
    use_expert: bool = True  # "grow" by the expert's labels and "relabel" leaves
    #: how the expert's help picks a leaf's action: "vote" (the majority of its labels over the
    #: pool states reaching the leaf) or "score" (the action of the highest mean score there:
    #: Q-values for DQN, log pi for PPO/A2C; the CART stump of "grow" then also fits weighted by
    #: ``max_a score - min_a score``, as the distillation resamples)
    leaf_rule: str = "vote"
    pool_every: int = 10  # generations between refreshes of the visited-state pool
    pool_episodes: int = 8
    selection_episodes: int = 100  # held-out episodes for the final choice
    finalists: int = 12  # trees compared on the held-out episodes
    n_envs: int = 64
    refine_episodes: int = 16_000  # the polish: CMA-ES on thresholds, then free pruning

    def __post_init__(self) -> None:
        if self.leaf_rule not in LEAF_RULES:
            raise ValueError(f"leaf_rule {self.leaf_rule!r} is not one of "
                             f"{', '.join(LEAF_RULES)}")

    def as_params(self) -> dict[str, Any]:
        """Plain data for cache keys; ``leaf_rule`` only where not the default, so the keys
        of every search run before it existed stay as they were."""
        params = asdict(self)
        if params["leaf_rule"] == "vote":
            del params["leaf_rule"]
        return params


@dataclass(frozen=True)
class QualityBar:
    """When an expert is good enough to count in the claims; one object is both the test
    (:meth:`__call__`) and its text (:meth:`describe`), so the two cannot disagree.

    Each expert is judged alone on its final evaluation row (``mean_return``, rates).
    ``scripted_share``: the mean return must reach this share of a scripted policy's return
    (passed as ``scripted``; a bar that needs it fails without it).
    """

    min_return: float | None = None
    min_return_by_algo: tuple[tuple[str, float], ...] = ()  # overrides min_return per algo
    min_success_rate: float | None = None
    max_collision_rate: float | None = None
    scripted_share: float | None = None

    def __call__(self, algo: str, row: dict[str, Any], scripted: float | None = None) -> bool:
        r = float(row["mean_return"])
        threshold = dict(self.min_return_by_algo).get(algo, self.min_return)
        if threshold is not None and r < threshold:
            return False
        if self.min_success_rate is not None and \
                float(row.get("success_rate", 0.0)) < self.min_success_rate:
            return False
        if self.max_collision_rate is not None and \
                float(row.get("collision_rate", 1.0)) > self.max_collision_rate:
            return False
        if self.scripted_share is not None:
            return scripted is not None and r >= self.scripted_share * scripted
        return True

    def describe(self) -> str:
        parts = []
        by_algo = dict(self.min_return_by_algo)
        if self.min_return is not None or by_algo:
            text = f"mean_return >= {self.min_return:g}" if self.min_return is not None else ""
            extra = "; ".join(f">= {v:g} ({a.upper()})" for a, v in by_algo.items())
            parts.append("; ".join(p for p in (text, extra) if p)
                         if text else f"mean_return {extra}")
        if self.min_success_rate is not None:
            parts.append(f"success_rate >= {self.min_success_rate:g}")
        if self.max_collision_rate is not None:
            parts.append(f"collision_rate <= {self.max_collision_rate:g}")
        if self.scripted_share is not None:
            parts.append(f"mean_return >= {self.scripted_share:g} x scripted policy")
        return " and ".join(parts) or "none (every expert counts)"


@dataclass(frozen=True)
class Clip:
    """What ``make animations`` films of a task: at most ``max_steps`` steps, every
    ``every``-th one drawn, each shown ``frame_ms`` milliseconds."""

    max_steps: int
    every: int
    frame_ms: int


@dataclass(frozen=True)
class FrontTarget:
    """A done-when bar of Imitation-BT+: retention with at most this many BT nodes.

    Both ``None``: no bar, the task is reported as measured."""

    experts: tuple[str, ...]
    min_retention: float | None  # mean random-normalised retention over seeds, %
    max_bt_nodes: int | None  # mean nodes of the committed (smallest verified) BT
    rank: int = 100  # position in the targets table (lower first)

    def describe(self) -> str:
        if self.min_retention is None or self.max_bt_nodes is None:
            return "reported as measured"
        return f">= {self.min_retention:g} % with <= {self.max_bt_nodes} nodes"


#: Outcome rates an episode batch can report beside the return (``Task.metrics``), computed by
#: :func:`ibt.evaluate.rollouts.episode_metrics`.
METRICS = ("success_if_positive", "success_if_terminated", "collision_rate",
           "battery_failure_rate", "delivered")
