"""G-code as the link sees it, and as each firmware reads it.

A *command* is one non-empty file line with its comments (``; ...`` and ``( ... )``) and
surrounding blanks removed; the text is otherwise sent exactly as written, so an
emulator trace can be compared with the file command by command.

The pre-flight check must read a command's text exactly as the firmware will, so this
module has one reader per family (rules from the firmware sources, cited at each one):

* :func:`read_grbl`: GRBL 1.1 (gnea/grbl ``protocol.c``, ``gcode.c``, ``nuts_bolts.c``)
  and grblHAL (``protocol.c``, ``gcode.c``): blanks inside words are dropped before
  parsing, so ``G1 X4 00`` is ``X400``; a line GRBL would answer with ``error:N`` is
  refused with that number.
* :func:`read_marlin`: Marlin 2.x (``gcode/parser.cpp``, ``parser.h``), Klipper
  (``klippy/gcode.py``), RepRapFirmware and Hyrel. These disagree on text outside a
  common grammar (Marlin reads ``X4 00`` as ``X4``, Klipper refuses it; Marlin ignores
  lower case unless built with ``GCODE_CASE_INSENSITIVE``, Klipper upper-cases; Marlin
  keeps the last of two ``X`` words, ``FASTER_GCODE_PARSER`` off the first), so text
  outside it is refused, naming the problem.
* :func:`read_extended`: a Klipper extended command, ``NAME KEY=VALUE ...``.

:func:`firmware_reader` picks the reader of a machine profile's firmware: the pre-flight
check, ``fabkit verify`` and the duration estimate read every command through it.

Every refusal is a :class:`GcodeError` whose message lacks the file and line; the check
adds them.
"""

from __future__ import annotations

import re
import stat
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fabkit.errors import FabkitError
from fabkit.machines import MachineProfile

MAX_JOB_BYTES = 64 * 1024 * 1024
"""Largest G-code file ``fabkit send`` reads (bytes): a sheet's job is far smaller."""
MAX_JOB_LINES = 2_000_000
"""Most lines in a G-code file."""
MAX_LINE_CHARS = 4096
"""Longest file line, comment included (characters)."""

_PAREN_COMMENT = re.compile(r"\([^)]*\)")
_WORD = re.compile(r"([A-Za-z])\s*([-+]?(?:\d+\.?\d*|\.\d+))")
_LINE_END = re.compile(r"\r\n|\r|\n")
_LINE_END_BYTES = re.compile(rb"\r\n|\r|\n")


class GcodeError(FabkitError):
    """A command the check refuses; the message lacks the file and line (added later)."""


@dataclass(frozen=True, slots=True)
class Command:
    """One command of a job: its 1-based line in the file and its text (comments removed)."""

    file_line: int
    text: str


class Commands(Sequence[Command]):
    """A job's commands held as two columns, ``texts`` and their 1-based ``file_lines``:
    a :class:`Command` is made only when one is asked for (a million objects made up
    front cost more than the reading)."""

    __slots__ = ("texts", "file_lines")

    def __init__(self, texts: list[str], file_lines: list[int]) -> None:
        self.texts = texts
        self.file_lines = file_lines

    def __len__(self) -> int:
        return len(self.texts)

    def __getitem__(self, index):  # int -> Command, slice -> Commands
        if isinstance(index, slice):
            return Commands(self.texts[index], self.file_lines[index])
        return Command(self.file_lines[index], self.texts[index])

    def __iter__(self) -> Iterator[Command]:
        return map(Command, self.file_lines, self.texts)

    def __eq__(self, other: object) -> bool:
        if isinstance(other, Commands):
            return self.texts == other.texts and self.file_lines == other.file_lines
        return isinstance(other, Sequence) and list(self) == list(other)

    __hash__ = None  # type: ignore[assignment]  # mutable lists inside

    def __repr__(self) -> str:
        return f"Commands({len(self)} commands)"


def job_texts(job: Sequence[Command]) -> list[str]:
    """The commands' texts, in order (a :class:`Commands` holds them as they are)."""
    return job.texts if isinstance(job, Commands) else [command.text for command in job]


