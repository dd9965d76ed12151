"""One worker process beside a command, for work on plain data that returns plain data.

``fabkit run`` draws its design pictures there (:func:`fabkit.plot.draw_design`, about
2 s) while it plans, writes, verifies and sends; drawing is Python-bound, so a thread
would wait for the interpreter lock instead. The worker is

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
from multiprocessing.pool import Pool


@contextmanager
def worker(warm: tuple[str, ...] = ()) -> Iterator[Pool]:
    """A pool of one spawned worker that has imported ``warm`` (module names); give it
    work with ``apply_async``. It is terminated when the block ends."""
    context = multiprocessing.get_context("spawn")
    with _sigint_ignored():
        pool = context.Pool(1, initializer=_start, initargs=(warm,))
    with pool:
        yield pool


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


def _start(warm: tuple[str, ...]) -> None:
    """The worker's start: ignore SIGINT, import ``warm`` (module names)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for name in warm:
        importlib.import_module(name)
