"""Refinement by return (Imitation-BT+): a distilled tree's thresholds, leaf actions and
shape tuned on episodes."""


def __getattr__(name: str) -> object:
    from ibt import _submodule

    return _submodule(__name__, name)
