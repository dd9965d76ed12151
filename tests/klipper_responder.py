"""A pty that answers a Marlin-protocol host in Klipper's words, as klippy does on /tmp/printer.

Written from Klipper's source, commit 84104bbbd7625d28b4eaaad83f4562972460ecd9
(``v0.13.0-730-g84104bbbd``), and checked against transcripts of that klippy, unmodified,
run in debug-output mode (tests/test_klipper_responder.py). Paths are in Klipper's repo:

* input: reads of up to 4096 bytes, split at ``\\n``, the unfinished rest kept
  (klippy/gcode.py:440-448); a read that is not UTF-8 is dropped whole, without an
  answer (gcode.py:441-443). Before a read's lines run, a *bare* ``M112`` among them
  (``^(N\\d+)?\\s*M112(\\s|$)``: not with ``*checksum``) shuts down at once
  (gcode.py:436, 460-464).
* a line: stripped, cut at ``;`` (gcode.py:205-208); a leading ``N<n>`` is skipped and
  ``*<checksum>`` is just another parameter (gcode.py:201, 210-218): neither is checked,
  no line is refused and Klipper never asks for a resend.
* ``ok`` (``ok <msg>`` for M105/M115) after every line, also after an error
  (gcode.py:54-62, 222-236); it never names a line. No ``busy:``, no ``wait``.
* ``// <text>`` for information (gcode.py:250-254); an error is ``!! <first line>``,
  its other lines first as ``// `` lines (gcode.py:255-260), then ``ok``.
* M110: ``ok`` (gcode.py:338-340). M115: ``ok FIRMWARE_NAME:Klipper FIRMWARE_VERSION:<v>``
  on the ok line itself (gcode.py:344-351).
* M105: ``ok B:<t> /<target> T0:<t> /<target>``, sorted by id, ``%.1f`` (extras/heaters.py:
  331-347; ids ``B`` extras/heater_bed.py:11, ``T0`` kinematics/extruder.py:147-148);
  ``ok T:0`` without heaters (gcode.py:285-288) and before ready (heaters.py:338-339).
* M109/M190: a temperature line without ``ok`` once a second until reached, then ``ok``
  (heaters.py:348-365; here ``heat_reports`` lines ``report_s`` apart; ``heat_reports=0``
  is klippy in debug-output mode, which neither waits nor heats, heaters.py:350-351).
* G0/G1 (extras/gcode_move.py:134-161): ``ok`` once queued (toolhead.py:395-409; with a
  real MCU it waits while more than 1 s of motion is queued, toolhead.py:195, 356-379);
  ``!! Must home axis first: X Y Z [E]`` / ``!! Move out of range: ...`` (``%.3f``,
  toolhead.py:62-65, kinematics/cartesian.py:97-116; unhomed limits (1, -1),
  cartesian.py:45); ``!! Extrude when no extruder present: ...`` (extruder.py:292-296);
  ``!! Unable to parse move '<line>'`` (gcode_move.py:158-160); on an error the position
  stays (gcode_move.py:52-53). G28 homes to the envelope's minimum (``position_endstop``;
  extras/homing.py:337-355, gcode_move.py:79-82), M18/M84 forget it
  (extras/stepper_enable.py:82-83, 116-120). G20: ``!! Machine does not support G20
  (inches) command`` (gcode_move.py:165).
* M114: ``X:%.3f Y:%.3f Z:%.3f E:%.3f`` then ``ok`` (gcode_move.py:191-194).
* G4 / M400: ``ok`` (toolhead.py:417-429, 565-571).
* unknown: ``// Unknown command:"X"`` + ``ok`` (gcode.py:316) -- also M117/M118 without
  [display]/[respond] (extras/display_status.py:18, extras/respond.py:25); M104/M140
  ``S0`` without heaters, M107, M106 ``S0`` and M21 get a plain ``ok``
  (gcode.py:289-291, 309-315); a blank or comment-only line gets ``ok`` (gcode.py:295-299).
* M112: ``// Klipper state: Shutdown`` (gcode.py:186-192, 263-264, 341-343), ``ok``. Then
  only M110, M112, M115, M105, M114, STATUS, RESTART, FIRMWARE_RESTART run
  (gcode.py:119-124, 190; heaters.py:259; gcode_move.py:24); every other line, blank ones
  too, gets the state message (klippy.py:204-209, extras/error_mcu.py:8-13, 91-95) as
  ``// `` lines, ``!! Shutdown due to M112 command`` and ``ok`` (gcode.py:292-293).
  FIRMWARE_RESTART/RESTART: ``ok``, ``// Klipper state: Disconnect``, about a second
  later ``// Klipper state: Ready`` (gcode.py:193-199, 352-367; klippy.py:364); lines that
  arrived meanwhile find klippy starting: the same as after a shutdown, with the message
  ``Printer is not ready`` ... (klippy.py:13-17) and ``ok T:0`` for M105 (here
  ``restart_s``).
* STATUS: ``// Klipper state: Ready`` + ``ok``, or the state message and ``// Klipper
  state: Not ready`` as an error (gcode.py:370-377).

The machine is a cartesian printer; with ``heaters`` it has an extruder and a heated bed,
without them neither (M105 ``ok T:0``; E moves fail). No fan, display or [respond].
``homing_required=False`` starts homed. Answers come at once: the 1 s motion buffer, the
20-line input limit (gcode.py:465-470) and klippy dropping answers the host does not read
(non-blocking writes, gcode.py:482-488) are not modelled.
After the ``with`` block, ``executed`` lists the commands Klipper acknowledged without an
error, as it ran them (``N<n>``, ``*<checksum>`` and comments removed; blank lines left
out), ``errors`` the ``!!`` texts and ``state`` the state it ended in (``"ready"``,
``"shutdown"``). Klipper's ``// Klipper state: Ready`` at start-up is not sent: it comes
before a host opens the port, and pyserial's ``open`` discards it.
"""

