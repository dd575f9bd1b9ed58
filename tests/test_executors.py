"""Executors of a session (fit.pipeline.executors): a local process pool, a real Dask
LocalCluster (2 worker processes) and a caller's concurrent.futures executor, each given
tasks that return, raise, kill their own worker or run past the timeout."""

from __future__ import annotations

import os
import time
from concurrent.futures import ProcessPoolExecutor

import distributed  # the test extra installs Dask and psutil (.[test])
import psutil
import pytest
from executor_tasks import blas_share, process_id, square, worker_settings

from fit.pipeline.executors import (
    DASK_MISSING,
    DaskExecutor,
    FuturesExecutor,
    LocalExecutor,
    open_executor,
)
from mocap.errors import InputError

JOBS = [1, "raise", 2, "die", 3, "hang", 4]


@pytest.fixture(scope="module")
def dask_client():
    """A real LocalCluster, 2 worker processes of 1 thread; a worker that dies once too
    often gives its task up (allowed-failures 1) to keep the test short, and no worker
    holds two tasks at once (worker-saturation 1)."""
    import dask
    with dask.config.set({"distributed.scheduler.allowed-failures": 1,
                          "distributed.scheduler.worker-saturation": 1.0}):
        with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                      dashboard_address=None) as cluster, \
                distributed.Client(cluster) as client:
            yield client


@pytest.mark.parametrize("kind", ["local", "dask"])
def test_each_way_a_task_ends_is_an_outcome_and_the_others_go_on(kind, dask_client):
    pool = LocalExecutor(2) if kind == "local" else DaskExecutor(client=dask_client)
    # Dask: the deaths in a run of their own; Dask may put an innocent task on the worker
    # that dies, and with allowed-failures 1 two such deaths give it up too
    runs = [JOBS] if kind == "local" else [[1, "raise", 2, "hang"], ["die"], [3, 4]]
    outcomes = {}
    with pool:
        for jobs in runs:
            outcomes.update({o.job: o for o in pool.map_unordered(square, jobs, shared=2,
                                                                  timeout=4)})
    assert set(outcomes) == set(JOBS)
    for job in (1, 2, 3, 4):
        assert outcomes[job].ok and outcomes[job].result == job ** 2
    assert outcomes["raise"].error == "ValueError: take 'raise' is broken"
    assert "square" in outcomes["raise"].traceback
    assert outcomes["hang"].error == "timed out after 4 s (the per-take timeout)"
    assert 4 <= outcomes["hang"].seconds < 20
    died = outcomes["die"].error
    if kind == "local":
        assert died == "worker process died (SIGKILL) (out of memory?) before the take finished"
    else:                                   # rescheduled once, then given up
        assert died.startswith("every worker that ran it died: KilledWorker")


def test_dask_survives_its_losses(dask_client):
    """After a worker was killed and one restarted for a timeout, both workers serve again."""
    deadline = time.monotonic() + 60
    while len(dask_client.nthreads()) < 2 and time.monotonic() < deadline:
        time.sleep(0.2)
    with DaskExecutor(client=dask_client) as pool:
        assert pool.slots() == 2
        assert sorted(o.result for o in pool.map_unordered(square, [5, 6, 7], shared=3)) == \
            [125, 216, 343]
    assert dask_client.status == "running"           # a caller's client is left open


def test_a_callers_process_pool(dask_client):
    pool = ProcessPoolExecutor(2)
    with FuturesExecutor(pool) as ex:
        outcomes = {o.job: o for o in ex.map_unordered(square, [1, "raise", 2], shared=3)}
    assert outcomes[2].result == 8 and outcomes["raise"].error.startswith("ValueError")
    assert pool.submit(abs, -1).result() == 1            # not shut down: it is the caller's
    pool.shutdown()


def test_a_dask_clients_concurrent_futures_executor(dask_client):
    """client.get_executor(): Dask futures behind a concurrent.futures face."""
    outcomes = {o.job: o for o in FuturesExecutor(dask_client.get_executor()).map_unordered(
        square, [2, "raise"], shared=5)}
    assert outcomes[2].result == 32 and outcomes["raise"].error.startswith("ValueError")


