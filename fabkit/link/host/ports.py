"""Opening a port: a device path (``/dev/ttyUSB0``, ``COM3``) or any pyserial URL.

``sim://marlin`` and ``sim://grbl`` reach the built-in emulator through pyserial's URL
handler mechanism (:mod:`fabkit.link.emulator.protocol_sim`), so emulator and hardware share one
code path.
"""

from __future__ import annotations

import serial

import fabkit.link  # noqa: F401  (registers the sim:// handler with pyserial)
from fabkit.errors import FabkitError

SIM_DEFAULT_MACHINES = {"marlin": "marlin_generic", "grbl": "grbl_diw"}


def sim_personality(port: str) -> str | None:
    """``marlin`` / ``grbl`` for a ``sim://`` URL, else None."""
    if not port.lower().startswith("sim://"):
        return None
    return port[len("sim://") :].split("?", 1)[0].strip("/").lower()


def sim_time_scale(port: str) -> float:
    """The ``time_scale`` of a ``sim://`` URL (1 for anything else, or a bad URL)."""
    if sim_personality(port) is None:
        return 1.0
    from fabkit.link.emulator.port import config_from_url

    try:
        return config_from_url(port, 0).time_scale
    except ValueError:
        return 1.0


def default_machine(port: str) -> str:
    """The profile used without --machine: grbl_diw on sim://grbl, else marlin_generic."""
    return SIM_DEFAULT_MACHINES.get(sim_personality(port) or "", "marlin_generic")


def open_port(port: str, baud: int, timeout_s: float = 0.01) -> serial.SerialBase:
    """Open ``port`` at ``baud``; any failure is one FabkitError line."""
    try:
        return serial.serial_for_url(port, baudrate=baud, timeout=timeout_s)
    except (serial.SerialException, ValueError, OSError) as exc:
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise FabkitError(f"cannot open port {port}: {reason}") from None
