"""Sub-commands of the ``fabkit`` CLI, one module each, discovered by :mod:`fabkit.cli`.

A module here defines ``register(subparsers)`` and nothing with logic of its own.
"""
