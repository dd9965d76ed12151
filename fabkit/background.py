"""One worker process beside a command, for work on plain data that returns plain data.

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
  alone answers it (one line, exit 130). The worker starts with SIGINT ignored (an
  ignored signal stays ignored in a process its creator starts), so not even an
  interrupt during its own start-up reaches it; the caller ignores Ctrl-C only while it
  starts the worker (milliseconds). Leaving the ``with`` block terminates the worker.
  Its work writes no file (the caller writes what it returns), so a terminated worker
  leaves nothing half-written.
"""

from __future__ import annotations

import importlib
import multiprocessing
import signal
import threading
from collections.abc import Iterator
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


@contextmanager
def worker(warm: tuple[str, ...] = ()) -> Iterator[Worker]:
    """A spawned worker process that imports ``warm`` (module names) first. It is
    terminated when the block ends."""
    context = multiprocessing.get_context("spawn")
    with _sigint_ignored():
        pool = context.Pool(1, initializer=_start, initargs=(warm,))
    with pool:
        yield Worker(pool)


@contextmanager
def _sigint_ignored() -> Iterator[None]:
    """Ignore SIGINT in the block (signal handlers can only be set in the main thread;
    elsewhere the worker's :func:`_start` ignores it, once it runs)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _call(function: str, args: tuple[Any, ...]) -> Any:
    """``function`` (``"module:name"``) called on ``args``, in the worker."""
    module, name = function.split(":")
    return getattr(importlib.import_module(module), name)(*args)


def _start(warm: tuple[str, ...]) -> None:
    """The worker's start: ignore SIGINT, import ``warm`` (module names)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for name in warm:
        importlib.import_module(name)
