"""Experts: SB3 checkpoints loaded as an `Expert` (with training and records), and agents given
as a plain Python callable ``MODULE:FUNCTION`` (:mod:`ibt.experts.callable_agent`)."""

from __future__ import annotations

import importlib

#: names importable from ``ibt.experts`` directly, each from its module on first use
_LAZY = {
    "Expert": "ibt.experts.expert", "load_expert": "ibt.experts.expert",
    "CallableExpert": "ibt.experts.callable_agent",
    "agent_digest": "ibt.experts.callable_agent",
    "load_callable_agent": "ibt.experts.callable_agent",
}


def __getattr__(name: str) -> object:
    module = _LAZY.get(name)
    if module is not None:
        return getattr(importlib.import_module(module), name)
    from ibt import _submodule

    return _submodule(__name__, name)
