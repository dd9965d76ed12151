"""The Klipper-wording responder (tests/klipper_responder.py) against transcripts of a real
klippy (commit 84104bbbd, ``v0.13.0-730-g84104bbbd``, unmodified, on its pty, debug-output
mode: no MCU, so M109/M190 do not wait: ``heat_reports=0``), with a raw pyserial client."""

from __future__ import annotations

import time

import serial

from tests.klipper_responder import SHUTDOWN_MESSAGE, KlipperResponder

# Recorded from klippy with an extruder and a heated bed (``>`` sent, ``<`` received).
WITH_HEATERS = """
> N0 M110 N0*125
< ok
> N1 M115*39
< ok FIRMWARE_NAME:Klipper FIRMWARE_VERSION:v0.13.0-730-g84104bbbd
> N2 M105*37
< ok B:0.0 /0.0 T0:0.0 /0.0
> N3 G1 X10 Y10 F3000*79
< !! Must home axis first: 10.000 10.000 0.000 [0.000]
< ok
> N4 M114*35
< X:0.000 Y:0.000 Z:0.000 E:0.000
< ok
> N5 G28*22
< ok
> N6 M114*33
< X:0.000 Y:0.000 Z:0.000 E:0.000
< ok
> N7 G1 X300 Y10*28
< !! Move out of range: 300.000 10.000 0.000 [0.000]
< ok
> N8 G1 X10 Y10 Z1 F3000*15
< ok
> N9 FOO*17
< // Unknown command:"FOO"
< ok
> N10 M117 Hello world*53
< // Unknown command:"M117"
< ok
> N11 M118 hi*58
< // Unknown command:"M118"
< ok
> N12 G4 P100*95
< ok
> N13 M400*21
< ok
> N14 M104 S200*82
< ok
> N15 M109 S200*94
< ok
> N16 M190 S60*105
< ok
> N17 M105*17
< ok B:0.0 /60.0 T0:0.0 /200.0
> N18 STATUS*115
< // Klipper state: Ready
< ok
> N19 M105*99
< ok B:0.0 /60.0 T0:0.0 /200.0
> N24 G1 X20*0
< ok
> G1 X30
< ok
> M114
< X:30.000 Y:10.000 Z:1.000 E:0.000
< ok
> N20 M112*19
< // Klipper state: Shutdown
< ok
> N21 G1 X40*103
< // Shutdown due to M112 command
< // Once the underlying issue is corrected, use the
< // "FIRMWARE_RESTART" command to reset the firmware, reload the
< // config, and restart the host software.
< // Printer is shutdown
< !! Shutdown due to M112 command
< ok
> N22 M105*23
< ok B:0.0 /60.0 T0:0.0 /200.0
> N23 M115*23
< ok FIRMWARE_NAME:Klipper FIRMWARE_VERSION:v0.13.0-730-g84104bbbd
> N24 M114*17
< X:30.000 Y:10.000 Z:1.000 E:0.000
< ok
> N25 M110 N0*74
< ok
> N26 STATUS*126
< // Shutdown due to M112 command
< // Once the underlying issue is corrected, use the
< // "FIRMWARE_RESTART" command to reset the firmware, reload the
< // config, and restart the host software.
< // Printer is shutdown
< // Klipper state: Not ready
< !! Shutdown due to M112 command
< ok
"""

# Recorded from klippy with neither extruder nor heaters.
WITHOUT_HEATERS = """
> N0 M110 N0*125
< ok
> N1 M115*39
< ok FIRMWARE_NAME:Klipper FIRMWARE_VERSION:v0.13.0-730-g84104bbbd
> N2 M105*37
< ok T:0
> N3 G28*19
< ok
> N4 G1 X10 Y10 E1 F3000*91
< !! Extrude when no extruder present: 10.000 10.000 0.000 [1.000]
< ok
> N5 M104 S0*99
< ok
> N6 M104 S200*80
< // Unknown command:"M104"
< ok
> N7 M106 S255*88
< // Unknown command:"M106"
< ok
> N8 M107*16
< ok
> N9 M114*40
< X:0.000 Y:0.000 Z:0.000 E:0.000
< ok
"""

# Recorded from klippy with heaters: blank line, comments, M110 with a number, no [respond].
ODDITIES = """
>
< ok
> ; just a comment
< ok
> N5 G1 X10 ; comment*99
< !! Must home axis first: 10.000 0.000 0.000 [0.000]
< ok
> N6 M105 S0*97
< ok B:0.0 /0.0 T0:0.0 /0.0
> N7 M110 N7*11
< ok
> RESPOND MSG=hi
< // Unknown command:"RESPOND"
< ok
"""

SHUTDOWN_LINES = [f"// {line}" for line in SHUTDOWN_MESSAGE.split("\n")]


def exchanges(transcript: str) -> list[tuple[str, list[str]]]:
    """The transcript as (line sent, answers) pairs."""
    pairs: list[tuple[str, list[str]]] = []
    for line in transcript.strip("\n").split("\n"):
        if line.startswith(">"):
            pairs.append((line[2:], []))
        else:
            pairs[-1][1].append(line[2:])
    return pairs


def read_until(port: serial.Serial, prefix: str = "ok") -> list[str]:
    """Answers up to and including the first one that starts with ``prefix``."""
    got: list[str] = []
    while not got or not got[-1].startswith(prefix):
        raw = port.readline()
        if not raw:
            raise TimeoutError(f"no {prefix!r} after {got}")
        got.append(raw.decode().rstrip("\n"))
    return got


