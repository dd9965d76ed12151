"""pyserial URL handler for ``sim://marlin`` and ``sim://grbl``: the built-in emulator.

pyserial's ``serial_for_url`` imports ``<package>.protocol_<scheme>`` for each package in
``serial.protocol_handler_packages`` and instantiates its ``Serial`` class;
:mod:`fabkit.link` appends itself to that list, so ``serial.serial_for_url("sim://...")``
opens this class. It runs the emulator lazily on the caller's thread, on the real clock:
reads sleep until the emulated machine has something to say.
"""

from __future__ import annotations

import time

from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from fabkit.link.emulator.port import Emulator, config_from_url

_NAP_S = 0.05  # longest sleep while nothing is scheduled


class Serial(SerialBase):
    """A serial port whose far end is an :class:`~fabkit.link.emulator.port.Emulator`."""

    emulator: Emulator

    def open(self) -> None:
        if self.is_open:
            raise SerialException("port is already open")
        if self._port is None:
            raise SerialException("port must be configured before it can be used")
        try:
            config = config_from_url(str(self._port), int(self._baudrate))
        except ValueError as exc:
            raise SerialException(str(exc)) from None
        self.emulator = Emulator(config, now=time.monotonic())
        self._rx = bytearray()
        self.is_open = True

    def close(self) -> None:
        self.is_open = False

    def _reconfigure_port(self, *args: object) -> None:
        """Nothing to configure: the emulator's baud rate is fixed when it is opened."""

    def _pump(self) -> None:
        if not self.is_open:
            raise PortNotOpenError()
        self._rx += self.emulator.poll(time.monotonic())
        if self.emulator.disconnected and not self._rx:
            raise SerialException("sim: the emulated machine disconnected")

    @property
    def in_waiting(self) -> int:
        self._pump()
        return len(self._rx)

    def read(self, size: int = 1) -> bytes:
        """Up to ``size`` bytes, waiting at most ``timeout`` seconds (None: forever); bytes
        already received are returned without running the emulator."""
        if not self.is_open:
            raise PortNotOpenError()
        if len(self._rx) < size:
            self._wait(size)
        data = bytes(self._rx[:size])
        del self._rx[:size]
        return data

    def _wait(self, size: int) -> None:
        """Run the emulator until ``size`` bytes are in, or ``timeout`` seconds passed."""
        deadline = None if self._timeout is None else time.monotonic() + self._timeout
        self._pump()
        while len(self._rx) < size:
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                break
            wake = min(self.emulator.next_time(), now + _NAP_S)
            if deadline is not None:
                wake = min(wake, deadline)
            if wake > now:
                time.sleep(wake - now)
            self._pump()

    def write(self, data: bytes) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        if self.emulator.disconnected:
            raise SerialException("sim: the emulated machine disconnected")
        data = bytes(data)
        self.emulator.host_write(data, time.monotonic())
        return len(data)

    def reset_input_buffer(self) -> None:
        self._pump()
        self._rx.clear()

    def reset_output_buffer(self) -> None:
        """Written bytes are already on the emulated wire: nothing to discard."""

    @property
    def out_waiting(self) -> int:
        return 0

    def _update_break_state(self) -> None:
        """No break condition on the emulated line."""

    def _update_rts_state(self) -> None:
        """RTS is not wired on the emulated line."""

    def _update_dtr_state(self) -> None:
        """DTR is not wired on the emulated line (no reset on open)."""

    @property
    def cts(self) -> bool:
        return True

    @property
    def dsr(self) -> bool:
        return True

    @property
    def ri(self) -> bool:
        return False

    @property
    def cd(self) -> bool:
        return True
