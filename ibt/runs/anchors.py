"""The published small policies each study compares with, as their papers report them (or as
run here, where a paper published the tree but not its return on our task version), in one
shape for discrete and continuous tasks."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Anchor:
    """A published small tree, as its paper reports it."""

    source: str
    task: str
    nodes: int  # the tree's node count (leaves + splits), as published
    leaves: int | None
    mean_return: float
    std_return: float | None
    # the bar "ahead of it at its own size": a mean return above the anchor's with at
    # most ``leaves`` leaves, a BT of at most ``max_bt_nodes`` nodes and, where published, at
    # least ``min_share`` of the episodes at or above the task's protocol threshold
    max_bt_nodes: int | None = None
    min_share: float | None = None


#: MENS-DT-RL (Costa, Custode, Iacca et al., "Evolving interpretable decision trees for
#: reinforcement learning", Artificial Intelligence, 2024): univariate trees evolved on return.
DISCRETE = (
    Anchor("MENS-DT-RL", "LunarLander-v3", nodes=43, leaves=22, mean_return=240.6,
           std_return=59.8, max_bt_nodes=45, min_share=0.90),
    Anchor("MENS-DT-RL", "MountainCar-v0", nodes=7, leaves=4, mean_return=-103.3,
           std_return=None, max_bt_nodes=7),
    # Kohler et al.'s interpretable-rl-zoo: CART trees distilled by DAgger from the SB3-zoo
    # PPO expert (KohlerHECTOR/interpretable-rl-zoo), its trees run here on LunarLander-v3 on
    # 50 episodes each; a CART of L leaves has 2L-1 nodes
    Anchor("interpretable-rl-zoo CART, run here", "LunarLander-v3", nodes=15, leaves=8,
           mean_return=17.2, std_return=None),
    Anchor("interpretable-rl-zoo CART, run here", "LunarLander-v3", nodes=31, leaves=16,
           mean_return=139.4, std_return=None),
    Anchor("interpretable-rl-zoo CART, run here", "LunarLander-v3", nodes=63, leaves=32,
           mean_return=187.8, std_return=132.6),
)



#: The continuous tasks' anchors: regression trees distilled from the SB3-zoo PPO expert by
#: KohlerHECTOR/interpretable-rl-zoo, run here on 50 episodes, and ICCT's DAgger tree baseline
#: as its README reports it; a tree of L leaves has 2L - 1 nodes.
CONTINUOUS = tuple(
    Anchor(source, task, nodes=2 * leaves - 1, leaves=leaves, mean_return=mean, std_return=None)
    for source, task, leaves, mean in (
        ("interpretable-rl-zoo tree, run here", "LunarLanderContinuous-v3", 8, 61.2),
        ("interpretable-rl-zoo tree, run here", "LunarLanderContinuous-v3", 16, 129.5),
        ("interpretable-rl-zoo tree, run here", "LunarLanderContinuous-v3", 32, 202.8),
        ("ICCT DAgger tree (published)", "LunarLanderContinuous-v3", 32, 184.7),
        ("interpretable-rl-zoo tree, run here", "Pendulum-v1", 8, -767.4),
        ("interpretable-rl-zoo tree, run here", "Pendulum-v1", 16, -420.4),
        ("interpretable-rl-zoo tree, run here", "Pendulum-v1", 32, -287.1),
    ))
