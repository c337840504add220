"""The task catalogue: every fact about one environment in one entry (`Task`)."""


def __getattr__(name: str) -> object:
    from ibt import _submodule

    return _submodule(__name__, name)
