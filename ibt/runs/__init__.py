"""Runs and their artifacts: the content-addressed cache, the paper grid, the front, the
cached steps notebooks call."""


def __getattr__(name: str) -> object:
    from ibt import _submodule

    return _submodule(__name__, name)
