"""Opening a port: a device path (``/dev/ttyUSB0``, ``COM3``) or any pyserial URL.

``sim://marlin`` and ``sim://grbl`` reach the built-in emulator through pyserial's URL
handler mechanism (:mod:`fabkit.link.emulator.protocol_sim`), so emulator and hardware share one
code path. A port that does not open is one line saying why in fabkit's words (no such
device, permission denied, busy, not a serial device, bad URL), from the operating system's
error number rather than pyserial's message; :func:`check_port` refuses what it can
without opening the port (``fabkit run --send``, before the solve).
"""

from __future__ import annotations

import errno
import os
import stat

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
    """Open ``port`` at ``baud`` (bit/s) with a read timeout of ``timeout_s`` (s); any failure
    is one FabkitError line saying why in a few words (:func:`_why_not`)."""
    try:
        return serial.serial_for_url(port, baudrate=baud, timeout=timeout_s)
    except (serial.SerialException, OSError, ValueError, LookupError) as exc:
        # LookupError: pyserial's loop:// handler raises KeyError for an unknown option
        raise FabkitError(f"cannot open port {port}: {_why_not(port, exc)}") from None


def check_port(port: str) -> None:
    """Refuse ``port`` without opening it (opening resets many boards, and a port held open
    is busy for everyone else): a ``sim://`` URL with a bad option, a URL pyserial has no
    handler for, a device path that does not exist, is not a device or may not be opened
    by this user. A FabkitError worded as :func:`open_port`'s."""
    try:
        if sim_personality(port) is not None:
            from fabkit.link.emulator.port import config_from_url

            config_from_url(port, 0)
        elif "://" in port:
            serial.serial_for_url(port, do_not_open=True)
        elif os.name == "posix":  # COM3 and the like are not files
            _check_device(port)
    except (serial.SerialException, OSError, ValueError, LookupError) as exc:
        raise FabkitError(f"cannot open port {port}: {_why_not(port, exc)}") from None


def _check_device(path: str) -> None:
    """OSError unless ``path`` is a character device this user may read and write."""
    if not stat.S_ISCHR(os.stat(path).st_mode):
        raise OSError(errno.ENOTTY, os.strerror(errno.ENOTTY), path)
    if not os.access(path, os.R_OK | os.W_OK):
        raise OSError(errno.EACCES, os.strerror(errno.EACCES), path)


_NO_DEVICE = "no such device"
_DENIED = (
    "permission denied (add your user to the dialout group: sudo usermod -aG dialout $USER, "
    "then log in again)"
)
_BUSY = "busy (another program has it open)"
_REASONS = {
    errno.ENOENT: _NO_DEVICE,
    errno.ENOTDIR: _NO_DEVICE,
    errno.ENODEV: _NO_DEVICE,
    errno.ENXIO: _NO_DEVICE,
    errno.EACCES: _DENIED,
    errno.EPERM: _DENIED,
    errno.EBUSY: _BUSY,
    errno.EAGAIN: _BUSY,
    errno.ENOTTY: "not a serial device",
    errno.EISDIR: "not a serial device",
    errno.EIO: "input/output error (unplug the device and plug it in again)",
}
"""Why a port did not open, by the operating system's error number."""
_BAD_URL = (
    "bad URL (a device path, or a URL pyserial or fabkit knows: socket://HOST:PORT, "
    "rfc2217://HOST:PORT, loop://, sim://marlin, sim://grbl)"
)


def _why_not(port: str, exc: BaseException) -> str:
    """Why ``port`` did not open, in fabkit's own words: from the operating system's error
    behind ``exc``, else the emulator's own sentence for a ``sim://`` URL, else a bad URL
    (a device path always fails with an operating-system error)."""
    cause = _os_error(exc)
    if cause is not None:
        code, text = cause
        return _REASONS.get(code, text[:1].lower() + text[1:])
    if sim_personality(port) is not None and str(exc):
        return str(exc).splitlines()[0]
    return _BAD_URL


def _os_error(exc: BaseException) -> tuple[int, str] | None:
    """The error number and text of the operating-system error behind ``exc``: pyserial
    raises its own exception while handling it (``termios.error`` too has the pair)."""
    for error in (exc.__context__, exc):
        args = getattr(error, "args", ())
        if len(args) >= 2 and isinstance(args[0], int) and isinstance(args[1], str):
            return args[0], args[1]
    return None
