"""The console entry point: Ctrl-C during the imports is one line and exit code 130 too.

The ``fabkit`` script calls :func:`run`; this module imports nothing but built-in modules
before the handler is in place, so an interrupt while the command line and its stages
load (seconds on a cold start) never shows a traceback.
"""

import atexit
import gc
import sys


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
    try:
        from fabkit.cli import main

        code = main()
    except KeyboardInterrupt:
        print("fabkit: interrupted", file=sys.stderr)
        code = 130
    sys.exit(code)
