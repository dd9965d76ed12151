"""Worker processes beside a command, for work on plain data that returns plain data.

:func:`worker` is one worker for a block of the caller's; :func:`parallel_map` spreads
independent calls (a verdict's simulations from several starts) over the cores, in a
pool of workers kept for the life of the process.

``fabkit run`` draws its pictures there (the design's and the toolpath preview, about
2.5 s) while it plans, writes, verifies and sends; drawing is Python-bound, so a thread
would wait for the interpreter lock instead. The work is named by ``"module:function"``:
the worker imports that module, the caller never does (the caller need not load
matplotlib at all). The worker is

- spawned, not forked: a forked copy of a process whose BLAS has started threads can
  hang;
- started at once, importing ``warm`` (the modules its work needs) while the caller
  goes on, so the work starts without that delay;
- deaf to Ctrl-C: the terminal sends the interrupt to both processes, and the caller
  alone answers it (one line, exit 130). The caller holds SIGINT back (blocks it) while
  it starts a worker, and the worker starts with it held (a process inherits the mask of
  the thread that starts it), until :func:`_start` ignores it; so an interrupt during
  the worker's start-up never reaches the worker, and one that comes while the caller
  starts it reaches the caller when it is done (ignoring it there instead lost a Ctrl-C
  that came in those milliseconds: the run went on). Leaving the ``with`` block by an exception
  terminates the worker (else it is kept for the next block). Its work writes no file
  (the caller writes what it returns), so a terminated worker leaves nothing
  half-written.
"""

from __future__ import annotations

import atexit
import importlib
import multiprocessing
import os
import signal
import sys
import threading
import types
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from multiprocessing.pool import AsyncResult, Pool
from typing import Any


class Worker:
    """The worker process of :func:`worker`."""

    def __init__(self, pool: Pool) -> None:
        self._pool = pool

    def start(self, function: str, *args: Any) -> AsyncResult:
        """Start ``function`` (``"module:name"``) on ``args`` in the worker, after the work
        started before it; ``.get()`` on the result waits for its value (or raises its
        exception)."""
        return self._pool.apply_async(_call, (function, args))


class _Pool(Pool):
    """A :class:`multiprocessing.pool.Pool` whose ``terminate()`` cannot hang.

    The pool's feeder thread writes each task to a pipe the workers read. A task larger
    than the pipe holds (64 kB: the toolpath preview's arrays, a simulation's mesh) given
    while every worker is busy leaves the feeder blocked in that write. ``terminate()``
    drains the pipe once, then kills the workers and joins the feeder, which a write
    begun after the drain keeps blocked for ever (CPython issues 73945 and 78178 are of
    this family): a Ctrl-C at that moment hung the run. Here the drain goes on, in a
    thread of its own, until the feeder has ended.
    """

    @staticmethod
    def _help_stuff_finish(inqueue: Any, task_handler: threading.Thread, size: int) -> None:
        inqueue._rlock.acquire()  # as Pool does: no worker takes a task from here on

        def drain() -> None:
            while task_handler.is_alive():
                if inqueue._reader.poll(0.05):
                    inqueue._reader.recv_bytes()

        threading.Thread(target=drain, name="fabkit-pool-drain", daemon=True).start()


_WORKER: Pool | None = None


@contextmanager
def worker(warm: tuple[str, ...] = ()) -> Iterator[Worker]:
    """A spawned worker process that imports ``warm`` (module names) first. It is kept
    for the life of the process and serves the next block too (its start costs about
    1.7 s of CPU: a script or a test that runs many commands pays it once); a block left
    by an exception (Ctrl-C, a failed stage) terminates it, so that nothing of an
    interrupted command goes on."""
    global _WORKER
    if _WORKER is None:
        with _sigint_held(), _main_hidden():
            _WORKER = _Pool(1, _start, (warm,), context=multiprocessing.get_context("spawn"))
        atexit.register(_terminate_worker)
    try:
        yield Worker(_WORKER)
    except BaseException:
        _terminate_worker()
        raise


def _terminate_worker() -> None:
    global _WORKER
    if _WORKER is not None:
        _WORKER.terminate()
        _WORKER = None


@contextmanager
def _main_hidden() -> Iterator[None]:
    """Start workers without the caller's ``__main__``: a spawned worker would run the
    caller's script again to rebuild it (and a script that calls fabkit at its top level,
    without ``if __name__ == "__main__":``, would start workers from there). The work is
    named by module, so the workers need nothing of it."""
    main = sys.modules["__main__"]
    sys.modules["__main__"] = types.ModuleType("__main__")
    try:
        yield
    finally:
        sys.modules["__main__"] = main


@contextmanager
def _sigint_held() -> Iterator[None]:
    """Block SIGINT in the calling thread for the block: processes started in it start
    with SIGINT blocked, and a SIGINT that came meanwhile is delivered at its end."""
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


_POOL: Pool | None = None
WORKERS_ENV = "FABKIT_WORKERS"
"""Environment variable: how many worker processes :func:`parallel_map` may use (default:
the cores this process may run on; 1: none, every call in the caller)."""


def parallel_map(
    function: str,
    calls: list[tuple[Any, ...]],
    warm: tuple[str, ...] = (),
    progress: Callable[[int, int], None] | None = None,
) -> list:
    """``function`` (``"module:name"``) called on each of ``calls`` (argument tuples), in
    order; in a pool of spawned workers (importing ``warm`` first) when there are two
    calls or more and two cores, else in the caller. ``progress(done, total)`` follows
    the calls as they end. The pool is started at the first such call and kept until the
    process ends; its workers ignore Ctrl-C (the caller answers it), and an exception in
    a call is raised here."""
    workers = _workers()
    if workers < 2 or len(calls) < 2:
        results = (_call(function, args) for args in calls)
    else:
        results = _pool(workers, warm).imap(_star_call, [(function, args) for args in calls])
    out = []
    for result in results:
        out.append(result)
        if progress is not None:
            progress(len(out), len(calls))
    return out


def _pool(workers: int, warm: tuple[str, ...]) -> Pool:
    """The pool of :func:`parallel_map`, started at its first use."""
    global _POOL
    if _POOL is None:
        with _sigint_held(), _main_hidden():
            _POOL = _Pool(workers, _start, (warm,), context=multiprocessing.get_context("spawn"))
        atexit.register(_POOL.terminate)
    return _POOL


def _star_call(item: tuple[str, tuple[Any, ...]]) -> Any:
    return _call(*item)


def _workers() -> int:
    """The worker processes :func:`parallel_map` may use (:data:`WORKERS_ENV`)."""
    given = os.environ.get(WORKERS_ENV, "")
    if given.isdigit() and int(given) >= 1:
        return int(given)
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def _call(function: str, args: tuple[Any, ...]) -> Any:
    """``function`` (``"module:name"``) called on ``args``, in the worker."""
    module, name = function.split(":")
    return getattr(importlib.import_module(module), name)(*args)


def _start(warm: tuple[str, ...]) -> None:
    """The worker's start: ignore SIGINT (held since it was started: :func:`_sigint_held`;
    one that came meanwhile is dropped), import ``warm`` (module names)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    for name in warm:
        importlib.import_module(name)
