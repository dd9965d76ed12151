"""OctoPrint's VirtualPrinter, an outside model of Marlin, behind a pyserial-like port.

``octoprint.plugins.virtual_printer.virtual.VirtualPrinter`` is the Marlin emulation
OctoPrint's authors test OctoPrint against. Used here as a library (no OctoPrint server,
no network): :class:`VirtualPrinterPort` gives it the face of a pyserial port, so that
fabkit's sender, or any hand-written client, talks to it as to a printer::

    with VirtualPrinterPort(simulated_errors=[], rxBuffer=16) as port:
        port.write(b"N0 M110 N0*125\\n")
        ...
    port.executed  # the commands VirtualPrinter ran, in order
    port.accepted  # the line numbers it took as received, in order

Everything VirtualPrinter writes (its virtual SD card, ``eeprom.json``) goes to a
temporary folder, removed on close unless the caller passed its own ``folder``.

Three things VirtualPrinter does that a real serial line does not, and what the port
makes of them:

* it takes one *line* per item of its receive queue and keeps the rest of an item for
  later, so two lines in one ``write`` would be answered one line late; the port hands
  it one line per item, as OctoPrint writes (a serial line carries bytes, not writes);
* its ``write`` holds its ``_incoming_lock`` while it waits for room in the receive
  queue, and its reader needs that lock to ask for a resend: a writer waiting on a full
  queue and a resend request block each other until the write times out. The port waits
  for room itself, with the lock free, and hands VirtualPrinter only what fits;
* lines come out of ``readline`` mostly without their ``\\n``; the port adds it.

Quirks of the model itself, which a sender's test must allow for (OctoPrint 1.11.8;
``test_virtual_printer_port.py`` pins the first two down):

* ``105:resend_with_timeout`` (a default simulated error) answers the first ``N105``
  with ``Resend:105``/``ok``, then drops the next line unseen and counts 105 as
  received: a resent ``N105`` gets ``expected line 106 got 105``. Whatever a host
  sends as ``N105`` after the request never runs;
* a real checksum error is answered with ``Resend:`` one more than the checksummed
  lines it counted since ``M110``, which runs ahead of the line number after every
  earlier resend: that line is then counted as received and never runs;
* ``110:missing_lineno`` sends its ``Error:`` with neither ``Resend:`` nor ``ok``;
* moves run at a tenth of their duration in a planner thread (``commandBuffer`` deep);
  ``ok`` comes once a move is queued, so a job of long moves is planner-bound.
"""

from __future__ import annotations

import copy
import multiprocessing
import os
import queue
import re
import select
import tempfile
import threading
import time
import tty
from collections.abc import Iterator, Sequence
from typing import Any
from unittest import mock

import serial
from octoprint.plugins.virtual_printer import VirtualPrinterPlugin, virtual

from fabkit.gcode.read import frame_marlin

DEFAULT_SETTINGS: dict[str, Any] = VirtualPrinterPlugin().get_settings_defaults()
"""The virtual printer plugin's defaults, as OctoPrint starts it."""

_READ_TIMEOUT_S = 0.02  # VirtualPrinter's own readline timeout (the pump's wake-up period)
_STOP_TIMEOUT_S = 10.0  # longest close() waits for a VirtualPrinter thread
_CONSTRUCTION = threading.Lock()  # one construction at a time (plugin manager stand-in)


