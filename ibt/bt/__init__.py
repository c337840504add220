"""The Behavior Tree model every step downstream consumes: nodes, executors and node counts."""


def __getattr__(name: str) -> object:
    from ibt import _submodule

    return _submodule(__name__, name)