@dataclass(frozen=True)
class Block:
    """One command as a firmware reads it.

    ``codes``: the command words in order: ``G1``; for GRBL every G and M word of the
    block (``G91``, ``G38.2``, ``G92.1``, ``M8``) or a system command (``$H``); a Klipper
    extended command's name. ``values``: value word letter -> number, as written (mm,
    mm/min; no unit conversion). ``flags``: letters given without a number (Marlin
    ``G28 X``). ``params``: a Klipper extended command's ``KEY=VALUE`` pairs.
    """

    codes: tuple[str, ...]
    values: Mapping[str, float] = field(default_factory=dict)
    flags: frozenset[str] = frozenset()
    params: Mapping[str, str] = field(default_factory=dict)


def strip_comment(line: str) -> str:
    """``line`` without ``;`` and ``( )`` comments and surrounding blanks."""
    return _PAREN_COMMENT.sub("", line.split(";", 1)[0]).strip()


def commands_from_lines(lines: Iterable[str], first_line: int = 1) -> Commands:
    """The commands of ``lines`` (blank and comment-only lines skipped)."""
    texts = [
        line.strip() if ";" not in line and "(" not in line else strip_comment(line)
        for line in lines
    ]  # nothing to strip but blanks without a comment
    if all(texts):
        return Commands(texts, list(range(first_line, first_line + len(texts))))
    numbers = [number for number, text in enumerate(texts, first_line) if text]
    return Commands([text for text in texts if text], numbers)


def read_job(path: str | Path) -> Commands:
    """Read a G-code file into commands (FabkitError, one line, for a file that is missing,
    not a regular file, not ASCII, or over :data:`MAX_JOB_BYTES`, :data:`MAX_JOB_LINES` or
    :data:`MAX_LINE_CHARS`: the size is checked before anything is read)."""
    return read_job_bytes(path)[1]


def read_job_bytes(path: str | Path) -> tuple[bytes, Commands]:
    """The bytes of a G-code file and its commands, read once (so that a printer host gets
    exactly the bytes that were checked); refused as by :func:`read_job`."""
    path = Path(path)
    raw = _read_bounded(path)
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError as exc:
        line = len(_LINE_END.findall(raw[: exc.start].decode("ascii"))) + 1
        raise FabkitError(f"{path}:{line}: non-ASCII byte in G-code") from None
    lines = text.split("\n") if "\r" not in text else _LINE_END.split(text)  # the same lines
    if len(lines) > MAX_JOB_LINES:
        raise FabkitError(f"{path}: more than {MAX_JOB_LINES} lines, the limit for a G-code file")
    long = _long_line(raw)
    if long is not None:
        line = len(_LINE_END.findall(text[:long])) + 1
        raise FabkitError(
            f"{path}:{line}: line longer than {MAX_LINE_CHARS} characters, the limit for G-code"
        )
    return raw, commands_from_lines(lines)


def _long_line(raw: bytes) -> int | None:
    """The offset of the first line of ``raw`` longer than :data:`MAX_LINE_CHARS` (its end
    of line not counted), or None."""
    data = np.frombuffer(raw, np.uint8)
    breaks = np.flatnonzero((data == ord("\n")) | (data == ord("\r")))
    starts = np.concatenate(([0], breaks + 1))
    lengths = np.concatenate((breaks, [len(raw)])) - starts
    long = np.flatnonzero(lengths > MAX_LINE_CHARS)
    return int(starts[long[0]]) if len(long) else None


def line_ends(raw: bytes) -> list[int]:
    """The byte offset just past each line of a file's bytes ``raw`` (its end of line
    included; a last line without one ends at ``len(raw)``), lines split as by
    :func:`read_job`: file line ``n`` ends at ``line_ends(raw)[n - 1]``."""
    ends = [match.end() for match in _LINE_END_BYTES.finditer(raw)]
    return ends if ends and ends[-1] == len(raw) else [*ends, len(raw)]


def _read_bounded(path: Path) -> bytes:
    """The bytes of ``path``, refusing a non-regular or too large file before reading it."""
    try:
        info = path.stat()
        if not stat.S_ISREG(info.st_mode):
            raise FabkitError(f"cannot read G-code file {path}: not a regular file")
        if info.st_size > MAX_JOB_BYTES:
            raise FabkitError(_too_large(path, info.st_size))
        with path.open("rb") as handle:
            raw = handle.read(MAX_JOB_BYTES + 1)
    except OSError as exc:
        raise FabkitError(f"cannot read G-code file {path}: {exc.strerror}") from None
    if len(raw) > MAX_JOB_BYTES:  # it grew while being read
        raise FabkitError(_too_large(path, len(raw)))
    return raw


