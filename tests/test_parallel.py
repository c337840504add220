"""Mapping a stage over items (ibt.engine.parallel): where the items run (in this process, on
the local cores, on a Dask cluster), what a worker is handed (this process's folder and import
path, a status file per item), how a Dask address that fails is named, and the arithmetic of
rounds on the cores. Quick: the cluster and the local cores are stood in for in this process,
except one real run on two local processes at the end."""

from __future__ import annotations

import contextlib
import math
import os
import sys
import threading
import time
import types

import joblib
import pytest
from hypothesis import given
from hypothesis import strategies as st

from ibt.engine import parallel
from ibt.engine.worker_progress import reporting

ADDRESS = "tcp://10.0.0.1:8786"


def _pair(a: int, b: int) -> tuple[int, int, int]:
    return a, b, os.getpid()


@pytest.fixture
def local(monkeypatch):
    """The local cores stood in for by this process: the calls they get, run here."""
    calls: list[tuple] = []

    def run(fn, args, n_jobs):
        calls.append((fn, list(args), n_jobs))
        return [fn(*a) for a in args]

    monkeypatch.delenv(parallel.DASK_ENV, raising=False)
    monkeypatch.setattr(parallel, "_on_local_cores", run)
    return calls


@pytest.fixture
def cluster(monkeypatch):
    """A Dask cluster at :data:`ADDRESS` stood in for by this process."""
    calls: list[tuple] = []

    def run(address, fn, args):
        calls.append((address, fn, list(args)))
        return [fn(*a) for a in args]

    monkeypatch.setenv(parallel.DASK_ENV, ADDRESS)
    monkeypatch.setattr(parallel, "_on_cluster", run)
    return calls


# -- the arithmetic of rounds -------------------------------------------------------------

@pytest.mark.parametrize("n_jobs, items, expected", [
    (1, 1, 1), (1, 2, 1), (1, 5, 1), (2, 1, 2), (2, 2, 2), (2, 3, 3), (2, 4, 2), (2, 5, 2),
    (3, 3, 3), (3, 4, 4), (3, 5, 5), (3, 6, 3)])
def test_a_round_of_fewer_than_twice_the_cores_runs_one_process_an_item(n_jobs, items,
                                                                        expected):
    assert parallel.processes(n_jobs, items) == expected


@pytest.mark.parametrize("left, width, expected", [
    (1, 2, 2), (2, 2, 2), (3, 2, 3), (4, 2, 2), (5, 2, 2), (1, 1, 1), (2, 1, 1),
    (3, 3, 3), (4, 3, 4), (5, 3, 5), (6, 3, 3), (7, 3, 3)])
def test_a_remainder_of_under_two_rounds_is_one_round(left, width, expected):
    assert parallel.round_size(left, width) == expected


@given(st.integers(1, 40), st.integers(1, 16))
def test_the_wall_time_of_a_round_is_its_items_over_the_cores_it_uses(items, n_jobs):
    """Folded (more processes than cores): the items share the cores, ``items / n_jobs``;
    otherwise whole waves of one job each on ``processes`` processes."""
    running = parallel.processes(n_jobs, items)
    got = parallel.wall(items, n_jobs)
    assert isinstance(got, float)
    if running == items > n_jobs:
        assert got == items / n_jobs and 1 < got < 2
    else:
        assert got == math.ceil(items / running)
    assert got >= items / n_jobs
    if n_jobs == 1:
        assert got == items


def test_the_wall_time_of_some_rounds():
    assert parallel.wall(3, 2) == 1.5 and parallel.wall(4, 2) == 2.0
    assert parallel.wall(1, 2) == 1.0 and parallel.wall(5, 4) == 1.25
    assert parallel.wall(9, 4) == 3.0 and parallel.wall(8, 4) == 2.0 and parallel.wall(3, 1) == 3


# -- where the items run ------------------------------------------------------------------

