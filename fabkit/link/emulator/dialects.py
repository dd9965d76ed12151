"""How each Marlin-protocol firmware words its answers, as the emulator reproduces them.

Every fact below was read in the firmware's own source (the file is named on each
field); the emulator (:mod:`fabkit.link.emulator.marlin`) uses them, the sender has its own
reading of the same sources (:mod:`fabkit.link.answers`). Line numbers and checksums
are the RepRap scheme everywhere: ``N<n> <command>*<xor of the bytes before *>``.

=================  ======================================================================
dialect            behaviour on a bad line, acknowledgement, keep-alive
=================  ======================================================================
marlin-2.1         ``Error:checksum mismatch, Last Line: 4`` (or line-number / no-checksum
                   wording), receive buffer drained, ``Resend: 5``, ``ok``; ``ok`` after
                   a command runs; ``echo:busy: processing`` every 2 s while a command
                   blocks. Marlin/src/gcode/queue.cpp (``gcode_line_error`` drains the
                   RX buffer, ``flush_and_request_resend`` prints ``STR_RESEND`` then
                   ``STR_OK``), Marlin/src/core/language.h, gcode.cpp ``host_keepalive``.
marlin-2.0         as 2.1 but no ``ok`` after ``Resend:`` (2.0.9.x queue.cpp:
                   ``flush_and_request_resend`` prints only ``STR_RESEND``).
marlin-1.1         as 2.1; ``MarlinSerial::flush()`` (AVR) empties the receive ring, and
                   ``flush_and_request_resend`` calls ``ok_to_send()``
                   (Marlin/Marlin_main.cpp, MarlinSerial.cpp).
prusa              Marlin 1.x wording plus ``Error:No Line Number with checksum, Last
                   Line: N`` for a ``*`` without ``N``; ``printf("Resend: %ld\\nok\\n")``
                   after ``MYSERIAL.flush()`` (drain) (Firmware/cmdqueue.cpp,
                   Firmware/Marlin_main.cpp ``FlushSerialRequestResend``, ``host_keepalive``).
repetier           ``Error:Wrong checksum`` / ``Error:expected line 5 got 6``, an empty
                   line, ``Resend:5``, ``ok``; no drain (``RFHardwareSerial::flush`` only
                   waits for TX); up to 14 later out-of-order lines, and lines seen
                   already (within 40), answer ``skip 6`` + ``ok``; ``ok 6`` names the line
                   and is sent when the line is queued, not run (``ACK_WITH_LINENUMBER``);
                   ``M105`` prints ``T:...`` when it runs; ``busy:processing`` every 2 s;
                   ``wait`` after 1 s idle with empty buffers; lines end in ``\\r\\n``
                   (src/ArduinoAVR/Repetier/gcode.cpp ``requestResend``,
                   ``checkAndPushCommand``, ``keepAlive``; Communication.cpp; Configuration.h).
smoothieware       ``rs N5`` for a bad checksum or an unexpected line number, no ``Error:``,
                   no ``ok``, no drain; every later line also gets ``rs N5``
                   (src/modules/communication/GcodeDispatch.cpp).
reprapfirmware     RRF 3 in Marlin emulation (``M555 P2``): a line with a bad checksum is
                   discarded without any answer and line numbers are not checked
                   (src/GCodes/GCodeBuffer/StringParser.cpp ``LineFinished``); with
                   ``M575 P0 S1`` (which a link that can corrupt bytes needs) so is a
                   line without a checksum (src/GCodes/GCodes2.cpp); ``ok`` after
                   each command, ``ok T:...`` for M105 (src/GCodes/GCodes.cpp
                   ``HandleReply``).
=================  ======================================================================
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Dialect:
    """One firmware's answers (see the module docstring for the sources).

    ``line_error``: how a rejected numbered line is answered ("marlin": ``Error:`` +
    ``Resend:``, "repetier", "smoothie": ``rs N``, "silent": nothing). ``resend_ok``:
    ``ok`` follows the resend request; ``drain``: the receive buffer is emptied on a
    line error; ``ack_numbered``: ``ok <n>`` names the line; ``ack_on_queue``: ``ok``
    when the line is queued rather than run; ``busy``: the keep-alive line while a
    command blocks ("" = none); ``idle_wait_s``: ``wait`` after that long idle (0 =
    never); ``strict_star``: a ``*`` without ``N`` is a line error (Prusa);
    ``check_sequence``: line numbers must be consecutive; ``checksum_required``: a line
    without a checksum is dropped (RepRapFirmware with ``M575 P0 S1``).
    """

    name: str
    firmware_name: str
    line_error: str = "marlin"
    resend_ok: bool = True
    drain: bool = True
    ack_numbered: bool = False
    ack_on_queue: bool = False
    busy: str = "echo:busy: processing"
    idle_wait_s: float = 0.0
    strict_star: bool = False
    check_sequence: bool = True
    checksum_required: bool = False
    eol: bytes = b"\n"
    banner: tuple[str, ...] = ("start",)


DIALECTS = {
    d.name: d
    for d in (
        Dialect(
            "marlin-2.1",
            "FIRMWARE_NAME:Marlin 2.1.2.1 (fabkit emulator) SOURCE_CODE_URL:"
            "github.com/MarlinFirmware/Marlin PROTOCOL_VERSION:1.0 MACHINE_TYPE:3D Printer "
            "EXTRUDER_COUNT:1",
            banner=("start", "echo:Marlin 2.1.2.1 (fabkit emulator)", "echo:Free Memory: 4096"),
        ),
        Dialect(
            "marlin-2.0",
            "FIRMWARE_NAME:Marlin 2.0.9.3 (fabkit emulator) SOURCE_CODE_URL:"
            "github.com/MarlinFirmware/Marlin PROTOCOL_VERSION:1.0 MACHINE_TYPE:3D Printer "
            "EXTRUDER_COUNT:1",
            resend_ok=False,
            banner=("start", "echo:Marlin 2.0.9.3 (fabkit emulator)"),
        ),
        Dialect(
            "marlin-1.1",
            "FIRMWARE_NAME:Marlin 1.1.9 (fabkit emulator) SOURCE_CODE_URL:"
            "https://github.com/MarlinFirmware/Marlin PROTOCOL_VERSION:1.0 "
            "MACHINE_TYPE:3D Printer EXTRUDER_COUNT:1",
            banner=("start", "echo: External Reset", "Marlin 1.1.9"),
        ),
        Dialect(
            "prusa",
            "FIRMWARE_NAME:Prusa-Firmware 3.13.0 based on Marlin FIRMWARE_URL:"
            "https://github.com/prusa3d/Prusa-Firmware PROTOCOL_VERSION:1.0 "
            "MACHINE_TYPE:Prusa i3 MK3S EXTRUDER_COUNT:1",
            strict_star=True,
            banner=("start", "echo: 3.13.0-7080"),
        ),
        Dialect(
            "repetier",
            "FIRMWARE_NAME:Repetier_1.0.4 COMPILED:Jan  1 2024 FIRMWARE_URL:"
            "https://github.com/repetier/Repetier-Firmware/ PROTOCOL_VERSION:1.0 "
            "MACHINE_TYPE:Mendel EXTRUDER_COUNT:1 REPETIER_PROTOCOL:3",
            line_error="repetier",
            drain=False,
            ack_numbered=True,
            ack_on_queue=True,
            busy="busy:processing",
            idle_wait_s=1.0,
            eol=b"\r\n",
            banner=("start", "Info:External Reset"),
        ),
        Dialect(
            "smoothieware",
            "FIRMWARE_NAME:Smoothieware, FIRMWARE_URL:http%3A//smoothieware.org, "
            "X-SOURCE_CODE_URL:https://github.com/Smoothieware/Smoothieware, "
            "FIRMWARE_VERSION:edge-fabkit, X-SYSTEM_CLOCK:100MHz, X-AXES:5",
            line_error="smoothie",
            resend_ok=False,
            drain=False,
            busy="",
            banner=("Smoothie", "ok"),
        ),
        Dialect(
            "reprapfirmware",
            "FIRMWARE_NAME: RepRapFirmware for Duet 3 MB6HC FIRMWARE_VERSION: 3.5.0 "
            "ELECTRONICS: Duet 3 MB6HC v1.01 FIRMWARE_DATE: 2024-01-01 00:00:00",
            line_error="silent",
            resend_ok=False,
            drain=False,
            busy="",
            check_sequence=False,
            checksum_required=True,
            banner=(),
        ),
    )
}
DEFAULT_DIALECT = "marlin-2.1"