from __future__ import annotations

import multiprocessing
import os
import re
import select
import time
import tty

KLIPPER_COMMIT = "84104bbbd7625d28b4eaaad83f4562972460ecd9"
KLIPPER_VERSION = "v0.13.0-730-g84104bbbd"
ENVELOPE = ((0.0, 235.0), (0.0, 235.0), (0.0, 250.0))  # machines/klipper_generic.toml
SHUTDOWN_MESSAGE = (  # klippy/klippy.py:204-209, klippy/extras/error_mcu.py:8-13, 91-95
    "Shutdown due to M112 command\n"
    "Once the underlying issue is corrected, use the\n"
    '"FIRMWARE_RESTART" command to reset the firmware, reload the\n'
    "config, and restart the host software.\n"
    "Printer is shutdown"
)
STARTUP_MESSAGE = (  # klippy/klippy.py:13-17
    "Printer is not ready\n"
    "The klippy host software is attempting to connect.  Please\n"
    "retry in a few moments."
)
_WORDS = re.compile(r"([A-Z_]+|[A-Z*])")  # how klippy splits a line into words
_BARE_M112 = re.compile(r"^(?:[nN][0-9]+)?\s*[mM]112(?:\s|$)")
_NUMBER = re.compile(r"^[nN][0-9]+\s*")
_CHECKSUM = re.compile(r"\*\d+$")
_QUIET = {"G21", "G4", "M400", "M110", "M204", "M220", "M221"}  # plain ok, nothing to model
_WHEN_NOT_READY = {"M110", "M112", "M115", "M105", "M114", "STATUS", "RESTART", "FIRMWARE_RESTART"}


class KlipperError(Exception):
    """A command error: answered ``!! <first line>`` (other lines as ``//``), then ``ok``."""