def test_one_job_or_one_item_runs_here(local, monkeypatch):
    assert parallel.parallel_map(_pair, [(1, 2), (3, 4)], n_jobs=1) == [
        (1, 2, os.getpid()), (3, 4, os.getpid())]
    assert parallel.parallel_map(_pair, [(1, 2)], n_jobs=4) == [(1, 2, os.getpid())]
    assert parallel.parallel_map(_pair, [], n_jobs=4) == []
    assert parallel.parallel_map(_pair, [(5, 6)], n_jobs=4, progress=True) == [
        (5, 6, os.getpid())]
    assert local == []


def test_two_items_and_two_jobs_run_on_the_local_cores_in_order(local, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "path", ["", "relative", str(tmp_path / "absolute")])
    got = parallel.parallel_map(_pair, [(1, 2), (3, 4), (5, 6)], n_jobs=2)
    assert got == [(1, 2, os.getpid()), (3, 4, os.getpid()), (5, 6, os.getpid())]
    [(fn, args, n_jobs)] = local
    assert fn is parallel._here and n_jobs == 2
    here = (str(tmp_path), [str(tmp_path), str(tmp_path / "relative"), str(tmp_path / "absolute")])
    assert args == [(here, _pair, 1, 2), (here, _pair, 3, 4), (here, _pair, 5, 6)]


def test_local_progress_draws_the_items_bars_while_they_run(monkeypatch):
    made = []

    class Bars:
        def __init__(self, items, lines):
            self.items, self.lines, self.open = items, lines, False
            made.append(self)

        def path(self, item):
            return f"status-{item}"

        def __enter__(self):
            self.open = True
            return self

        def __exit__(self, *exc):
            self.open = False

    def run(fn, args, n_jobs):  # the items run inside the bars' block
        assert made[0].open
        return [fn(*a) for a in args]

    monkeypatch.delenv(parallel.DASK_ENV, raising=False)
    monkeypatch.setattr("ibt.engine.worker_progress.WorkerBars", Bars)
    monkeypatch.setattr(parallel, "_on_local_cores", run)
    seen = []
    monkeypatch.setattr(parallel, "_here",
                        lambda here, fn, *args: seen.append(args[0]) or fn(*args))
    got = parallel.parallel_map(_pair, [(1, 2), (3, 4), (5, 6)], n_jobs=2, progress=True)
    assert got == [(1, 2, os.getpid()), (3, 4, os.getpid()), (5, 6, os.getpid())]
    [bars] = made
    assert (bars.items, bars.lines, bars.open) == (3, 2, False)
    assert seen == ["status-0", "status-1", "status-2"]


def test_local_progress_wraps_each_item_in_reporting(local, monkeypatch):
    seen = []
    monkeypatch.setattr(parallel, "_here",
                        lambda here, fn, *args: seen.append((fn, args)) or fn(*args))
    got = parallel.parallel_map(_pair, [(1, 2), (3, 4)], n_jobs=2, progress=True)
    assert got == [(1, 2, os.getpid()), (3, 4, os.getpid())]
    assert [fn for fn, _ in seen] == [reporting, reporting]
    paths = [args[0] for _, args in seen]
    assert [args[1:] for _, args in seen] == [(_pair, 1, 2), (_pair, 3, 4)]
    assert len(set(paths)) == 2 and all(p.endswith(".txt") for p in paths)
    assert not any(os.path.exists(os.path.dirname(p)) for p in paths)  # the folder is gone


def test_an_address_sends_the_items_to_the_cluster_even_with_one_job(local, cluster):
    got = parallel.parallel_map(_pair, [(1, 2), (3, 4)], n_jobs=1)
    assert got == [(1, 2, os.getpid()), (3, 4, os.getpid())]
    [(address, fn, args)] = cluster
    assert address == ADDRESS and fn is parallel._here and local == []
    assert [a[1:] for a in args] == [(_pair, 1, 2), (_pair, 3, 4)]
    assert parallel.parallel_map(_pair, [(1, 2)], n_jobs=4) == [(1, 2, os.getpid())]
    assert len(cluster) == 1  # one item runs here