def replay(machine: KlipperResponder, transcript: str) -> None:
    with serial.Serial(machine.path, 250000, timeout=2) as port:
        for sent, answers in exchanges(transcript):
            port.write(sent.encode() + b"\n")
            assert read_until(port) == answers, sent


def test_answers_like_klippy_with_heaters():
    with KlipperResponder(heat_reports=0) as machine:
        replay(machine, WITH_HEATERS)
    assert machine.state == "shutdown"
    assert machine.executed[:4] == ["M110 N0", "M115", "M105", "M114"]  # no N, no checksum
    assert "G1 X300 Y10" not in machine.executed and "G1 X40" not in machine.executed
    assert machine.errors[:2] == [
        "Must home axis first: 10.000 10.000 0.000 [0.000]",
        "Move out of range: 300.000 10.000 0.000 [0.000]",
    ]


def test_answers_like_klippy_without_heaters():
    with KlipperResponder(heaters=False) as machine:
        replay(machine, WITHOUT_HEATERS)
    assert machine.state == "ready"


def test_blank_lines_comments_and_unchecked_numbers():
    with KlipperResponder() as machine:
        replay(machine, ODDITIES)
    assert machine.executed == ["M105 S0", "M110 N7", "RESPOND MSG=hi"]


def test_a_framed_m112_waits_its_turn_a_bare_one_does_not():
    with KlipperResponder() as machine, serial.Serial(machine.path, 250000, timeout=2) as port:
        port.write(b"N1 G28*18\n")
        assert read_until(port) == ["ok"]
        port.write(b"N2 G1 X10 Y10*43\nN3 G4 P10*95\nN4 M112*37\nN5 M105*34\n")
        answers = [*read_until(port), *read_until(port), *read_until(port), *read_until(port)]
        assert answers == [
            "ok",
            "ok",
            "// Klipper state: Shutdown",
            "ok",
            "ok B:0.0 /0.0 T0:0.0 /0.0",
        ]
    with KlipperResponder() as machine, serial.Serial(machine.path, 250000, timeout=2) as port:
        port.write(b"N1 G28*18\n")
        assert read_until(port) == ["ok"]
        port.write(b"N2 G1 X10 Y10*43\nN3 G4 P10*95\nN4 M112\nN5 M105*34\n")
        refused = [*SHUTDOWN_LINES, "!! Shutdown due to M112 command", "ok"]
        assert read_until(port, "//") == ["// Klipper state: Shutdown"]
        assert read_until(port) == refused and read_until(port) == refused
        assert read_until(port) == ["ok"]
        assert read_until(port) == ["ok B:0.0 /0.0 T0:0.0 /0.0"]
    assert machine.executed == ["G28", "M112", "M105"]


def test_lines_sent_during_a_restart_find_klippy_not_ready():
    machine = KlipperResponder(restart_s=0.5)
    with machine, serial.Serial(machine.path, 250000, timeout=2) as port:
        port.write(b"N1 G28*18\nN2 M112*17\n")
        assert read_until(port) == ["ok"] and read_until(port)[-1] == "ok"
        port.write(b"N4 FIRMWARE_RESTART*50\n")
        assert read_until(port, "//") == ["ok", "// Klipper state: Disconnect"]
        port.write(b"N5 M105*34\nN6 G1 X10*37\n")
        assert read_until(port, "// Klipper state: Ready") == [
            "ok T:0",
            "// Printer is not ready",
            "// The klippy host software is attempting to connect.  Please",
            "// retry in a few moments.",
            "!! Printer is not ready",
            "ok",
            "// Klipper state: Ready",
        ]
        port.write(b"N7 G1 X10*36\n")
        assert read_until(port) == ["!! Must home axis first: 10.000 0.000 0.000 [0.000]", "ok"]
    assert machine.state == "ready"


def test_m109_reports_temperatures_without_ok_while_it_waits():
    # from the source (klippy/extras/heaters.py:348-359): debug-output klippy does not wait
    with KlipperResponder() as machine, serial.Serial(machine.path, 250000, timeout=2) as port:
        port.write(b"M109 S200\n")
        assert read_until(port) == [
            "B:0.0 /0.0 T0:0.0 /200.0",
            "B:0.0 /0.0 T0:100.0 /200.0",
            "ok",
        ]
        port.write(b"M105\n")
        assert read_until(port) == ["ok B:0.0 /0.0 T0:200.0 /200.0"]


def test_a_read_that_is_not_utf8_is_lost_whole():
    with KlipperResponder() as machine, serial.Serial(machine.path, 250000, timeout=0.3) as port:
        port.write(b"N1 M105*38\n\xff\nN2 M114*36\n")
        time.sleep(0.1)
        port.write(b"N3 M114*34\n")
        assert read_until(port) == ["X:0.000 Y:0.000 Z:0.000 E:0.000", "ok"]
    assert machine.executed == ["M114"]


def test_many_lines_at_once_each_get_one_ok_and_run_in_order():
    # (the oks wait in the pty until the write is done: 500 of them fit its buffer)
    job = ["G28", *(f"G1 X{10 + i % 200} Y{10 + i % 7} F6000" for i in range(500))]
    framed = []
    for n, text in enumerate(job, start=1):
        body = f"N{n} {text}"
        checksum = 0
        for byte in body.encode():
            checksum ^= byte
        framed.append(f"{body}*{checksum}\n")
    with KlipperResponder() as machine, serial.Serial(machine.path, 250000, timeout=2) as port:
        port.write("".join(framed).encode())
        answers = [read_until(port) for _ in job]
    assert all(answer == ["ok"] for answer in answers)
    assert machine.executed == job and machine.errors == []
