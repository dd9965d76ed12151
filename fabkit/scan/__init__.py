"""Scans of printed sheets against their targets (``fabkit compare``, docs/compare.md).

:mod:`~fabkit.scan.read` reads a scan and its units, :mod:`~fabkit.scan.targets` the
target at the part's printed size (from a run's folder, or a design alone),
:mod:`~fabkit.scan.align` fits one to the other without correspondences, and
:mod:`~fabkit.scan.compare` gives the verdict. Only the commands import this package.
"""
