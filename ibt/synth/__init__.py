"""Logic synthesis: decision tree -> rules -> Espresso -> Behavior Tree, with the baselines
and the decision list."""


def __getattr__(name: str) -> object:
    from ibt import _submodule

    return _submodule(__name__, name)
