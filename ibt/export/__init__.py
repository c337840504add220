"""Behavior Trees out of Python: drawings (graphviz), JSON files and BehaviorTree.CPP XML
and engine."""


def __getattr__(name: str) -> object:
    from ibt import _submodule

    return _submodule(__name__, name)