def _merged(defaults: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """``defaults`` with ``overrides`` applied, nested dicts merged key by key."""
    result = copy.deepcopy(defaults)
    for key, value in overrides.items():
        if isinstance(value, dict) and isinstance(result.get(key), dict):
            result[key] = _merged(result[key], value)
        else:
            result[key] = copy.deepcopy(value)
    return result


class _Settings:
    """The part of OctoPrint's ``PluginSettings`` that VirtualPrinter reads."""

    def __init__(self, values: dict[str, Any], basefolder: str) -> None:
        self._values = values
        self._basefolder = basefolder

    def get(self, path: Sequence[str], merged: bool = False) -> Any:
        value: Any = self._values
        for key in path:
            if not isinstance(value, dict) or key not in value:
                return None
            value = value[key]
        return value

    def get_int(self, path: Sequence[str]) -> int | None:
        value = self.get(path)
        return None if value is None else int(value)

    def get_float(self, path: Sequence[str]) -> float | None:
        value = self.get(path)
        return None if value is None else float(value)

    def get_boolean(self, path: Sequence[str]) -> bool:
        return bool(self.get(path))

    def global_get_basefolder(self, name: str) -> str:
        folder = os.path.join(self._basefolder, name)
        os.makedirs(folder, exist_ok=True)
        return folder


class _NoPrinterProfiles:
    """Stands in for OctoPrint's printer profile manager (read by ``m115ReportArea``)."""

    def get_current_or_default(self) -> dict[str, Any]:
        return {}


class _NoPlugins:
    """Stands in for OctoPrint's plugin manager while VirtualPrinter is built.

    VirtualPrinter asks it once, in ``__init__``, for the
    ``octoprint.plugin.virtual_printer.custom_action`` hooks, and never uses the answer
    (``_action_hooks`` is read nowhere in OctoPrint 1.11)."""

    def get_hooks(self, name: str) -> dict[str, Any]:
        return {}


class _RecordingPrinter(virtual.VirtualPrinter):
    """VirtualPrinter noting the commands it runs and the line numbers it takes.

    *Executed*: VirtualPrinter dispatches a command matching ``^([GMTF])(\\d+)`` to
    ``_gcode_<letter>(code, data)`` first, if the class has one, and then to
    ``_gcode_<command>(data)``; it gets there only after its line number, checksum,
    simulated-error, lock and debug checks. Defining the ``G`` and ``M`` letter handlers
    (and wrapping the existing ``T`` and ``F``) records each such command, stripped of
    ``N`` and checksum, and returns ``None`` so that dispatch goes on unchanged. Nothing
    is patched: the hook is per instance, by subclassing.

    *Accepted*: every time ``lastN`` (the last line number it has taken) moves on by
    exactly one, the new number is noted: the lines VirtualPrinter says it received, as
    the next ``ok`` and the next ``Resend:`` will count them.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.executed: list[str] = []
        self.accepted: list[int] = []
        self._last_n = 0
        super().__init__(*args, **kwargs)

    @property
    def lastN(self) -> int:
        return self._last_n

    @lastN.setter
    def lastN(self, value: int) -> None:
        if value == self._last_n + 1:
            self.accepted.append(value)
        self._last_n = value

    def _gcode_G(self, code: str, data: str) -> None:
        self.executed.append(data)

    _gcode_M = _gcode_G

    def _gcode_T(self, code: str, data: str) -> None:
        self.executed.append(data)
        super()._gcode_T(code, data)

    def _gcode_F(self, code: str, data: str) -> bool:
        self.executed.append(data)
        return super()._gcode_F(code, data)


def _lines(data: bytes) -> Iterator[bytes]:
    """``data`` cut after each ``\\n`` (the last piece may lack one)."""
    start = 0
    while start < len(data):
        end = data.find(b"\n", start)
        end = len(data) if end < 0 else end + 1
        yield data[start:end]
        start = end


class VirtualPrinterPort:
    """A VirtualPrinter that looks like an open pyserial port; a context manager.

    Keyword arguments other than the four below override VirtualPrinter's settings
    (:data:`DEFAULT_SETTINGS`; nested dicts such as ``errors`` are merged, an unknown
    name is a ``TypeError``): ``simulated_errors=[]`` turns the simulated line errors
    off, ``rxBuffer=16`` shrinks its receive queue (bytes), ``commandBuffer`` is its
    planner depth, ``simulateReset=False`` drops the boot banner.

    ``folder``: where VirtualPrinter keeps its SD card and EEPROM (default: a temporary
    folder, removed on close). ``timeout``: the read timeout (s; ``None`` waits
    forever, as in pyserial). ``write_timeout``: how long ``write`` waits for room in
    the receive queue before ``serial.SerialTimeoutException``. ``late``: the first line
    written that starts with these bytes reaches VirtualPrinter only together with the
    next line, right before it (a firmware busy when the line arrives reads both later).

    The boot banner (``start`` ...) is waiting to be read when the constructor returns.
    """

    def __init__(
        self,
        *,
        folder: str | os.PathLike[str] | None = None,
        timeout: float | None = 1.0,
        write_timeout: float | None = 10.0,
        late: bytes | None = None,
        **settings_overrides: Any,
    ) -> None:
        unknown = sorted(set(settings_overrides) - set(DEFAULT_SETTINGS))
        if unknown:
            raise TypeError(f"not VirtualPrinter settings: {', '.join(unknown)}")
        self.timeout = timeout
        self.write_timeout = write_timeout
        self.settings = _merged(DEFAULT_SETTINGS, settings_overrides)
        self._tempdir = None if folder is not None else tempfile.TemporaryDirectory()
        self.folder = os.fspath(folder) if folder is not None else self._tempdir.name
        self._rx = bytearray()
        self._rx_ready = threading.Condition()
        self._write_lock = threading.Lock()
        self._pump_error: BaseException | None = None
        self._stop = threading.Event()
        self._closed = False
        self._late = late
        self._held: bytes | None = None

        try:
            with _CONSTRUCTION, mock.patch.object(virtual, "plugin_manager", _NoPlugins):
                before = set(threading.enumerate())
                self.printer = _RecordingPrinter(
                    _Settings(self.settings, self.folder),
                    _NoPrinterProfiles(),
                    self.folder,
                    read_timeout=_READ_TIMEOUT_S,
                    write_timeout=write_timeout if write_timeout is not None else 1e9,
                )
                started = [t for t in threading.enumerate() if t not in before]
        except BaseException:  # it starts its threads last: nothing to stop
            if self._tempdir is not None:
                self._tempdir.cleanup()
            raise
        self._threads = [t for t in started if t.name.startswith("octoprint.plugins.")]

        while self.printer.outgoing.qsize():  # the boot banner, before the first read
            self._rx += self._complete(self.printer.readline())
        self._pump = threading.Thread(target=self._run_pump, name="VirtualPrinterPort pump")
        self._pump.start()

    # -- what VirtualPrinter did --------------------------------------------------------

    @property
    def executed(self) -> list[str]:
        """The commands VirtualPrinter ran, in order, without ``N`` and checksum.

        A numbered ``M110`` only sets the line number and is not listed; neither is a
        line VirtualPrinter refused (wrong number or checksum, a simulated error) nor
        one it dropped unseen (after ``resend_with_timeout``)."""
        return list(self.printer.executed)

    @property
    def accepted(self) -> list[int]:
        """The line numbers VirtualPrinter took as received, in order (see
        :class:`_RecordingPrinter`); ``M110`` resets are not listed."""
        return list(self.printer.accepted)

    # -- the pyserial face ----------------------------------------------------------------

    @property
    def is_open(self) -> bool:
        return not self._closed

    @property
    def in_waiting(self) -> int:
        """Bytes received and not yet read."""
        self._check_open()
        with self._rx_ready:
            return len(self._rx)

    def read(self, size: int = 1) -> bytes:
        """Up to ``size`` bytes: returns when it has ``size``, or when ``timeout`` is up."""
        self._check_open()
        deadline = None if self.timeout is None else time.monotonic() + self.timeout
        with self._rx_ready:
            while len(self._rx) < size and not self._closed and self._pump_error is None:
                if deadline is None:
                    self._rx_ready.wait()
                    continue
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                self._rx_ready.wait(remaining)
            data = bytes(self._rx[:size])
            del self._rx[:size]
        if not data and self._pump_error is not None:
            raise serial.SerialException("VirtualPrinter failed") from self._pump_error
        return data

    def readline(self) -> bytes:
        """Bytes up to and including the next ``\\n``, or what came before ``timeout``."""
        self._check_open()
        deadline = None if self.timeout is None else time.monotonic() + self.timeout
        with self._rx_ready:
            while b"\n" not in self._rx and not self._closed and self._pump_error is None:
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    break
                self._rx_ready.wait(remaining)
            end = self._rx.find(b"\n") + 1 or len(self._rx)
            data = bytes(self._rx[:end])
            del self._rx[:end]
        return data

    def write(self, data: bytes) -> int:
        """Hands all of ``data`` to VirtualPrinter, one line per queue item, waiting (not
        spinning) for room in its receive queue; returns ``len(data)``."""
        data = bytes(data)
        with self._write_lock:
            self._check_open()
            deadline = None if self.write_timeout is None else time.monotonic() + self.write_timeout
            for line in self._in_order(data):
                done = 0
                while done < len(line):
                    room = self._wait_for_room(deadline)
                    written = self.printer.write(line[done : done + room])
                    if not written:
                        raise serial.PortNotOpenError()
                    done += written
        return len(data)

    def _in_order(self, data: bytes) -> Iterator[bytes]:
        """The lines of ``data`` as VirtualPrinter gets them (``late``: held back once)."""
        for line in _lines(data):
            if self._late is not None and line.startswith(self._late):
                self._late, self._held = None, b""
            if self._held is not None and not self._held.endswith(b"\n"):
                self._held += line  # until the held line is complete
                continue
            if self._held is not None:
                yield self._held
                self._held = None
            yield line

    def reset_input_buffer(self) -> None:
        """Drops the bytes received and not yet read."""
        self._check_open()
        with self._rx_ready:
            self._rx.clear()

    def flush(self) -> None:
        """Nothing to do: ``write`` returns once VirtualPrinter has everything."""

    def close(self) -> None:
        """Stops VirtualPrinter and every thread it and the port started; idempotent.

        Raises ``RuntimeError`` if a VirtualPrinter thread is still alive after
        10 s (a ``G4 S60`` sleeps unstoppably, for one)."""
        if self._closed:
            return
        self._closed = True
        with self._rx_ready:
            self._rx_ready.notify_all()
        self._stop.set()
        self._pump.join()
        try:
            self._stop_printer()
        finally:
            if self._tempdir is not None:
                self._tempdir.cleanup()

    def __enter__(self) -> VirtualPrinterPort:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- inside ---------------------------------------------------------------------------

    def _check_open(self) -> None:
        if self._closed:
            raise serial.PortNotOpenError()

    @staticmethod
    def _complete(line: bytes) -> bytes:
        return line if not line or line.endswith(b"\n") else line + b"\n"

    def _run_pump(self) -> None:
        """Moves VirtualPrinter's output lines into the port's receive buffer."""
        while not self._stop.is_set():
            try:
                line = self._complete(self.printer.readline())  # waits up to 20 ms
            except BaseException as error:  # handed to the reader
                self._pump_error = error
                line = b""
            if line or self._pump_error is not None:
                with self._rx_ready:
                    self._rx += line
                    self._rx_ready.notify_all()
            if self._pump_error is not None:
                return

    def _wait_for_room(self, deadline: float | None) -> int:
        """Free bytes in VirtualPrinter's receive queue, once there are any.

        Waits on the queue's own condition (a ``get`` notifies it), without
        VirtualPrinter's ``_incoming_lock``; ``_qsize`` is the queue's byte count, read
        under its mutex as ``queue.Queue`` itself does."""
        incoming = self.printer.incoming
        if incoming is None:
            raise serial.PortNotOpenError()
        with incoming.not_full:
            while (room := incoming.maxsize - incoming._qsize()) <= 0:
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    raise serial.SerialTimeoutException("VirtualPrinter's receive queue is full")
                incoming.not_full.wait(remaining)
        return room

    def _stop_printer(self) -> None:
        """VirtualPrinter.close() in an order that leaves no thread behind.

        ``close()`` alone drops its queues at once: the reader can stay blocked on a full
        planner queue nobody empties any more, and the planner thread can die on
        ``task_done`` of a queue that is gone. So: stop the reader first (``_killed`` is
        what ``close()`` sets first; long moves and heat-ups watch it), empty the planner
        queue, wait for the move in progress, stop the report timers, close, wake the
        planner thread with the ``None`` it skips, and join everything."""
        printer = self.printer
        planner = printer.buffered
        deadline = time.monotonic() + _STOP_TIMEOUT_S
        printer._killed = True
        printer._sdPrinting = False
        printer._sdPrintingSemaphore.set()
        printer._busy = None
        for thread in self._threads:
            if thread.name.endswith("wait_thread"):
                thread.join(max(0.0, deadline - time.monotonic()))
        while True:
            try:
                planner.get_nowait()
            except queue.Empty:
                break
            planner.task_done()
        with planner.all_tasks_done:
            while planner.unfinished_tasks and time.monotonic() < deadline:
                planner.all_tasks_done.wait(max(0.0, deadline - time.monotonic()))
        others = [printer._sdPrinter, printer._busy_loop]
        for timer in (
            printer._temperature_reporter,
            printer._sdstatus_reporter,
            printer._pos_reporter,
        ):
            if timer is not None:
                timer.cancel()
                others.append(timer)
        printer.close()
        planner.put(None)
        alive = []
        for thread in [*self._threads, *others]:
            if thread is not None and thread is not threading.current_thread():
                thread.join(max(0.0, deadline - time.monotonic()))
                if thread.is_alive():
                    alive.append(thread.name)
        if alive:
            raise RuntimeError(f"VirtualPrinter threads still running: {', '.join(alive)}")


# -- behind a pseudo-terminal, in a process of its own ---------------------------------------


class VirtualPrinterPty:
    """A VirtualPrinter served on a pseudo-terminal from a forked process; a context manager.

    The way OctoPrint's users reach a printer (a device path) and a fair stage for timing
    senders: VirtualPrinter's threads do not share an interpreter (and its lock) with the
    sender. ``path`` is the device to open; keyword arguments are VirtualPrinter settings
    as for :class:`VirtualPrinterPort`. After the ``with`` block, ``executed`` and
    ``accepted`` hold what the port recorded."""

    def __init__(self, **settings_overrides: Any) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self.executed: list[str] = []
        self.accepted: list[int] = []
        context = multiprocessing.get_context("fork")
        self._stop = context.Event()
        self._results = context.Queue()
        self._process = context.Process(target=self._serve, args=(settings_overrides,), daemon=True)

    def __enter__(self) -> VirtualPrinterPty:
        self._process.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self.executed, self.accepted = self._results.get(timeout=20)
        self._process.join(timeout=10)
        os.close(self.master)
        os.close(self.slave)

    def _serve(self, settings: dict[str, Any]) -> None:
        with VirtualPrinterPort(timeout=0.01, **settings) as port:
            answers = threading.Thread(target=self._answer, args=(port,), daemon=True)
            answers.start()
            while not self._stop.is_set():
                if select.select([self.master], [], [], 0.01)[0]:
                    port.write(os.read(self.master, 4096))
            answers.join()
            self._results.put((port.executed, port.accepted))

    def _answer(self, port: VirtualPrinterPort) -> None:
        while not self._stop.is_set():
            data = port.read(max(1, port.in_waiting))
            if data:
                os.write(self.master, data)


# -- a reference host -----------------------------------------------------------------------

_RESEND = re.compile(r"Resend:\s*(\d+)")


def ping_pong_send(port: Any, lines: Sequence[str], answer_timeout_s: float = 10.0) -> float:
    """Sends ``lines`` one numbered line per ``ok``, as simple hosts do; returns lines/s.

    ``M110 N0`` first, then line ``k`` of ``lines`` as ``N<k+1>``; a ``Resend: N`` makes
    the line after the next ``ok`` be ``N`` again. ``port`` is anything pyserial-like
    (``read``, ``write``, ``timeout``); silence for ``answer_timeout_s`` is a
    ``TimeoutError``. The yardstick for send-ahead: its rate is about one line per
    round trip."""
    texts = ["M110 N0", *lines]
    rx = bytearray()
    port.timeout = answer_timeout_s
    start = time.monotonic()
    n = 0
    while n < len(texts):
        port.write(frame_marlin(n, texts[n]))
        while True:
            while b"\n" not in rx:
                chunk = port.read(max(1, getattr(port, "in_waiting", 0)))
                if not chunk:
                    raise TimeoutError(f"no answer to line {n} in {answer_timeout_s} s")
                rx += chunk
            end = rx.index(b"\n") + 1
            answer = rx[:end].decode("latin-1").strip()
            del rx[:end]
            resend = _RESEND.match(answer)
            if resend:
                n = int(resend.group(1)) - 1
            if answer.startswith("ok"):
                break
        n += 1
    return len(lines) / (time.monotonic() - start)