def test_a_clusters_items_report_progress_nowhere(cluster, monkeypatch):
    seen = []
    monkeypatch.setattr(parallel, "_here",
                        lambda here, fn, *args: seen.append((fn, args)) or fn(*args))
    monkeypatch.setattr("ibt.engine.worker_progress.WorkerBars",
                        lambda *a: pytest.fail("no bars for a cluster"))
    assert parallel.parallel_map(_pair, [(1, 2), (3, 4)], n_jobs=2, progress=True) == [
        (1, 2, os.getpid()), (3, 4, os.getpid())]
    assert seen == [(reporting, (None, _pair, 1, 2)), (reporting, (None, _pair, 3, 4))]


# -- what a worker is handed ----------------------------------------------------------------

def test_a_worker_moves_to_the_callers_folder_and_adds_its_import_path(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "there").mkdir()
    monkeypatch.setattr(sys, "path", ["/a", "/b"])
    got = parallel._here((str(tmp_path / "there"), ["/b", "/c", "/a", "/d"]), _pair, 1, 2)
    assert got == (1, 2, os.getpid())
    assert os.getcwd() == str(tmp_path / "there") and sys.path == ["/a", "/b", "/c", "/d"]


def test_a_worker_without_the_callers_folder_stays_where_it_is(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "path", ["/a"])
    assert parallel._here((str(tmp_path / "absent"), ["/a"]), _pair, 1, 2) == (1, 2, os.getpid())
    assert os.getcwd() == str(tmp_path) and sys.path == ["/a"]


# -- the cluster --------------------------------------------------------------------------

class _Client:
    closed = 0

    def __init__(self, address, timeout):
        self.address, self.timeout = address, timeout

    def close(self):
        type(self).closed += 1


@pytest.fixture
def joblib_dask(monkeypatch):
    """joblib's dask backend stood in for: records the backend and the jobs asked for."""
    asked: dict[str, object] = {}

    @contextlib.contextmanager
    def config(backend):
        asked["backend"] = backend
        yield

    class Parallel:
        def __init__(self, n_jobs):
            asked["n_jobs"] = n_jobs

        def __call__(self, jobs):
            fail = asked.get("fail")
            if fail is not None:
                raise fail
            return (fn(*args, **kwargs) for fn, args, kwargs in jobs)

    monkeypatch.setattr(joblib, "parallel_config", config)
    monkeypatch.setattr(joblib, "Parallel", Parallel)
    _Client.closed = 0
    monkeypatch.setattr(parallel, "dask_client", lambda address: _Client(address, None))
    return asked


def test_the_cluster_runs_every_item_on_all_its_workers(joblib_dask):
    assert parallel._on_cluster(ADDRESS, _pair, [(1, 2), (3, 4)]) == [
        (1, 2, os.getpid()), (3, 4, os.getpid())]
    assert joblib_dask == {"backend": "dask", "n_jobs": -1} and _Client.closed == 1


def test_a_failing_cluster_is_named_and_its_client_closed(joblib_dask):
    joblib_dask["fail"] = OSError("lost\n  the   worker " + "x" * 300)
    with pytest.raises(RuntimeError) as raised:
        parallel._on_cluster(ADDRESS, _pair, [(1, 2)])
    text = str(raised.value)
    assert text.startswith(f"IBT_DASK_SCHEDULER={ADDRESS}: the Dask cluster failed (OSError: "
                           "lost the worker xxx")
    why = text.partition("(")[2].partition(")")[0]
    assert len(why) == 200 and text.endswith("; check the scheduler and its workers, or unset "
                                             "IBT_DASK_SCHEDULER to run on this machine's cores")
    assert raised.value.__suppress_context__ and _Client.closed == 1
    joblib_dask["fail"] = TimeoutError("slow")
    with pytest.raises(RuntimeError, match=r"failed \(TimeoutError: slow\)"):
        parallel._on_cluster(ADDRESS, _pair, [(1, 2)])
    assert _Client.closed == 2


def test_an_items_own_error_passes_through_and_the_client_is_closed(joblib_dask):
    joblib_dask["fail"] = ValueError("the item's own")
    with pytest.raises(ValueError, match="the item's own"):
        parallel._on_cluster(ADDRESS, _pair, [(1, 2)])
    assert _Client.closed == 1


