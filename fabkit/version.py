"""fabkit's version: in the header of every machine file it writes and in ``--version``."""

__version__ = "0.1.0"
