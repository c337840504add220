"""Results to readers: statistics, the paper's claims with verdicts, markdown, figures.
Reads results only."""


def __getattr__(name: str) -> object:
    from ibt import _submodule

    return _submodule(__name__, name)
