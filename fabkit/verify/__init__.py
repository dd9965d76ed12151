"""``fabkit verify``: read a machine file back as a machine would, and check it.

The readers (:mod:`~fabkit.verify.read_gcode`, :mod:`~fabkit.verify.read_dxf`,
:mod:`~fabkit.verify.read_laser`) parse the file that goes to the machine, independently
of the writers and of ``toolpath.npz``, into what it makes on the flat sheet: roads with
their widths and the process values they were printed with, or exposed pixels with
their director and doses. :mod:`~fabkit.verify.raster` turns roads into a grid of the
sheet (coverage, road direction, the values); :mod:`~fabkit.verify.machine_file` reads the
file onto those grids and reports; :mod:`~fabkit.verify.compare_fields` inverts every
channel's calibration to read the features back and compares director, features and
coverage with the design; :mod:`~fabkit.verify.as_fabricated` forward-simulates the
sheet as fabricated under every stimulus (:mod:`fabkit.mechanics.fabricated`) and gives
its verdict.

Called, ``fabkit.verify(design, machine_file)`` is the public API's
:func:`fabkit.api.verify` (``import fabkit`` makes this package callable; docs/api.md).
"""
