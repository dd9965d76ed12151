"""The bilayer swimmer: a disc that cycles through shapes and swims at low Reynolds number.

:mod:`fabkit.swimmer.stokes` is the hydrodynamics (regularised Stokeslets),
:mod:`fabkit.swimmer.motion` sums the rigid motion over a sequence of shapes,
:mod:`fabkit.swimmer.cycle` is the stimulus path and the shapes along it.
"""
