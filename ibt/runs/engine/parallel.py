"""Map a stage over independent items: in process, on the local cores (joblib's loky
processes) or on a Dask cluster when ``IBT_DASK_SCHEDULER`` names a scheduler's address.

Each item's result depends on its own arguments only (seeds are explicit), so the three give
the same results in the same order; each worker writes its own cache entries, which are
atomic, so a cluster's workers and this process may share one cache folder. A worker first
extends its import path with this process's, so it imports the same user modules (an
environment module found in the current folder or added to the path by a caller).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Sequence
from typing import Any

DASK_ENV = "IBT_DASK_SCHEDULER"


def parallel_map(fn: Callable[..., Any], args: Sequence[tuple[Any, ...]], *, n_jobs: int = 1
                 ) -> list[Any]:
    """``[fn(*a) for a in args]``: in this process where one job or one item suffices, else
    over ``n_jobs`` local processes, or the Dask scheduler at ``$IBT_DASK_SCHEDULER``."""
    address = os.environ.get(DASK_ENV)
    if len(args) <= 1 or (n_jobs <= 1 and not address):
        return [fn(*a) for a in args]
    from joblib import Parallel, delayed, parallel_config

    paths = [os.path.abspath(p) if p else os.getcwd() for p in sys.path]
    args = [(paths, fn, *a) for a in args]
    fn = _with_import_path
    if address:
        from dask.distributed import Client

        client = Client(address)
        try:
            with parallel_config(backend="dask"):
                return list(Parallel(n_jobs=-1)(delayed(fn)(*a) for a in args))
        finally:
            client.close()
    with parallel_config(backend="loky", n_jobs=n_jobs):
        return list(Parallel()(delayed(fn)(*a) for a in args))


def _with_import_path(paths: list[str], fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(*args)`` in a worker whose import path holds ``paths`` too."""
    sys.path.extend(p for p in paths if p not in sys.path)
    return fn(*args)