def _too_large(path: Path, size: int) -> str:
    return (
        f"{path}: G-code file of {size / 2**20:.1f} MiB is larger than the limit of "
        f"{MAX_JOB_BYTES // 2**20} MiB"
    )


def words(text: str) -> dict[str, float]:
    """The letter/number words of a command, letters upper-cased (``G1 X10`` -> G, X).

    A loose reading for the emulator and the writers' tests; the check uses the
    firmware readers below.
    """
    return {letter.upper(): float(value) for letter, value in _WORD.findall(text)}


def code_of(text: str) -> str:
    """The command word, upper-cased: ``G1``, ``M104``, ``G38.2``, ``$H``, ``T0``.

    A line that starts with an axis word (GRBL's modal motion) gives that letter;
    an extended (Klipper-style) command gives its name.
    """
    match = re.match(r"\s*([A-Za-z$])\s*([-+]?\d*\.?\d*)", text)
    if match is None:
        return text.split()[0].upper() if text.split() else ""
    letter, number = match.groups()
    if letter == "$":
        return "$" + text.strip()[1:2].upper()
    if letter.upper() in "GMT" and any(c.isdigit() for c in number):  # "G+": no number
        value = float(number)
        return f"{letter.upper()}{int(value)}" if value.is_integer() else f"{letter.upper()}{value}"
    head = text.split()[0].upper()
    return head if "_" in head or len(head) > 1 and head.isalpha() else letter.upper()


def marlin_checksum(payload: bytes) -> int:
    """XOR of all bytes of ``payload`` (Marlin, RepRap and Klipper line checksum)."""
    value = 0
    for byte in payload:
        value ^= byte
    return value


def frame_marlin(number: int, text: str) -> bytes:
    """``N<number> <text>*<checksum>\\n`` as bytes."""
    payload = f"N{number} {text}".encode("ascii")
    return payload + b"*%d\n" % marlin_checksum(payload)


def text_checksums(texts: Sequence[str]) -> list[int] | None:
    """:func:`marlin_checksum` of each text's bytes, all at once (numpy: the XOR of a text
    is that of two prefixes of the joined texts); None if a text is not ASCII."""
    joined = "".join(texts)
    if not joined.isascii():
        return None
    data = np.frombuffer(joined.encode("ascii"), np.uint8)
    lengths = np.fromiter(map(len, texts), np.int64, len(texts))
    ends = np.cumsum(lengths)
    prefixes = np.concatenate(([0], np.bitwise_xor.accumulate(data)))  # XOR of data[:i]
    return (prefixes[ends] ^ prefixes[ends - lengths]).tolist()


def frame_summed(number: int, text: str, text_sum: int) -> bytes:
    """:func:`frame_marlin` of an ASCII ``text`` whose checksum is ``text_sum`` (from
    :func:`text_checksums`): only the ``N<number> `` head is summed here."""
    head = b"N%d " % number
    return b"%s%s*%d\n" % (head, text.encode("ascii"), marlin_checksum(head) ^ text_sum)


# -- GRBL ----------------------------------------------------------------------------------

GRBL_G = frozenset({
    "G0", "G1", "G2", "G3", "G4", "G10", "G17", "G18", "G19", "G20", "G21", "G28", "G28.1",
    "G30", "G30.1", "G38.2", "G38.3", "G38.4", "G38.5", "G40", "G43.1", "G49", "G53", "G54",
    "G55", "G56", "G57", "G58", "G59", "G61", "G80", "G90", "G91", "G91.1", "G92", "G92.1",
    "G93", "G94",
})  # fmt: skip
"""The G words GRBL 1.1 parses (gcode.c, STEP 2)."""
GRBL_M = frozenset({"M0", "M1", "M2", "M30", "M3", "M4", "M5", "M7", "M8", "M9", "M56"})
"""Its M words (M7 and M56 are compile options)."""
GRBL_VALUE_LETTERS = "FIJKLNPRSTXYZ"
"""Value words GRBL knows; any other letter is error:20."""
GRBL_MAX_DIGITS = 8
"""GRBL's read_float keeps 8 digits, counting leading zeros; grblHAL skips leading zeros.
Longer numbers read differently on the two and are refused."""

