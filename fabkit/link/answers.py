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
  halted; ``Smoothie`` + ``ok`` when its USB port (re)attaches, its receive buffer
  flushed (src/libs/USBDevice/USBSerial/USBSerial.cpp ``on_main_loop``).
* RepRapFirmware 3 (src/GCodes/GCodeBuffer/StringParser.cpp, src/GCodes/GCodes.cpp):
  a line with a bad checksum is dropped without an answer and line numbers are not
  checked; ``Error: Bad command: X`` + ``ok``; RRF 2 answered ``rs`` + the line number.
* Klipper (klippy/gcode.py and extras/heaters.py at 84104bbb, v0.13.0-730): ``N<n>``
  and ``*<checksum>`` are skipped unchecked, no line is refused and nothing is asked for
  again (gcode.py:201, 210-218); ``ok`` after every line, never with a number, also after
  an error (gcode.py:54-62, 222-236); M115 answers on the ok line, ``ok FIRMWARE_NAME:
  Klipper FIRMWARE_VERSION:...`` (gcode.py:344-351); M105 ``ok B:0.0 /0.0 T0:0.0 /0.0``
  (ids sorted: bed first, ``T0``; heaters.py:331-347) or ``ok T:0`` without heaters
  (gcode.py:285-288); M109/M190 print ``B:... T0:...`` once a second while they wait
  (heaters.py:348-365); information as ``// `` lines, an error as ``!! <text>`` then
  ``ok`` (gcode.py:250-260): ``!! Must home axis first: X Y Z [E]``, ``!! Move out of
  range: X Y Z [E]`` (toolhead.py:62-65, kinematics/cartesian.py:97-116); ``// Unknown
  command:"X"`` + ``ok`` (gcode.py:316); M112 and any shutdown: ``// Klipper state:
  Shutdown`` (gcode.py:186-192, 263-264), then every command ``!! Shutdown due to ...``
  (gcode.py:292-293); a restart ``// Klipper state: Disconnect``. No ``busy:``, no
  ``wait``.
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
# a temperature report on the ok line: the answer to M105 (Marlin ``ok T:21.3 /0.0 B:...``,
# Klipper ``ok B:0.0 /0.0 T0:0.0 /0.0`` or, without heaters, ``ok T:0``)
_TEMPERATURES = re.compile(r"\s(?:T\d*|B|C):\s*-?\d")
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
_UNKNOWN = re.compile(r'(?:(?:echo:|//)\s*Unknown command:\s*"(.*)"|Unknown command:\s*(.*)|'
                      r"Error:\s*Bad command:\s*(.*))")  # fmt: skip
_KLIPPER_DOWN = ("// klipper state: shutdown", "// klipper state: disconnect")
_REPORT = re.compile(r"\s*(?:T\d*|B|C):\s*-?\d")  # a temperature report (M105, M109, M190)
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
            temperatures=_TEMPERATURES.search(line) is not None,
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
    if lowered.startswith(_KLIPPER_DOWN):
        return Answer(FATAL, line)
    if lowered.startswith(("busy:", "echo:busy:")):
        return Answer(BUSY, line)
    if lowered == "wait":
        return Answer(WAIT, line)
    if _REPORT.match(line):
        return Answer(TEMPERATURES, line)
    if re.match(r"X:-?\d", line):
        return Answer(POSITION, line)
    if lowered == "start" or line == "Smoothie":  # Smoothieware: USBSerial.cpp on attach
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


# How a firmware answers M105, as the handshake finds out (:func:`m105_answer`): the
# report on the ok line; an ``ok <n>`` naming the line (the report follows on a line of
# its own); the report on a line of its own after the plain ``ok``, or before it.
ON_OK_LINE, NAMED_OK, AFTER_OK, BEFORE_OK = "on_ok_line", "named_ok", "after_ok", "before_ok"


