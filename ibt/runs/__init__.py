"""The studies: the paper grid, the size-retention front and Imitation-BT+, the structure
searches, the relational and continuous studies, the headline BTs and the notebooks' steps, each
a composition of the engine's cached stages (:mod:`ibt.engine`) over the committed experts."""


def __getattr__(name: str) -> object:
    from ibt import _submodule

    return _submodule(__name__, name)