class KlipperResponder:
    """A pty whose far end (a forked process) answers like klippy; see the module docstring."""

    def __init__(
        self,
        heaters: bool = True,
        homing_required: bool = True,
        envelope: tuple[tuple[float, float], ...] = ENVELOPE,
        version: str = KLIPPER_VERSION,
        heat_reports: int = 2,
        report_s: float = 0.02,
        restart_s: float = 0.2,
    ) -> None:
        self.heaters = heaters
        self.homing_required = homing_required
        self.envelope = envelope
        self.version = version
        self.heat_reports = heat_reports
        self.report_s = report_s
        self.restart_s = restart_s
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self.executed: list[str] = []
        self.errors: list[str] = []
        self.partial = ""  # an unfinished line
        self._reset()
        context = multiprocessing.get_context("fork")
        self._stop = context.Event()
        self._results = context.Queue()
        self._process = context.Process(target=self._run, daemon=True)

    def _reset(self) -> None:
        """The state after klippy (re)starts: ready, not homed, at 0, heaters off."""
        self.state = "ready"
        self.homed = [not self.homing_required] * 3
        self.position = [0.0, 0.0, 0.0, 0.0]  # toolhead coordinates
        self.base = [0.0, 0.0, 0.0, 0.0]  # G92 offsets
        self.absolute, self.absolute_e = True, True
        self.temps = {"B": [0.0, 0.0], "T0": [0.0, 0.0]}  # id -> [current, target]

    def __enter__(self) -> KlipperResponder:
        self._process.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self.executed, self.errors, self.state = self._results.get(timeout=10)
        self._process.join(timeout=5)
        os.close(self.master)
        os.close(self.slave)

    # -- the klippy side (in the forked process) ----------------------------------------------

    def _run(self) -> None:
        while not self._stop.is_set():
            self._read(0.005)
        self._results.put((self.executed, self.errors, self.state))

    def _read(self, timeout_s: float) -> None:
        """One read of the pty, as klippy's ``_process_data`` does it."""
        if not select.select([self.master], [], [], timeout_s)[0]:
            return
        try:
            data = os.read(self.master, 4096).decode()
        except UnicodeDecodeError:
            return  # the whole read is lost, as in klippy
        lines = (self.partial + data).split("\n")
        self.partial = lines.pop()
        if len(lines) < 20 and any(_BARE_M112.match(line) for line in lines):
            self._shut_down()
        for line in lines:
            self._line(line)

    def say(self, text: str) -> None:
        os.write(self.master, text.encode() + b"\n")

    def _info(self, text: str) -> None:
        self.say("// " + "\n// ".join(part.strip() for part in text.strip().split("\n")))

    def _line(self, raw: str) -> None:
        line = raw.strip().split(";", 1)[0]
        words = _WORDS.split(line.upper())
        if "".join(words[:2]) == "N":
            command = "".join(words[3:5]).strip()
        else:
            command = "".join(words[:3]).strip()
        params = {words[i]: words[i + 1].strip() for i in range(1, len(words), 2)}
        try:
            ack = self._command(command, params, raw.strip())
        except KlipperError as error:
            lines = str(error).strip().split("\n")
            if len(lines) > 1:
                self._info("\n".join(lines))
            self.say(f"!! {lines[0].strip()}")
            self.errors.append(lines[0].strip())
            ack = "ok"
        else:
            text = _CHECKSUM.sub("", _NUMBER.sub("", line.strip())).strip()
            if text:
                self.executed.append(text)
        if ack:
            self.say(ack)

    def _command(self, command: str, params: dict[str, str], original: str) -> str | None:
        """Run one command; return its ``ok`` line (None after a restart: no ok)."""
        if command == "M105":
            return "ok " + self._temperatures()
        message = {"shutdown": SHUTDOWN_MESSAGE, "startup": STARTUP_MESSAGE}.get(self.state)
        if message and command not in _WHEN_NOT_READY and command != "M21":
            raise KlipperError(message)
        if command in _QUIET or command == "M21" or not command:
            return "ok"
        if command == "M115":
            return f"ok FIRMWARE_NAME:Klipper FIRMWARE_VERSION:{self.version}"
        if command == "M112":
            self._shut_down()
        elif command == "M114":
            x, y, z, e = (p - b for p, b in zip(self.position, self.base, strict=True))
            self.say(f"X:{x:.3f} Y:{y:.3f} Z:{z:.3f} E:{e:.3f}")
        elif command in ("G0", "G1"):
            self._move(params, original)
        elif command == "G28":
            axes = [i for i, axis in enumerate("XYZ") if axis in params] or [0, 1, 2]
            for i in axes:
                self.homed[i] = True
                self.position[i], self.base[i] = self.envelope[i][0], 0.0
        elif command in ("M18", "M84"):
            self.homed = [not self.homing_required] * 3
        elif command == "G92":
            given = {i: _float(params, a, original) for i, a in enumerate("XYZE") if a in params}
            for i in given or range(4):
                self.base[i] = self.position[i] - given.get(i, 0.0)
        elif command in ("G90", "G91"):
            self.absolute = command == "G90"
        elif command in ("M82", "M83"):
            self.absolute_e = command == "M82"
        elif command == "G20":
            raise KlipperError("Machine does not support G20 (inches) command")
        elif command in ("M104", "M109", "M140", "M190") and self.heaters:
            self._heat("T0" if command in ("M104", "M109") else "B", params, original, command)
        elif command in ("M104", "M140") and not _float(params, "S", original):
            pass  # turning off a heater that is not there
        elif command == "M107" or (command == "M106" and not _float(params, "S", original, 1)):
            pass  # turning off a fan that is not there
        elif command == "STATUS":
            if message:
                raise KlipperError(message + "\nKlipper state: Not ready")
            self._info("Klipper state: Ready")
        elif command in ("RESTART", "FIRMWARE_RESTART"):
            self.say("ok")
            self._info("Klipper state: Disconnect")
            time.sleep(self.restart_s)
            self._reset()
            self.state = "startup"  # what arrived meanwhile finds klippy not ready
            self._read(0.0)
            self.state = "ready"
            self._info("Klipper state: Ready")
            return None
        else:
            self._info(f'Unknown command:"{command}"')
        return "ok"

    def _shut_down(self) -> None:
        if self.state == "ready":
            self._info("Klipper state: Shutdown")
        self.state = "shutdown"

    def _temperatures(self) -> str:
        if not self.heaters or self.state == "startup":
            return "T:0"
        return " ".join(f"{k}:{cur:.1f} /{target:.1f}" for k, (cur, target) in self.temps.items())

    def _heat(self, heater: str, params: dict[str, str], original: str, command: str) -> None:
        target = _float(params, "S", original)
        self.temps[heater][1] = target
        if command in ("M109", "M190") and target and self.heat_reports:
            start = self.temps[heater][0]
            for k in range(self.heat_reports):
                self.temps[heater][0] = start + (target - start) * k / self.heat_reports
                self.say(self._temperatures())
                time.sleep(self.report_s)
            self.temps[heater][0] = target

    def _move(self, params: dict[str, str], original: str) -> None:
        new = list(self.position)
        try:
            for i, axis in enumerate("XYZE"):
                if axis in params:
                    value = float(params[axis])
                    relative = not (self.absolute_e if axis == "E" else self.absolute)
                    new[i] = new[i] + value if relative else value + self.base[i]
            speed = float(params.get("F", "1"))
        except ValueError:
            raise KlipperError(f"Unable to parse move '{original}'") from None
        if speed <= 0:
            raise KlipperError(f"Invalid speed in '{original}'")
        moved = [abs(n - p) > 1e-9 for n, p in zip(new, self.position, strict=True)]
        if not any(moved[:3]):
            new[:3] = self.position[:3]  # an extrude-only move
        elif any(self._outside(new, i) for i in (0, 1)) or moved[2]:
            for i in range(3):
                if moved[i] and self._outside(new, i):
                    why = "Must home axis first" if not self.homed[i] else "Move out of range"
                    raise KlipperError(f"{why}: {_where(new)}")
        if moved[3] and not self.heaters:
            raise KlipperError(f"Extrude when no extruder present: {_where(new)}")
        self.position = new

    def _outside(self, position: list[float], axis: int) -> bool:
        low, high = self.envelope[axis] if self.homed[axis] else (1.0, -1.0)
        return not low <= position[axis] <= high


def _float(params: dict[str, str], name: str, original: str, default: float = 0.0) -> float:
    if name not in params:
        return default
    try:
        return float(params[name])
    except ValueError:
        raise KlipperError(f"Error on '{original}': unable to parse {params[name]}") from None


def _where(position: list[float]) -> str:
    x, y, z, e = position
    return f"{x:.3f} {y:.3f} {z:.3f} [{e:.3f}]"
