"""Gymnasium environments of ``ibt``; importing this package registers them.

* ``PackageDelivery-v0``: :class:`ibt.envs.package_delivery.PackageDeliveryEnv` with a 200-step
  time limit.
"""

from __future__ import annotations

import gymnasium

ENV_ID = "PackageDelivery-v0"

if ENV_ID not in gymnasium.registry:
    gymnasium.register(
        id=ENV_ID,
        entry_point="ibt.envs.package_delivery:PackageDeliveryEnv",
        max_episode_steps=200,
    )

__all__ = ["ENV_ID"]


def __getattr__(name: str) -> object:
    from ibt import _submodule

    return _submodule(__name__, name)
