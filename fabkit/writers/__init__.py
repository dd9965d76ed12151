"""Writers: toolpaths and director fields as machine files.

* :mod:`fabkit.writers.gcode` -- G-code for printers and dispensers (Marlin, Klipper,
  RepRapFirmware, GRBL, Hyrel), checked against the machine profile before writing;
  its stages are ``gcode_setup``, ``gcode_rows``, ``gcode_checks`` and ``gcode_header``.
* :mod:`fabkit.writers.dxf` -- DXF drawings (paths, travels, channels, outline, inlet).
* :mod:`fabkit.writers.laser` -- photoalignment patterns: angle and dose maps, binned DMD
  masks with a JSON manifest, scan lines for scanning writers.

Every writer works in the sheet frame (mm), places the result on the machine
(:mod:`fabkit.writers.common`), refuses anything outside the envelope or above a limit
before writing, and writes atomically.
"""
