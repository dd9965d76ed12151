"""The machine link: the host (:mod:`~fabkit.link.host`: check G-code against a machine
profile, stream it over serial or hand it to a printer host) and the emulated machine
(:mod:`~fabkit.link.emulator`), sharing the G-code words and dialects
(:mod:`~fabkit.gcode.read`, :mod:`~fabkit.link.answers`, :mod:`~fabkit.link.arcs`,
:mod:`~fabkit.gcode.duration`)."""

import serial

# pyserial finds the sim:// handler as module protocol_sim of a registered package
if "fabkit.link.emulator" not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append("fabkit.link.emulator")