def m105_answer(lines: list[str], last: int) -> str | None:
    """How ``lines`` (read since ``N0 M110 N0``, ``N1 M115``, ``N2 M105`` were sent, with
    no resend request among them) answer that M105, ``last`` being its line number; None
    while they do not yet.

    Marlin prints ``ok`` and the report on one line and sends no other ``ok`` for M105
    (Marlin/src/gcode/temp/M105.cpp ``GcodeSuite::M105``; gcode.cpp
    ``process_parsed_command``: ``case 105: M105(); return;`` skips ``ok_to_send``), as do
    Prusa-Firmware (Marlin_main.cpp ``process_commands``, ``case 105``), Smoothieware
    (GcodeDispatch.cpp ``ok %s`` with ``txt_after_ok``), RepRapFirmware in Marlin mode
    (GCodes.cpp ``HandleReplyPreserveResult``) and Klipper: :data:`ON_OK_LINE`.
    Repetier acknowledges a line when it queues it (gcode.cpp ``checkAndPushCommand``:
    ``ok 2`` with ``ACK_WITH_LINENUMBER``, the default, else ``ok``) and prints ``T:...``
    when it runs it (Commands.cpp ``printTemperatures``): :data:`NAMED_OK`, or without
    line numbers three ``ok`` then the report, :data:`AFTER_OK` (OctoPrint's
    VirtualPrinter with ``okBeforeCommandOutput`` answers so too). Three ``ok`` are no
    proof alone (one may pair with a refusal whose ``Resend`` was lost): the report says
    the M105 ran. A report before the third ``ok`` is :data:`BEFORE_OK`."""
    oks = 0
    reported_at = None  # oks before the first report on a line of its own
    for line in lines:
        answer = classify(line)
        if answer.kind == OK:
            if answer.temperatures:
                return ON_OK_LINE
            if (answer.number or 0) >= last:
                return NAMED_OK
            oks += 1
        elif answer.kind == TEMPERATURES and reported_at is None:
            reported_at = oks
    if oks < last + 1 or reported_at is None:
        return None
    return AFTER_OK if reported_at > last else BEFORE_OK


_LAST_LINE = re.compile(r"Last Line:\s*(\d+)", re.IGNORECASE)
_EXPECTED_GOT = re.compile(r"expected line\s+(\d+)\s+got\s+(\d+)", re.IGNORECASE)


def refused_line(line: str) -> tuple[int | None, int | None]:
    """What a line error says: the line the firmware expects and the number of the line
    it refused, where the wording tells (else None).

    Marlin and Prusa check the number before anything else (Marlin/src/gcode/queue.cpp
    ``get_serial_commands``), so ``checksum mismatch, Last Line: L`` and ``No Checksum
    with line number, Last Line: L`` refused line L+1 itself; ``Line Number is not Last
    Line Number+1`` refused another number and Prusa's ``No Line Number with checksum`` a
    line without one. Repetier (gcode.cpp) and OctoPrint's VirtualPrinter say ``expected
    line X got Y``; both check the checksum first, so their checksum errors name no
    number."""
    pair = _EXPECTED_GOT.search(line)
    if pair:
        return int(pair.group(1)), int(pair.group(2))
    last = _LAST_LINE.search(line)
    if last is None:
        return None, None
    expects = int(last.group(1)) + 1
    lowered = line.lower()
    numbered = "line number is not" not in lowered and "no line number" not in lowered
    return expects, expects if numbered else None


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
    it rejects a line; ``sequenced``: lines may be sent ahead, because the firmware
    refuses a line whose number is not the last one + 1 or (Klipper, on its
    pseudo-terminal) loses none (RepRapFirmware does neither, so only one line may be
    unanswered there); ``echo_word``: its unknown-command echo names the command word
    alone (Klipper: ``// Unknown command:"M117"``), not the whole line (Marlin).
    """

    name: str
    resend_ok: bool | None
    drains: bool
    sequenced: bool = True
    echo_word: bool = False

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
        return Firmware("Klipper", resend_ok=False, drains=False, echo_word=True)
    return Firmware("unknown", resend_ok=None, drains=flavour == "marlin")
