"""Map a stage over independent items: in process, on the local cores (joblib's loky
processes) or on a Dask cluster when ``IBT_DASK_SCHEDULER`` names a scheduler's address.

Each item's result depends on its own arguments only (seeds are explicit), so the three give
the same results in the same order; each worker writes its own cache entries, which are
atomic, so a cluster's workers and this process may share one cache folder. A worker first
takes this process's working folder and extends its import path with this process's, so
relative paths (a checkpoint) and user modules (an environment module in the current folder)
resolve as they do here; loky reuses its workers, so this is done for every item.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import warnings
from collections.abc import Callable, Sequence
from typing import Any

DASK_ENV = "IBT_DASK_SCHEDULER"
#: seconds to connect to the scheduler and finish the handshake before giving up (an address
#: that accepts and never answers would otherwise hang the run with no word)
DASK_TIMEOUT = 30.0


def dask_client(address: str, timeout: float | None = None) -> Any:
    """A Dask client of the scheduler at ``address``; ``RuntimeError`` (one line naming
    :data:`DASK_ENV`) when none answers within ``timeout`` seconds (:data:`DASK_TIMEOUT`)."""
    seconds = DASK_TIMEOUT if timeout is None else timeout
    said = (f"{DASK_ENV}={address}: no Dask scheduler answered within {seconds:.0f} s")
    fix = (f"start the scheduler there, or unset {DASK_ENV} to run on this machine's cores")
    try:
        from dask.distributed import Client
    except ImportError:
        raise RuntimeError(f"{DASK_ENV}={address}: dask.distributed is not installed; install "
                           f"it (pip install distributed) or unset {DASK_ENV}") from None
    # the connection and the handshake in a daemon thread, so that a scheduler that accepts
    # and never answers cannot outlast the timeout whatever Dask's own timeouts do
    import threading

    outcome: list[Any] = []

    def connect() -> None:
        try:
            outcome.append(Client(address, timeout=f"{seconds}s"))
        except BaseException as err:  # handed to the caller below
            outcome.append(err)

    thread = threading.Thread(target=connect, name="ibt-dask-connect", daemon=True)
    thread.start()
    thread.join(seconds + 5)
    if not outcome:
        raise RuntimeError(f"{said}; {fix}")
    if not isinstance(outcome[0], BaseException):
        return outcome[0]
    err = outcome[0]
    if not isinstance(err, OSError | TimeoutError | ValueError | RuntimeError):
        raise err
    why = " ".join(f"{type(err).__name__}: {err}".split())[:200]
    raise RuntimeError(f"{said} ({why}); {fix}") from None


def parallel_map(fn: Callable[..., Any], args: Sequence[tuple[Any, ...]], *, n_jobs: int = 1,
                 progress: bool = False) -> list[Any]:
    """``[fn(*a) for a in args]``: in this process where one job or one item suffices, else
    over ``n_jobs`` local processes, or the Dask scheduler at ``$IBT_DASK_SCHEDULER``.
    ``progress``: the progress bars the items draw (their configuration asks for them) are
    shown, a local worker's as a line under the caller's bar
    (:mod:`ibt.engine.worker_progress`), a cluster's nowhere."""
    address = os.environ.get(DASK_ENV)
    if len(args) <= 1 or (n_jobs <= 1 and not address):
        return [fn(*a) for a in args]
    from ibt.engine.worker_progress import WorkerBars, reporting

    bars = WorkerBars(len(args), n_jobs) if progress and not address else None
    if progress:
        args = [(bars.path(i) if bars else None, fn, *a) for i, a in enumerate(args)]
        fn = reporting
    here = (os.getcwd(), [os.path.abspath(p) if p else os.getcwd() for p in sys.path])
    args = [(here, fn, *a) for a in args]
    if address:
        return _on_cluster(address, _here, args)
    with bars if bars is not None else contextlib.nullcontext():
        return _on_local_cores(_here, args, n_jobs)


def _on_cluster(address: str, fn: Callable[..., Any], args: Sequence[tuple[Any, ...]]
                ) -> list[Any]:
    """``[fn(*a) for a in args]`` on the Dask cluster whose scheduler is at ``address``."""
    from joblib import Parallel, delayed, parallel_config

    client = dask_client(address)
    try:
        with parallel_config(backend="dask"):
            return list(Parallel(n_jobs=-1)(delayed(fn)(*a) for a in args))
    except (OSError, TimeoutError) as err:  # the cluster, not the work: name where it is
        why = " ".join(f"{type(err).__name__}: {err}".split())[:200]
        raise RuntimeError(f"{DASK_ENV}={address}: the Dask cluster failed ({why}); check "
                           f"the scheduler and its workers, or unset {DASK_ENV} to run on "
                           "this machine's cores") from None
    finally:
        client.close()


def _on_local_cores(fn: Callable[..., Any], args: Sequence[tuple[Any, ...]], n_jobs: int
                    ) -> list[Any]:
    """``[fn(*a) for a in args]`` over ``n_jobs`` loky processes."""
    from joblib import Parallel, delayed, parallel_config

    with parallel_config(backend="loky", n_jobs=n_jobs), warnings.catch_warnings():
        # loky replaces a worker that its idle timeout stopped while a round of long items ran
        # (LunarLander's restarts) and warns of it: the items run on, nothing to tell a user
        warnings.filterwarnings("ignore", message="A worker stopped while some jobs")
        return list(Parallel()(delayed(fn)(*a) for a in args))


def processes(n_jobs: int, items: int) -> int:
    """Processes for one round of ``items`` on ``n_jobs`` cores: one each where a round holds
    fewer than twice the cores (a folded round shares them), else ``n_jobs``."""
    return items if 1 < n_jobs < items < 2 * n_jobs else n_jobs


def round_size(left: int, width: int) -> int:
    """A round's items: ``width`` (its cores), or all ``left`` (the items not yet run) where
    fewer than two rounds' worth remain, so the remainder shares the cores."""
    return left if width < left < 2 * width else width


def wall(items: int, n_jobs: int) -> float:
    """Wall time of ``items`` equal jobs on ``n_jobs`` cores, in one job's time, as
    :func:`processes` runs them (a folded round shares the cores)."""
    running = processes(n_jobs, items)
    return items / n_jobs if running == items > n_jobs else float(math.ceil(items / running))


def _here(here: tuple[str, list[str]], fn: Callable[..., Any], *args: Any) -> Any:
    """``fn(*args)`` in a worker moved to the caller's folder (where it exists: a cluster's
    machine may lack it) with the caller's import path added to its own."""
    folder, paths = here
    if os.path.isdir(folder):
        os.chdir(folder)
    sys.path.extend(p for p in paths if p not in sys.path)
    return fn(*args)
