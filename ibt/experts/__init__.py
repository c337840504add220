"""Stable-Baselines3 experts: loading a checkpoint as an `Expert`, training and recording them."""


def __getattr__(name: str) -> object:
    from ibt import _submodule

    return _submodule(__name__, name)
