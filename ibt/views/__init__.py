"""Interactive and animated views: notebook widgets, the lesson, the GIFs of BTs in motion."""


def __getattr__(name: str) -> object:
    from ibt import _submodule

    return _submodule(__name__, name)