_G_GROUPS = {
    "G4": 0, "G10": 0, "G28": 0, "G28.1": 0, "G30": 0, "G30.1": 0, "G53": 0, "G92": 0,
    "G92.1": 0, "G0": 1, "G1": 1, "G2": 1, "G3": 1, "G38.2": 1, "G38.3": 1, "G38.4": 1,
    "G38.5": 1, "G80": 1, "G17": 2, "G18": 2, "G19": 2, "G90": 3, "G91": 3, "G91.1": 4,
    "G93": 5, "G94": 5, "G20": 6, "G21": 6, "G40": 7, "G43.1": 8, "G49": 8, "G54": 12,
    "G55": 12, "G56": 12, "G57": 12, "G58": 12, "G59": 12, "G61": 13,
}  # fmt: skip
"""Modal group of each G word (gcode.h, NIST RS274-NGC table 4): two in a block is error:21."""
_M_GROUPS = {"M0": 4, "M1": 4, "M2": 4, "M30": 4, "M3": 7, "M4": 7, "M5": 7, "M7": 8, "M8": 8,
             "M9": 8, "M56": 9}  # fmt: skip
_GRBL_POSITIVE = "FNPST"  # negative values are error:4
_GRBL_NUMBER = re.compile(r"[-+]?(\d*)\.?(\d*)")


def grbl_line(text: str) -> str:
    """The line GRBL's protocol loop hands its parser (grbl/protocol.c): blanks and control
    characters dropped everywhere, ``( )`` and ``;`` comments removed, letters upper-cased.
    grblHAL (``gc_normalize_block``) does the same."""
    if "(" not in text and ";" not in text and text.isascii() and text.isprintable():
        return text.replace(" ", "").upper()
    out: list[str] = []
    in_paren = False
    for char in text:
        if in_paren:
            in_paren = char != ")"
        elif char == ";":
            break
        elif char == "(":
            in_paren = True
        elif char > " ":
            out.append(char.upper() if "a" <= char <= "z" else char)
    return "".join(out)


def grbl_reject(text: str, number: int, reason: str) -> GcodeError:
    """GRBL would answer ``error:number``: the line would not run and the job stop."""
    return GcodeError(f"GRBL rejects '{text}': {reason} (error:{number})")


def read_grbl(text: str, extra_axes: str = "") -> Block:
    """Read ``text`` as GRBL 1.1 does (see :func:`grbl_line`, then gcode.c STEP 2: words,
    command numbers, modal groups, repeated and negative words). ``extra_axes``: axis
    letters the controller has besides XYZ (grblHAL's ``A``). Semantic checks that need
    the modal state (gcode.c STEP 3) are the check's."""
    line = grbl_line(text)
    if "/" in line:  # GRBL drops it anywhere, grblHAL only in front (block delete)
        raise GcodeError(f"'/' in '{text}': GRBL and grblHAL read it differently")
    if line.startswith("$"):
        return Block((_grbl_system(line),))
    codes: list[str] = []
    groups: set[str] = set()
    values: dict[str, float] = {}
    position = 0
    while position < len(line):
        letter = line[position]
        if not "A" <= letter <= "Z":
            raise grbl_reject(text, 1, f"'{letter}' where a word letter is expected")
        value, position = _grbl_number(text, line, position + 1)
        if letter in "GM":
            code = _grbl_command(text, letter, value)
            group = f"{letter}{(_G_GROUPS if letter == 'G' else _M_GROUPS)[code]}"
            if group in groups:
                raise grbl_reject(text, 21, f"two commands of one modal group ({code})")
            groups.add(group)
            codes.append(code)
            continue
        if letter not in GRBL_VALUE_LETTERS + extra_axes:
            raise grbl_reject(text, 20, f"GRBL has no {letter} word")
        if letter in values:
            raise grbl_reject(text, 25, f"{letter} given twice")
        if letter in _GRBL_POSITIVE and value < 0:
            raise grbl_reject(text, 4, f"{letter} must not be negative")
        if letter == "T" and value > 255:
            raise grbl_reject(text, 38, "tool number above 255")
        values[letter] = value
    return Block(tuple(codes), values)


