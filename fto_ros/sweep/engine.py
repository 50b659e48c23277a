"""Where the runs of a sweep (or of the main job) execute: in this process, in local worker
processes, or on an existing Dask distributed cluster.  One interface for the three:

    with Engine(workers=4) as engine:                 # or Engine(scheduler="tcp://host:8786")
        results = engine.map(fn, [(a1, b1), (a2, b2)], costs=[2.0, 1.0], on_done=print)

``fn`` must be a module-level function of an installed package (it is sent by reference)
and should return its failures as values; ``map`` returns the results in the order of the
argument tuples.  A task that does not come back (its worker process died, the cluster lost
it, the worker could not import it) is a :class:`Lost` in its place, never the end of the
map.  Tasks start in the order of decreasing ``costs`` (longest first: the last task to
finish is then a short one, which keeps every worker busy to the end).

- ``workers == 1``: in this process, one task after the other (no pool, no pickling).
- ``workers > 1``: a :class:`concurrent.futures.ProcessPoolExecutor` of that many processes
  (forkserver start method where the platform has it, with the replay code preloaded, so a
  new worker starts in milliseconds).  Nothing listens on the network.  A worker process
  that dies breaks the pool: the tasks that were running then are rerun one at a time, each
  alone in a new process (the one that dies again is a :class:`Lost`), and the others go to
  a new pool.
- ``scheduler``: a :class:`distributed.Client` connected to the scheduler at that address;
  each task is one ``Client.submit`` (Dask schedules, retries on worker loss and moves the
  data).  Before anything is submitted the engine reaches the scheduler (sweep/cluster.py:
  every failure one :class:`EngineError` line within the connect timeout) and checks that
  the cluster has workers, that they can import ``fto_ros``, and
  (:meth:`Engine.missing_paths`) that they see the files.  A scheduler lost during the map
  ends it at once: the tasks not done are :class:`Lost`, and :attr:`Engine.lost` says why.
"""
from __future__ import annotations

import asyncio
import multiprocessing
import os
import socket
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any, Callable, Sequence

from ..core.command_line import one_line
from .cluster import EngineError, client, quiet_dask, reach

#: seconds to wait for the scheduler to answer, and for a cluster to have a worker (the
#: default of fto-sweep's --connect-timeout)
CONNECT_TIMEOUT_S = 10.0

#: modules a forkserver imports once, before it forks the local workers
PRELOAD = ["fto_ros.replay.replay", "fto_ros.sweep.tasks"]


@dataclass(frozen=True)
class Lost:
    """In place of the result of a task that did not come back."""

    message: str


def _lost(err: BaseException) -> Lost:
    return Lost(f"{type(err).__name__}: {one_line(err)}")


