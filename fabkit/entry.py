"""The console entry point: Ctrl-C during the imports is one line and exit code 130 too.

The ``fabkit`` script calls :func:`run`; this module imports nothing but built-in modules
before the handler is in place, so an interrupt while the command line and its stages
load (seconds on a cold start) never shows a traceback.
"""

import atexit
import gc
import os
import sys

BLAS_THREADS = "1"
"""OpenBLAS threads of a command (``OPENBLAS_NUM_THREADS``, unless set already): fabkit's
linear algebra is sparse or small, its parallel work is in processes (the simulations'
pool, the pictures' worker), and OpenBLAS's idle threads spin. On this 2-core machine,
beside other work, the README's main command took 35-48 s with them and 26-27 s
without (user CPU 33-46 s -> 26 s), and the first barycentric transform of a Delaunay
triangulation (scipy's own OpenBLAS) took 0.5 s to start its threads, 3 ms without."""


def one_blas_thread() -> None:
    """:data:`BLAS_THREADS` for OpenBLAS, unless the environment says otherwise: read when
    a BLAS library loads, so called before numpy and scipy load (spawned workers inherit
    the environment)."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", BLAS_THREADS)


def run() -> None:
    """Import and run :func:`fabkit.cli.main`; exit with its code."""
    # At exit the interpreter collects garbage several times while it takes the modules
    # down, each time walking every object a run made (0.6 s after ``fabkit run``). The
    # process ends anyway: freeze them first (exit handlers still run, files are closed).
    atexit.register(gc.freeze)
    # A stage's line reaches a pipe or a log as it is printed (`fabkit run | tee log`), not
    # at the next 8 kB: the progress is what a reader of the log waits for.
    if hasattr(sys.stdout, "reconfigure"):
        sys.stdout.reconfigure(line_buffering=True)
    one_blas_thread()
    try:
        from fabkit.cli import main

        code = main()
    except KeyboardInterrupt:
        print("fabkit: interrupted", file=sys.stderr)
        code = 130
    sys.exit(code)