def _grbl_system(line: str) -> str:
    """``$H`` (homing), else the name of another system command (``$J``, ``$X``, ``$110``)."""
    return "$H" if line == "$H" else "$" + line[1:].split("=", 1)[0][:8]


def _grbl_number(text: str, line: str, start: int) -> tuple[float, int]:
    """GRBL's read_float (nuts_bolts.c): sign, digits and one '.', no exponent."""
    match = _GRBL_NUMBER.match(line, start)
    digits = match.group(1) + match.group(2)
    if not digits:
        raise grbl_reject(text, 2, f"no number after '{line[start - 1]}'")
    if len(digits) > GRBL_MAX_DIGITS:
        raise GcodeError(
            f"number '{match.group(0)}' in '{text}' has more than {GRBL_MAX_DIGITS} digits: "
            "GRBL and grblHAL read it differently"
        )
    return float(match.group(0)), match.end()


def _grbl_command(text: str, letter: str, value: float) -> str:
    """``G38.2``, ``M8``: the command GRBL makes of a G or M number (gcode.c: the integer
    part and the hundredths, rounded)."""
    if not 0 <= value < 256:
        raise GcodeError(f"unknown command {letter}{value:g} for flavour grbl")
    whole = int(value)
    hundredths = int(100 * (value - whole) + 0.5)
    name = f"{letter}{whole}"
    if hundredths:
        name += f".{hundredths // 10}" if hundredths % 10 == 0 else f".{hundredths:02d}"
    if name not in (GRBL_G if letter == "G" else GRBL_M):
        if hundredths and f"{letter}{whole}" in GRBL_G | GRBL_M:
            raise grbl_reject(text, 23, f"{name} is not an integer command")
        raise GcodeError(f"unknown command {name} for flavour grbl")
    return name


# -- Marlin, Klipper, RepRapFirmware, Hyrel --------------------------------------------

_MARLIN_COMMAND = re.compile(r"([GMTgmt])(\d+)(\.\d*)?")
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)")
STRING_COMMANDS = frozenset({"M117", "M118", "M0", "M1"})
"""Marlin commands whose text after the code is a message, not parameters."""
_PLAIN_MARLIN = re.compile(r"([GM](?:0|[1-9]\d*))((?: [A-Z][-+]?(?:\d+\.?\d*|\.\d+))*)")
"""The lines fabkit writes, read at once: an upper-case G or M code without a leading
zero or fraction, then parameters each after one blank, a letter and a number."""
_PLAIN_WORD = re.compile(r" ([A-Z])([-+]?(?:\d+\.?\d*|\.\d+))")


def read_marlin(text: str, *, upper: bool) -> Block:
    """Read ``text`` as Marlin 2.x (gcode/parser.cpp) and the Marlin-like firmwares do.

    The command is ``G``/``M``/``T`` and digits (``G01`` is refused: Klipper does not
    know it; ``G92.1`` reads as that code). Then parameters: a letter, optional blanks
    and a number (``[-+]`` digits, one ``.``; no exponent: Marlin's value_float stops at
    ``E``, so ``X1E3`` is ``X1 E3`` on all of them) or a letter alone (a flag). Refused:
    a number after blanks that follows a number (``X4 00``: Marlin X4, Klipper an error,
    GRBL X400), a repeated letter, a malformed number, any other character, and lower
    case unless ``upper`` (Klipper upper-cases every line; Marlin needs a build option).
    """
    plain = _PLAIN_MARLIN.fullmatch(text)
    if plain is not None and plain.group(1) not in STRING_COMMANDS:
        given = _PLAIN_WORD.findall(plain.group(2))
        values = {letter: float(number) for letter, number in given}
        if len(values) == len(given):  # else a letter given twice: refused below
            return Block((plain.group(1),), values)
    match = _MARLIN_COMMAND.match(text)
    if match is None:
        return Block((text.split()[0].upper(),))
    letter, number, fraction = match.groups()
    if not upper and letter.islower():
        raise _lower_case(letter, text)
    code = letter.upper() + number + (fraction or "")
    if len(number) > 1 and number[0] == "0":
        canonical = f"{letter.upper()}{int(number)}"
        raise GcodeError(f"'{text}': write {canonical} (Klipper does not know {code})")
    if code in STRING_COMMANDS:
        return Block((code,))
    rest = text[match.end() :]
    if upper:
        rest = rest.upper()
    values: dict[str, float] = {}
    flags: set[str] = set()
    position = 0
    while position < len(rest):
        position = _skip_blanks(rest, position)
        if position == len(rest):
            break
        letter = rest[position]
        _expect_letter(text, code, rest, position)
        if letter in values or letter in flags:
            raise GcodeError(f"{letter} given twice in '{text}': firmwares keep different ones")
        number = _NUMBER.match(rest, _skip_blanks(rest, position + 1))
        if number is None:
            if rest[position + 1 : position + 2].isalpha():
                raise GcodeError(
                    f"'{letter}{rest[position + 1]}' in '{text}': Klipper reads letters "
                    f"together as one word: write {letter} {rest[position + 1]}"
                )
            flags.add(letter)
            position += 1
            continue
        position = number.end()
        if position < len(rest) and (rest[position] == "." or rest[position].isdigit()):
            raise GcodeError(f"malformed number after {letter} in '{text}'")
        values[letter] = float(number.group(0))
    return Block((code,), values, frozenset(flags))


