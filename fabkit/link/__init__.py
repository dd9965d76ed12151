"""The machine link: check G-code against a machine profile and stream it over serial."""

import serial

if "fabkit.link" not in serial.protocol_handler_packages:
    serial.protocol_handler_packages.append("fabkit.link")