@pytest.fixture
def fake_dask(monkeypatch):
    """``dask.distributed`` whose ``Client`` does what ``behaviour`` says."""
    behaviour: dict[str, object] = {}

    class Client(_Client):
        def __init__(self, address, timeout):
            super().__init__(address, timeout)
            if "sleep" in behaviour:
                time.sleep(behaviour["sleep"])  # type: ignore[arg-type]
            if "hang" in behaviour:
                behaviour["hang"].wait()  # type: ignore[attr-defined]
            if "raise" in behaviour:
                raise behaviour["raise"]  # type: ignore[misc]

    module = types.ModuleType("dask.distributed")
    module.Client = Client  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "dask.distributed", module)
    return behaviour


def test_a_client_is_asked_for_with_the_timeout(fake_dask):
    client = parallel.dask_client(ADDRESS)
    assert (client.address, client.timeout) == (ADDRESS, f"{parallel.DASK_TIMEOUT}s")
    assert parallel.dask_client(ADDRESS, 2).timeout == "2s"
    assert parallel.DASK_TIMEOUT == 30.0


@pytest.mark.parametrize("error", [OSError("refused\n  there"), TimeoutError("refused there"),
                                   ValueError("refused there"), RuntimeError("refused there")])
def test_a_scheduler_that_refuses_is_named_with_the_reason(fake_dask, error):
    fake_dask["raise"] = error
    with pytest.raises(RuntimeError) as raised:
        parallel.dask_client(ADDRESS, 2)
    assert str(raised.value) == (
        f"IBT_DASK_SCHEDULER={ADDRESS}: no Dask scheduler answered within 2 s "
        f"({type(error).__name__}: refused there); start the scheduler there, or unset "
        "IBT_DASK_SCHEDULER to run on this machine's cores")
    assert raised.value.__suppress_context__


def test_a_long_reason_is_cut(fake_dask):
    fake_dask["raise"] = OSError("y" * 500)
    with pytest.raises(RuntimeError) as raised:
        parallel.dask_client(ADDRESS, 2)
    assert len(str(raised.value).partition("(")[2].partition(")")[0]) == 200


def test_another_error_of_the_client_is_raised_as_it_is(fake_dask):
    fake_dask["raise"] = KeyError("odd")
    with pytest.raises(KeyError, match="odd"):
        parallel.dask_client(ADDRESS, 2)


def test_without_dask_the_variable_is_named(monkeypatch):
    monkeypatch.setitem(sys.modules, "dask.distributed", None)
    with pytest.raises(RuntimeError, match=r"IBT_DASK_SCHEDULER=tcp://10\.0\.0\.1:8786: "
                                           r"dask\.distributed is not installed; install it "
                                           r"\(pip install distributed\) or unset "
                                           r"IBT_DASK_SCHEDULER$") as raised:
        parallel.dask_client(ADDRESS)
    assert raised.value.__suppress_context__


def test_a_scheduler_that_answers_within_the_grace_is_used(fake_dask):
    """Dask's own timeout is ``timeout``; the connection is given 5 s more to say so."""
    fake_dask["sleep"] = 3.0
    assert parallel.dask_client(ADDRESS, 0.5).address == ADDRESS


def test_a_scheduler_that_never_answers_fails_after_the_grace(fake_dask):
    fake_dask["hang"] = threading.Event()
    began = time.monotonic()
    try:
        with pytest.raises(RuntimeError) as raised:
            parallel.dask_client(ADDRESS, 0.0)
    finally:
        fake_dask["hang"].set()
    assert time.monotonic() - began >= 5.0
    assert str(raised.value) == (
        f"IBT_DASK_SCHEDULER={ADDRESS}: no Dask scheduler answered within 0 s; start the "
        "scheduler there, or unset IBT_DASK_SCHEDULER to run on this machine's cores")


# -- one real run on the local cores ------------------------------------------------------

def test_the_local_cores_run_the_items_in_other_processes_in_order(monkeypatch):
    monkeypatch.delenv(parallel.DASK_ENV, raising=False)
    got = parallel.parallel_map(_pair, [(1, 2), (3, 4), (5, 6)], n_jobs=2)
    assert [g[:2] for g in got] == [(1, 2), (3, 4), (5, 6)]
    assert os.getpid() not in {g[2] for g in got}
