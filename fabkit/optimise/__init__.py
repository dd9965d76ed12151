"""``fabkit optimise``: search a spec's initial data for the most coverage (docs/optimise.md).

:mod:`~fabkit.optimise.space` (what varies), :mod:`~fabkit.optimise.objective` (what a
candidate scores), :mod:`~fabkit.optimise.search` (differential evolution on a process
pool or a Dask cluster, with a checkpoint), :mod:`~fabkit.optimise.run` (the command's
work and its files), :mod:`~fabkit.optimise.pictures`, :mod:`~fabkit.optimise.tomlout`.
"""