def test_a_killed_process_pool_worker_fails_its_tasks_with_the_reason():
    with ProcessPoolExecutor(1) as pool:
        outcomes = {o.job: o for o in FuturesExecutor(pool).map_unordered(square, ["die"],
                                                                          shared=2)}
    assert outcomes["die"].error.startswith("worker process died: BrokenProcessPool")


def test_serial_local_runs_in_this_process():
    outcomes = list(LocalExecutor(1).map_unordered(lambda job, shared: os.getpid(), [0]))
    assert outcomes[0].result == os.getpid()


@pytest.mark.parametrize("workers, timeout", [(1, None), (1, 60.0), (2, None)])
def test_runs_here_says_where_the_jobs_run(workers, timeout):
    executor = LocalExecutor(workers)
    outcomes = list(executor.map_unordered(process_id, [0], timeout=timeout))
    assert executor.runs_here(timeout) == (outcomes[0].result == os.getpid())
    with ProcessPoolExecutor(1) as pool:
        assert not FuturesExecutor(pool).runs_here()


def test_local_workers_share_the_cores_out():
    """Two workers on the machine's cores: each on half the BLAS's threads (at least one),
    not all of them each (threads waiting for a core the other worker keeps busy)."""
    outcomes = list(LocalExecutor(2).map_unordered(blas_share, [0, 1]))
    share = max(1, (os.cpu_count() or 1) // 2)
    for outcome in outcomes:
        assert outcome.error is None, outcome.error
        blas, workers = outcome.result
        assert blas <= share and workers == blas


def test_the_dask_cluster_of_a_run_leaves_glibc_and_the_task_thread_alone(monkeypatch):
    """The LocalCluster a run starts: its workers on one BLAS thread, without the nanny's
    MALLOC_TRIM_THRESHOLD_ (it fixes glibc's mmap threshold: a take ran 30% slower) and
    without the profiler that samples the task's thread every 10 ms."""
    # a cluster started earlier in this process left the nanny's variables in os.environ
    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)
    with DaskExecutor(workers=1) as pool:
        outcomes = list(pool.map_unordered(worker_settings, [0]))
    assert outcomes[0].error is None, outcomes[0].error
    assert outcomes[0].result == (None, False, 1)


def test_no_local_process_outlives_an_abandoned_run(tmp_path):
    pid_file = tmp_path / "pid"
    run = LocalExecutor(2).map_unordered(square, [1, ("hang", pid_file)], shared=2)
    assert next(run).result == 1
    deadline = time.monotonic() + 20
    while not pid_file.is_file() or not pid_file.read_text():
        assert time.monotonic() < deadline
        time.sleep(0.05)
    hanging = psutil.Process(int(pid_file.read_text()))
    run.close()                                      # a driver that stops early
    hanging.wait(timeout=10)
    assert not hanging.is_running()


@pytest.mark.parametrize("args, match", [
    ({"executor": "slurm"}, r"executor must be one of \['dask', 'local'\], got 'slurm'"),
    ({"executor": "local", "scheduler": "tcp://h:1"},
     r"a scheduler address \(tcp://h:1\) needs executor 'dask', not 'local'"),
    ({"executor": object()}, r"executor must have a submit\(fn, \*args\) method"),
    ({"executor": "local", "workers": 0}, r"workers must be at least 1, got 0"),
])
def test_open_executor_errors(args, match):
    with pytest.raises(InputError, match=match):
        open_executor(**args)


def test_timeout_must_be_positive():
    with pytest.raises(InputError, match=r"timeout must be positive and finite, got -1"):
        list(LocalExecutor(2).map_unordered(square, [1], timeout=-1))


def test_unreachable_scheduler_is_one_line():
    with pytest.raises(InputError, match=r"cannot reach the Dask scheduler at tcp://127\.0\.0"
                                         r"\.1:9: "):
        DaskExecutor(scheduler="tcp://127.0.0.1:9")


def test_dask_missing_says_what_to_install(monkeypatch):
    monkeypatch.setattr("importlib.util.find_spec",
                        lambda name, *a: None if name == "distributed" else True)
    with pytest.raises(InputError, match=r"^executor 'dask' needs dask\.distributed: pip "
                                         r"install 'mocap2mesh\[dask\]'"):
        open_executor("dask")
    assert DASK_MISSING.count("\n") == 0
