"""Runs and their artifacts: the engine of cached stages and the pipeline's anytime ladder
(``engine``), the content-addressed cache, the paper grid, the front, the studies notebooks
call, and ``pipeline``'s recommendation and files."""


def __getattr__(name: str) -> object:
    from ibt import _submodule

    return _submodule(__name__, name)
