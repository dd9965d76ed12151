"""``python -m fabkit``: the command line (see :mod:`fabkit.entry`)."""

from fabkit.entry import run

run()
