"""``python -m fabkit``: the command line (see :mod:`fabkit.entry`)."""

from fabkit.entry import run

if __name__ == "__main__":  # not when a spawned worker process imports this module
    run()
