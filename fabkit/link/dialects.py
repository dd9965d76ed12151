"""What Marlin-protocol firmwares say, read for the sender: answers and ``M115`` reports.

The wording comes from each firmware's source (file named where the fact is used):

* Marlin 1.1/2.x (Marlin/src/gcode/queue.cpp, Marlin/src/core/language.h): line errors
  ``Error:Line Number is not Last Line Number+1, Last Line: N``, ``Error:checksum
  mismatch, Last Line: N``, ``Error:No Checksum with line number, Last Line: N``, then
  ``Resend: N+1``; ``ok`` after a command, ``ok N<n> P<planner> B<buffer>`` with
  ``ADVANCED_OK``; ``echo:busy: processing`` (``busy: paused for user`` ...) every
  ``host_keepalive`` interval; ``wait`` when idle with ``NO_TIMEOUTS``; ``echo:Unknown
  command: "X"``; ``Error:RX BUF overflow, increase RX_BUFFER_SIZE: N`` with
  ``RX_BUFFER_MONITOR``. 2.1 sends ``ok`` after ``Resend:``; 2.0.8 and later 2.0.x (the
  ``RingBuffer`` queue) do not; 2.0.0-2.0.7 and 1.1 call ``ok_to_send()`` there, which
  sends it unless the queue slot says not to.
* Prusa-Firmware (Firmware/cmdqueue.cpp, Marlin_main.cpp): the Marlin wording, plus
  ``Error:No Line Number with checksum, Last Line: N``; ``Resend: N`` then ``ok``.
* Repetier-Firmware (src/ArduinoAVR/Repetier/gcode.cpp, Communication.cpp):
  ``Error:expected line 100 got 101``, ``Error:Wrong checksum``, ``Error:Format error``,
  an empty line, ``Resend:100``, ``ok``; later lines ``skip 101`` + ``ok``; ``ok 101``
  names the line (``ACK_WITH_LINENUMBER``) and comes when the line is queued;
  ``busy:processing`` / ``busy:heating``; ``wait`` after a second without input;
  ``Unknown command:``.
* Smoothieware (src/modules/communication/GcodeDispatch.cpp): ``rs N100`` and nothing
  else for a bad line; ``ok - ignored`` for a line that is not a command; ``!!`` when
  halted.
* RepRapFirmware 3 (src/GCodes/GCodeBuffer/StringParser.cpp, src/GCodes/GCodes.cpp):
  a line with a bad checksum is dropped without an answer and line numbers are not
  checked; ``Error: Bad command: X`` + ``ok``; RRF 2 answered ``rs`` + the line number.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

# kinds of answer
OK, RESEND, SKIP, LINE_ERROR, ERROR, FATAL, BUSY, WAIT = (
    "ok",
    "resend",
    "skip",
    "line_error",
    "error",
    "fatal",
    "busy",
    "wait",
)
TEMPERATURES, POSITION, UNKNOWN_COMMAND, OVERFLOW, START, INFO, EMPTY, OTHER = (
    "temperatures",
    "position",
    "unknown_command",
    "overflow",
    "start",
    "info",
    "empty",
    "other",
)

_OK_NUMBER = re.compile(r"ok\s+N?(\d+)\b")
_RESEND = re.compile(r"(?:resend|rs)\b\D{0,40}?(\d+)", re.IGNORECASE)
_SKIP = re.compile(r"skip\s+(\d+)")
_LINE_ERRORS = (
    "last line",
    "line number",
    "checksum",
    "expected line",
    "format error",
)
_FATAL_ERRORS = (
    "kill()",
    "halted",
    "stopped",
    "thermal runaway",
    "maxtemp",
    "mintemp",
    "heating failed",
)
_UNKNOWN = re.compile(r'(?:echo:\s*Unknown command:\s*"(.*)"|Unknown command:\s*(.*)|'
                      r"Error:\s*Bad command:\s*(.*))")  # fmt: skip
_OVERFLOW = re.compile(r"RX BUF overflow.*?(\d+)")
_INFO = ("echo:", "//", "Info:", "Warning:", "Cap:", "FIRMWARE_NAME", "Debug:", "DEBUG", "X-")


@dataclass(frozen=True)
class Answer:
    """One line from the machine, classified: ``kind`` (one of the module constants),
    ``number`` (the line an ``ok <n>`` / resend / skip names, or a buffer size),
    ``temperatures`` (an ``ok T:`` answer to M105), ``ignored`` (Smoothieware's
    ``ok - ignored``: the answer to something that was not a command) and ``text``."""

    kind: str
    text: str
    number: int | None = None
    temperatures: bool = False
    ignored: bool = False


_PLAIN_OK = Answer(OK, "ok")


def classify(line: str) -> Answer:
    """What ``line`` (stripped) says; see the module docstring for the wordings."""
    if line == "ok":
        return _PLAIN_OK  # by far the most common answer
    if not line:
        return Answer(EMPTY, line)
    lowered = line.lower()
    if lowered.startswith("ok"):
        number = _OK_NUMBER.match(line)
        return Answer(
            OK,
            line,
            number=int(number.group(1)) if number else None,
            temperatures="T:" in line,
            ignored=lowered.startswith("ok - ignored"),
        )
    resend = _RESEND.match(line)
    if resend:
        return Answer(RESEND, line, number=int(resend.group(1)))
    skip = _SKIP.match(line)
    if skip:
        return Answer(SKIP, line, number=int(skip.group(1)))
    unknown = _UNKNOWN.match(line)
    if unknown:
        fragment = next(group for group in unknown.groups() if group is not None)
        return Answer(UNKNOWN_COMMAND, fragment.strip())
    if lowered.startswith(("error", "!!")):
        return _error(line, lowered)
    if lowered.startswith(("busy:", "echo:busy:")):
        return Answer(BUSY, line)
    if lowered == "wait":
        return Answer(WAIT, line)
    if re.match(r"\s*T:-?\d", line):
        return Answer(TEMPERATURES, line)
    if re.match(r"X:-?\d", line):
        return Answer(POSITION, line)
    if lowered == "start":
        return Answer(START, line)
    if line.startswith(_INFO):
        return Answer(INFO, line)
    return Answer(OTHER, line)


def _error(line: str, lowered: str) -> Answer:
    overflow = _OVERFLOW.search(line)
    if overflow:
        return Answer(OVERFLOW, line, number=int(overflow.group(1)))
    if lowered.startswith("!!") or any(word in lowered for word in _FATAL_ERRORS):
        return Answer(FATAL, line)
    if any(word in lowered for word in _LINE_ERRORS):
        return Answer(LINE_ERROR, line)
    return Answer(ERROR, line)


def position(line: str) -> dict[str, float]:
    """The axis values of an ``M114`` answer (``X:1.00 Y:2.00 Z:0.30 E:4.00 Count ...``)."""
    head = line.split("Count", 1)[0]
    found: dict[str, float] = {}
    for axis, value in re.findall(r"([XYZE]):(-?\d+\.?\d*)", head):
        found.setdefault(axis, float(value))  # the first: a garbled "Count" must not win
    return found


@dataclass(frozen=True)
class Firmware:
    """What the machine's ``M115`` said, as the sender needs it.

    ``resend_ok``: the firmware sends ``ok`` after a resend request (None: unknown, the
    sender then finds out with a probe); ``drains``: it empties its receive buffer when
    it rejects a line; ``sequenced``: it refuses a line whose number is not the last
    one + 1 (RepRapFirmware does not, so only one line may be unanswered there).
    """

    name: str
    resend_ok: bool | None
    drains: bool
    sequenced: bool = True

    @property
    def known(self) -> bool:
        return self.name != "unknown"


def identify(report: str, flavour: str) -> Firmware:
    """The firmware behind an ``M115`` report (``""`` if none came) on a ``flavour`` profile.

    Sources: see the module docstring. Without a report the profile's flavour decides
    (``marlin``: drains, ``ok`` after a resend unknown)."""
    text = report.upper()
    if "REPRAPFIRMWARE" in text or flavour == "reprap" and not text:
        return Firmware("RepRapFirmware", resend_ok=False, drains=False, sequenced=False)
    if "SMOOTHIEWARE" in text:
        return Firmware("Smoothieware", resend_ok=False, drains=False)
    if "REPETIER" in text:
        return Firmware("Repetier", resend_ok=True, drains=False)
    if "PRUSA" in text:
        return Firmware("Prusa-Firmware", resend_ok=True, drains=True)
    version = re.search(r"MARLIN\s+(BUGFIX-)?(\d+)\.(\d+)(?:\.(\d+|X))?", text)
    if version:
        bugfix, major, minor, patch = version.groups()
        name = f"Marlin {major}.{minor}" + (f".{patch.lower()}" if patch else "")
        release = (int(major), int(minor))
        if release != (2, 0):
            return Firmware(name, resend_ok=True, drains=True)
        if bugfix or patch == "X" or patch is not None and int(patch) >= 8:
            return Firmware(name, resend_ok=False, drains=True)
        return Firmware(name, resend_ok=None if patch is None else True, drains=True)
    if "KLIPPER" in text or flavour == "klipper":
        return Firmware("Klipper", resend_ok=None, drains=False)
    return Firmware("unknown", resend_ok=None, drains=flavour == "marlin")