def _skip_blanks(text: str, position: int) -> int:
    while position < len(text) and text[position] == " ":
        position += 1
    return position


def _expect_letter(text: str, code: str, rest: str, position: int) -> None:
    char = rest[position]
    if "A" <= char <= "Z":
        return
    if "a" <= char <= "z":
        raise _lower_case(char, text)
    if char.isdigit() or char in "+-.":
        number = _NUMBER.match(rest, position)
        stray = number.group(0) if number else char
        raise GcodeError(
            f"stray number '{stray}' in '{text}': Marlin ignores it, Klipper refuses the line "
            "and GRBL joins it to the word before (remove the blank)"
        )
    raise GcodeError(f"unexpected character '{char}' in {code} ('{text}')")


def _lower_case(letter: str, text: str) -> GcodeError:
    return GcodeError(
        f"lower-case '{letter}' in '{text}': Marlin ignores lower case unless built with "
        "GCODE_CASE_INSENSITIVE: write upper case"
    )


_EXTENDED_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")
_EXTENDED_PARAM = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)=([A-Za-z0-9_.+-]*)")


def is_extended(text: str) -> bool:
    """A Klipper extended command (``SET_PRESSURE_ADVANCE ...``): a name that is not a letter
    and a number (klippy/gcode.py is_traditional_gcode)."""
    head = text.split()[0]
    return _EXTENDED_NAME.fullmatch(head) is not None and not (len(head) > 1 and head[1].isdigit())


def read_extended(text: str) -> Block:
    """``NAME KEY=VALUE ...`` (klippy/gcode.py _get_extended_params, without shell quoting:
    values of letters, digits and ``_ . + -`` only)."""
    name, *pairs = text.split()
    params: dict[str, str] = {}
    for pair in pairs:
        match = _EXTENDED_PARAM.fullmatch(pair)
        if match is None:
            raise GcodeError(f"'{pair}' in '{text}' is not KEY=VALUE (letters, digits, _ . + -)")
        params[match.group(1).upper()] = match.group(2)
    return Block((name.upper(),), params=params)


def extra_axes(machine: MachineProfile) -> str:
    """The axis letters ``machine`` has besides X, Y, Z: grblHAL's ``A`` on a GRBL laser
    writer (its scan axis), else none."""
    return "A" if machine.flavour == "grbl" and machine.kind == "laser_writer" else ""


def firmware_reader(machine: MachineProfile) -> Callable[[str], Block]:
    """The reader of ``machine``'s firmware: GRBL's (with :func:`extra_axes`), a Klipper
    extended command's or Marlin's (Klipper upper-cases)."""
    if machine.flavour == "grbl":
        extra = extra_axes(machine)
        return lambda text: read_grbl(text, extra)
    if machine.flavour == "klipper":
        return lambda text: (
            read_extended(text) if is_extended(text) else read_marlin(text, upper=True)
        )
    return lambda text: read_marlin(text, upper=False)
