"""The batch runner: cases on an executor, one result file per case, for sweeps and studies.

A sweep (:mod:`mbsim.sweep`) and a study (:mod:`mbsim.study`) both run "cases on a process
pool into one file per case"; this module is that part, written once::

    with open_executor(jobs=4) as ex:                     # or open_executor(scheduler=...)
        run_batch(tasks, work, finish, executor=ex, spool_dir=out_dir)

Contract
    1. A *task* is anything with a ``number`` (its place in the batch, for the order in
       which finished tasks are handed back) and ``args`` (a tuple of plain, picklable
       values).
    2. ``work(*task.args)`` runs in a worker: a module-level function (so a process pool
       and Dask can send it) that never raises for a failure of its case (it returns what
       went wrong) and returns a picklable value.
    3. ``finish(task, value)`` runs in this process, in its main thread, once per task, as
       the task finishes (tasks finished together are handed back in ``number`` order);
       ``value`` is what ``work`` returned, or a :class:`WorkerLost` when the worker died
       (killed, out of memory).  It writes the case's file and its record.
    4. Resuming is the caller's: it leaves out of ``tasks`` the cases whose files are up to
       date.

Executors
    :func:`open_executor` opens a local process pool (fork while this process has a single
    thread, so workers start at once with the imports; forkserver otherwise) or the executor
    of a Dask cluster.  Pool workers ignore Ctrl-C (the parent stops them), take SIGTERM at
    its default action, and end themselves within ``ORPHAN_POLL`` s when the parent is gone
    (``kill -9`` of the parent alone).

Spool
    With ``spool_dir``, a local worker pickles its value into a folder
    ``.spool-<pid>-*`` there and sends back only the file name (:func:`run_spooled`): a
    Result is megabytes, and a worker stopped part-way through sending it through the
    pool's pipe leaves half a message on which the pool's result thread waits forever.  A
    spool folder left by a killed batch is removed by the next run into that folder
    (:func:`mbsim.output.hdf5.remove_stale_temporaries`).

Interrupting
    Ctrl-C (SIGINT) or SIGTERM while tasks run sets an event (:func:`stop_requests`); the
    wait loop then cancels the tasks not started, and raises KeyboardInterrupt from a safe
    point (never from inside the executor's locks), after the tasks finished so far have
    been handed to ``finish``.  An executor opened by :func:`open_executor` is then stopped:
    running workers are ended, their results lost.  A second signal raises at once.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import multiprocessing
import os
import pickle
import signal
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from mbsim.errors import MbsimError

POLL = 0.1  # s: how often the wait for tasks looks for a Ctrl-C / SIGTERM
ORPHAN_POLL = 0.5  # s: how often a pool worker checks that its parent is still there
CONNECT_TIMEOUT = 20.0  # s to reach a Dask scheduler


class BatchError(MbsimError):
    """A usage error of a batch (--jobs, --scheduler); exit code 2."""

    exit_code = 2


class Task(Protocol):
    number: int  # place in the batch
    args: tuple  # work(*args) in a worker


@dataclass
class WorkerLost:
    """The value ``finish`` gets for a task whose worker died."""

    message: str  # e.g. "BrokenProcessPool: A process in the process pool was terminated"


# --------------------------------------------------------------------------- executors


def _init_worker() -> None:
    """Pool workers leave Ctrl-C to the parent, which cancels and stops them; SIGTERM (the
    parent's terminate()) ends them, whatever handler a forked worker inherited; and a
    worker whose parent is gone (``kill -9`` of the parent alone) ends itself within
    ORPHAN_POLL s, instead of waiting forever for work on a queue whose other end it holds."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    parent = os.getppid()  # the batch's process, or the forkserver that exits with it

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(ORPHAN_POLL)
        os._exit(1)

    threading.Thread(target=watch, name="mbsim-parent-watch", daemon=True).start()


def _mp_context():
    """fork on Linux while this process has a single thread (workers start at once and
    inherit the imports); otherwise forkserver (spawn where there is none), which re-imports
    the main module in each worker: a script calling the runner needs an
    ``if __name__ == "__main__":`` guard there, as for any process pool."""
    methods = multiprocessing.get_all_start_methods()
    if sys.platform.startswith("linux") and "fork" in methods and threading.active_count() == 1:
        return multiprocessing.get_context("fork")
    return multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")


@contextlib.contextmanager
def open_executor(jobs: int | None = None, scheduler: str | None = None,
                  ncases: int | None = None) -> Iterator[cf.Executor]:  # fmt: skip
    """A concurrent.futures Executor for the cases.

    Without `scheduler`: a process pool of `jobs` workers (default min(CPUs, `ncases`)).
    With `scheduler` (``tcp://host:8786``): the executor of a ``distributed.Client``
    connected to that Dask scheduler; `jobs` is ignored (the cluster's workers decide).
    On leaving, the pool is shut down; after an exception (Ctrl-C) without waiting, and
    running workers are stopped.
    """
    if scheduler:
        try:
            from distributed import Client
        except ImportError:
            raise BatchError("--scheduler needs Dask distributed: pip install 'mbsim[cluster]'") \
                from None
        try:
            client = Client(scheduler, set_as_default=False, timeout=CONNECT_TIMEOUT)
        except (OSError, TimeoutError, ValueError) as exc:
            raise BatchError(f"--scheduler {scheduler}: cannot connect: {exc}") from None
        ex = client.get_executor(pure=False)
        try:
            yield ex
        except BaseException:
            ex.shutdown(wait=False)  # cancels what has not finished
            raise
        finally:
            client.close()
        return
    n = jobs or min(os.cpu_count() or 1, max(ncases or 1, 1))
    if n < 1:
        raise BatchError(f"--jobs {jobs}: expected a positive number")
    ex = cf.ProcessPoolExecutor(max_workers=n, mp_context=_mp_context(),
                                initializer=_init_worker)
    try:
        yield ex
    except BaseException:
        stop_pool(ex)
        raise
    else:
        ex.shutdown(wait=True)


def stop_pool(ex: cf.ProcessPoolExecutor) -> None:
    """Cancel what has not started and end the running workers now."""
    procs = list((getattr(ex, "_processes", None) or {}).values())  # our own workers
    manager = getattr(ex, "_executor_manager_thread", None)  # shutdown() forgets it
    ex.shutdown(wait=False, cancel_futures=True)
    for p in procs:
        if p.is_alive():
            p.terminate()
    for p in procs:
        p.join(timeout=5)
        if p.is_alive():  # did not take SIGTERM
            p.kill()
            p.join()
    # let the pool's result thread see the workers gone and finish now, not in the
    # interpreter's exit (where it races with concurrent.futures' own exit hook)
    if manager is not None:
        manager.join(timeout=10)


@contextlib.contextmanager
def stop_requests() -> Iterator[threading.Event]:
    """An Event set by Ctrl-C (SIGINT) or SIGTERM while the batch waits for tasks.

    Python raises KeyboardInterrupt wherever the main thread happens to be: inside the
    locks of concurrent.futures (a later exit then waits forever on the executor's thread)
    or in a weakref callback (where it is printed and dropped, and the batch goes on). So
    the first signal only sets the event, and the wait loop raises KeyboardInterrupt at a
    safe point; a second one raises at once. SIGTERM (``kill PID``, a batch system's time
    limit) is treated as Ctrl-C. Signals whose handler is not Python's default, and calls
    from another thread, are left alone (the event then stays clear).
    """
    stop = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return

    def handler(signum, frame):
        if stop.is_set():
            raise KeyboardInterrupt
        stop.set()

    defaults = {signal.SIGINT: signal.default_int_handler, signal.SIGTERM: signal.SIG_DFL}
    previous = {}
    try:
        for sig, default in defaults.items():
            if signal.getsignal(sig) is default:
                previous[sig] = signal.signal(sig, handler)
        yield stop
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


# --------------------------------------------------------------------------- spool


def run_spooled(spool: str, number: int, work: Callable, *args) -> str:
    """``work(*args)`` in a local pool worker: the value is pickled to a file in the folder
    `spool` and only its name goes back through the pool's pipe (one write of a few bytes,
    which a signal cannot split; module docstring)."""
    value = work(*args)
    path = os.path.join(spool, f"case{number}.pkl")
    with open(path, "wb") as fh:
        pickle.dump(value, fh, protocol=pickle.HIGHEST_PROTOCOL)
    return path


def _unspool(path: str) -> Any:
    with open(path, "rb") as fh:
        value = pickle.load(fh)
    os.unlink(path)
    return value


# --------------------------------------------------------------------------- the wait loop


def run_batch(tasks: Sequence[Task], work: Callable, finish: Callable[[Task, Any], None],
              jobs: int | None = None, scheduler: str | None = None,
              executor: cf.Executor | None = None,
              spool_dir: Path | None = None) -> None:  # fmt: skip
    """Run ``work(*task.args)`` for every task on an executor, hand each value to
    ``finish(task, value)`` here as it comes (module docstring: contract, interrupting).

    Parameters
    ----------
    tasks : the tasks to run (none: nothing is opened).
    work : module-level function run in the workers.
    finish : called in this thread per finished task, in ``number`` order within the tasks
        found finished together.
    jobs, scheduler : the executor :func:`open_executor` opens (when `executor` is None).
    executor : use this one instead (left open).
    spool_dir : a local pool's workers send their values through a spool folder made
        there (:func:`run_spooled`); None sends them through the pool's pipe.

    Raises
    ------
    KeyboardInterrupt
        Ctrl-C or SIGTERM while tasks ran: every task finished by then was handed to
        `finish`; the others were cancelled or stopped.
    """
    if not tasks:
        return
    with contextlib.ExitStack() as stack:
        local = isinstance(executor, cf.ProcessPoolExecutor) or (
            executor is None and not scheduler)
        # named after this process: a batch killed with kill -9 leaves it, and the next
        # run here removes it (output.hdf5.remove_stale_temporaries); removed after the
        # pool has stopped (an ExitStack exits in reverse order)
        spool = stack.enter_context(tempfile.TemporaryDirectory(
            prefix=f".spool-{os.getpid()}-", dir=spool_dir,
            ignore_cleanup_errors=True)) if local and spool_dir is not None else None
        ex = executor or stack.enter_context(open_executor(jobs, scheduler, len(tasks)))

        def submit(task: Task) -> cf.Future:
            if spool:
                return ex.submit(run_spooled, spool, task.number, work, *task.args)
            return ex.submit(work, *task.args)

        futures = {submit(t): t for t in tasks}
        pending = set(futures)
        try:
            with stop_requests() as stop:  # after submit: forked workers get none
                while pending and not stop.is_set():
                    done, pending = cf.wait(pending, timeout=POLL,
                                            return_when=cf.FIRST_COMPLETED)
                    for fut in sorted(done, key=lambda f: futures[f].number):
                        try:
                            value = fut.result()
                            value = _unspool(value) if spool else value
                        except Exception as exc:  # the worker died (killed, no memory)
                            value = WorkerLost(f"{type(exc).__name__}: {exc}")
                        finish(futures[fut], value)
                if stop.is_set():
                    raise KeyboardInterrupt
        except BaseException:
            for fut in futures:
                fut.cancel()
            raise
