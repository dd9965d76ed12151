"""The console entry point: Ctrl-C during the imports is one line and exit code 130 too.

The ``fabkit`` script calls :func:`run`; this module imports nothing but ``sys`` before
the handler is in place, so an interrupt while the command line and its stages load
(seconds on a cold start) never shows a traceback.
"""

import sys


def run() -> None:
    """Import and run :func:`fabkit.cli.main`; exit with its code."""
    try:
        from fabkit.cli import main

        code = main()
    except KeyboardInterrupt:
        print("fabkit: interrupted", file=sys.stderr)
        code = 130
    sys.exit(code)
