"""Episodes of any policy: rollouts, held-out seeds, retention, and the act() adapters of
trees and BTs."""


def __getattr__(name: str) -> object:
    from ibt import _submodule

    return _submodule(__name__, name)