def default_workers() -> int:
    """One worker per core this process may run on (its CPU affinity, else the machine's
    core count)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def where() -> str:
    """``host:pid`` of the process running a task (the 'worker' of a result)."""
    return f"{socket.gethostname()}:{os.getpid()}"


# ----------------------------------------------------------------- local worker processes
_started = None  # in a local worker: a flag per task, set as the task starts


def _init_local_worker(flags) -> None:
    global _started
    _started = flags


def _tracked(fn: Callable, index: int, args: tuple):
    """Run ``fn(*args)`` in a local worker, first telling the parent that ``index`` started
    (after a worker died, the tasks that were running can then be told from the queued)."""
    _started[index] = 1   # a byte in shared memory: a worker killed at any moment leaves no
    #                       half-written message (nor a held lock) behind
    return fn(*args)


def _context():
    methods = multiprocessing.get_all_start_methods()
    if "forkserver" in methods:
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(PRELOAD)
        return ctx
    return multiprocessing.get_context("spawn")


def prestart(workers: int | None, scheduler: str | None = None) -> None:
    """Start the forkserver of the local worker processes now, so that it imports
    :data:`PRELOAD` while this process still imports and plans (both pay the same imports:
    done one after the other they were the start-up of a small sweep).  Nothing for one
    worker, a cluster, or a platform without forkserver."""
    if scheduler is not None or (workers or default_workers()) <= 1:
        return
    if "forkserver" in multiprocessing.get_all_start_methods():
        from multiprocessing import forkserver
        _context()
        forkserver.ensure_running()


def _missing(paths: Sequence[str]) -> list[str]:
    """The paths this process cannot see (run on every Dask worker: a worker without fto_ros
    cannot even load this function)."""
    return [p for p in paths if not os.path.exists(p)]


class Engine:
    """Runs tasks in this process, in local worker processes or on a Dask cluster."""

    def __init__(self, workers: int | None = None, scheduler: str | None = None,
                 connect_timeout: float = CONNECT_TIMEOUT_S):
        if workers is not None and workers < 1:
            raise EngineError(f"workers must be >= 1, got {workers}")
        self.scheduler = scheduler
        self.workers = workers or default_workers()
        self.connect_timeout = float(connect_timeout)
        self.client = None
        self._n_cluster_workers = 0
        #: why a map ended early (the scheduler was lost), else None
        self.lost: str | None = None

    # -- connection --------------------------------------------------------------------
    def __enter__(self) -> "Engine":
        if self.scheduler is not None:
            self._connect()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self.client is not None:
            client, self.client = self.client, None
            try:
                client.close(timeout=self.connect_timeout)
            except Exception:  # noqa: BLE001  closing a lost connection: nothing left to do
                pass

    def _connect(self) -> None:
        address, timeout = self.scheduler, self.connect_timeout
        reach(address, timeout)    # refused, unreachable, unknown: one line within the timeout
        quiet_dask()
        self.client = client(address, timeout)
        try:
            self.client.wait_for_workers(1, timeout=timeout)
        except (OSError, TimeoutError) as err:
            self.close()
            raise EngineError(f"the Dask cluster at {address} has no worker (waited "
                              f"{timeout:g} s): {one_line(err) or 'timeout'}") from None
        answers = self.client.run(_missing, [], on_error="return")
        for worker, answer in answers.items():
            if isinstance(answer, BaseException):
                self.close()
                raise EngineError(f"Dask worker {worker} cannot run fto_ros "
                                  f"({_lost(answer).message}): install the package (same "
                                  "version) on every worker")
        self._n_cluster_workers = len(answers)

    @property
    def description(self) -> str:
        if self.client is not None:
            return f"Dask cluster at {self.scheduler} ({self._n_cluster_workers} worker(s))"
        if self.workers == 1:
            return "this process (1 worker)"
        return f"{self.workers} local worker processes"

    # -- data --------------------------------------------------------------------------
    def missing_paths(self, paths: Sequence[str]) -> dict[str, list[str]]:
        """``{worker: [paths it cannot see]}`` for the workers that miss some (local
        workers see what this process sees)."""
        if self.client is None:
            answers = {where(): _missing(paths)}
        else:
            answers = self.client.run(_missing, list(paths), on_error="return")
        return {worker: list(paths) if isinstance(missing, BaseException) else missing
                for worker, missing in answers.items() if missing}

    def share(self, obj: Any) -> Any:
        """A handle to pass ``obj`` to many tasks: on a cluster it is sent once to every
        worker (``Client.scatter(broadcast=True)``: the tasks then spread over all workers
        instead of queueing where the data is) instead of with every task; locally ``obj``."""
        if self.client is None:
            return obj
        return self.client.scatter([obj], broadcast=True, hash=False)[0]

    # -- running -----------------------------------------------------------------------
    def map(self, fn: Callable, arglists: Sequence[tuple], *, costs: Sequence[float] | None = None,
            on_done: Callable[[int, Any], None] | None = None) -> list:
        """``[fn(*args) for args in arglists]``, run as the engine runs things; a task that
        does not come back is a :class:`Lost`.  ``on_done(index, result)`` as each ends."""
        n = len(arglists)
        order = sorted(range(n), key=lambda i: -costs[i]) if costs is not None else list(range(n))
        done = on_done or (lambda i, r: None)
        if self.client is not None:
            return self._map_dask(fn, arglists, order, done)
        if self.workers == 1 or n <= 1:
            return self._map_here(fn, arglists, order, done)
        return self._map_pool(fn, arglists, order, done)

    @staticmethod
    def _map_here(fn, arglists, order, done) -> list:
        results: list = [None] * len(arglists)
        for i in order:
            try:
                results[i] = fn(*arglists[i])
            except Exception as err:  # noqa: BLE001  one task's failure is its result
                results[i] = _lost(err)
            done(i, results[i])
        return results

    def _map_pool(self, fn, arglists, order, done) -> list:
        results: dict[int, Any] = {}

        def finish(i: int, result: Any) -> None:
            results[i] = result
            done(i, result)

        ctx = _context()
        todo = list(order)
        while todo:
            started = self._round(ctx, fn, arglists, todo, self.workers, finish)
            left = [i for i in todo if i not in results]
            # a worker died: rerun the tasks that were running then, each alone, so that
            # only the one that kills its worker is lost (all of them if none said so)
            for i in [i for i in left if i in started] or left:
                self._round(ctx, fn, arglists, [i], 1, finish)
                if i not in results:
                    finish(i, Lost("its worker process died while running it (out of memory? "
                                   "a crash in a library?)"))
            todo = [i for i in left if i not in results]
        return [results[i] for i in range(len(arglists))]

    @staticmethod
    def _round(ctx, fn, arglists, todo, workers, finish) -> set[int]:
        """Run ``todo`` on a new pool of ``workers`` processes until all are done or a worker
        dies (the pool is then broken); ``finish`` each result.  The indices that started."""
        flags = ctx.RawArray("B", len(arglists))
        # the pool's workers are the children this process starts from here on
        others = set(multiprocessing.active_children())
        pool = ProcessPoolExecutor(min(workers, len(todo)), mp_context=ctx,
                                   initializer=_init_local_worker, initargs=(flags,))
        broken = False
        try:
            futures: dict = {}
            for i in todo:
                try:
                    futures[pool.submit(_tracked, fn, i, arglists[i])] = i
                except BrokenProcessPool:         # a worker died while the rest was submitted:
                    broken = True                 # the unsubmitted tasks go to the next round
                    break
            pending = set(futures)
            while pending and not broken:
                finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                for f in finished:
                    err = f.exception()
                    if isinstance(err, BrokenProcessPool):
                        broken = True
                    else:
                        finish(futures[f], f.result() if err is None else _lost(err))
        finally:
            if broken:
                # CPython 3.11's broken pool joins its surviving workers, which wait on the
                # call queue for ever (a sweep hung within 1-25 worker deaths): end them
                for p in set(multiprocessing.active_children()) - others:
                    p.kill()
            pool.shutdown(wait=True, cancel_futures=True)
        return {i for i in todo if flags[i]}

    def _map_dask(self, fn, arglists, order, done) -> list:
        from distributed import as_completed
        n = len(arglists)
        futures = {self.client.submit(fn, *arglists[i], pure=False, priority=n - rank): i
                   for rank, i in enumerate(order)}
        results: list = [None] * n
        finished: set[int] = set()
        try:
            for f in as_completed(futures, loop=self.client.loop):
                i = futures[f]
                try:
                    results[i] = f.result()
                except (Exception, asyncio.CancelledError) as err:  # noqa: BLE001
                    if self.client.status != "running":       # the scheduler is gone
                        self.lost = (f"lost the connection to the Dask scheduler at "
                                     f"{self.scheduler} (status {self.client.status})")
                        break
                    results[i] = Lost(f"the cluster could not run it: {_lost(err).message}")
                f.release()
                finished.add(i)
                done(i, results[i])
        finally:
            for f in futures:
                if not f.done():
                    f.cancel()
        if self.lost is not None:
            for i in sorted(set(range(n)) - finished):
                results[i] = Lost(f"not run: {self.lost}")
                done(i, results[i])
        return results
