"""Link benchmark: throughput at 115200 baud, and 100k-line jobs under injected faults.

Run: ``python benchmarks/link_throughput.py`` (about a minute; ``--lines`` changes the
size of the throughput job). It prints

1. the line rate of the send-ahead sender on the emulator at 115200 baud with real
   byte timing (10 bits per byte), as a share of the byte-limited line rate
   (baud / 10 / mean bytes per framed line), next to a one-line-per-ok sender on the
   same emulator in the same run; Marlin and GRBL, without and with 1 ms of one-way
   latency (a USB serial adapter);
2. a 100 000-line job on ``sim://marlin`` with 1 % corrupted lines and 0.1 % lost
   ``ok`` and on ``sim://grbl`` with lost, garbled and spurious answers: whether the
   emulator's execution trace equals the file, command for command.

The exit code is 1 if the send-ahead rate is below 90 % of the byte-limited rate at
115200 baud without latency, or a trace differs from its file.
"""

from __future__ import annotations

import argparse
import random
import sys
import time

from fabkit.link.gcode import Command, commands_from_lines, frame_marlin
from fabkit.link.ports import open_port
from fabkit.link.send import stream_job
from fabkit.link.session import LinkOptions
from fabkit.machines import load_machine

BAUD = 115200
HOUSEKEEPING = ("M110 N0", "M105")


def marlin_job(n: int) -> list[Command]:
    rng = random.Random(1)
    lines = ["G21", "G90", "M82", "G92 E0", "G1 Z0.3 F600"]
    for i in range(n):
        x, y = rng.uniform(10, 200), rng.uniform(10, 200)
        lines.append(f"G1 X{x:.3f} Y{y:.3f} E{0.01 * (i + 1):.4f} F2400")
    return commands_from_lines(lines)


def grbl_job(n: int) -> list[Command]:
    rng = random.Random(1)
    lines = ["G21", "G90", "G94", "M8", "F1200"]
    lines += [f"G1 X{rng.uniform(10, 200):.3f} Y{rng.uniform(10, 200):.3f}" for _ in range(n)]
    return commands_from_lines(lines)


def framed_bytes(job: list[Command], protocol: str) -> float:
    """Mean bytes per line on the wire (Marlin lines are numbered from 2)."""
    if protocol == "marlin":
        total = sum(len(frame_marlin(i + 2, c.text)) for i, c in enumerate(job))
    else:
        total = sum(len(c.text) + 1 for c in job)
    return total / len(job)


def throughput(protocol: str, n: int, latency_ms: float) -> tuple[float, float, float]:
    """Lines/s of the send-ahead and the one-line-per-ok sender, and the byte limit."""
    job = marlin_job(n) if protocol == "marlin" else grbl_job(n)
    machine = load_machine("marlin_generic" if protocol == "marlin" else "grbl_diw")
    limit = BAUD / 10 / framed_bytes(job, protocol)
    rates = []
    for window in (None, 1):
        url = f"sim://{protocol}?time_scale=0&latency_ms={latency_ms:g}"
        report = stream_job(
            open_port(url, BAUD), job, machine, options=LinkOptions(window_lines=window)
        )
        rates.append(report.lines_per_s)
    return rates[0], rates[1], limit


def faulty(url: str, job: list[Command], machine: str) -> bool:
    port = open_port(url, BAUD)
    start = time.monotonic()
    report = stream_job(port, job, load_machine(machine), options=LinkOptions(probe_min_s=0.02))
    elapsed = time.monotonic() - start
    trace = [e.command for e in port.emulator.trace if e.command not in HOUSEKEEPING]
    exact = trace == [c.text for c in job]
    stats = port.emulator.stats()
    print(
        f"  {url}\n    {len(job)} lines in {elapsed:.1f} s ({len(job) / elapsed:.0f} lines/s): "
        f"trace {'equals' if exact else 'DIFFERS FROM'} the file; "
        f"{stats.corrupted_lines} corrupted lines, {stats.dropped_oks} lost oks, "
        f"{stats.garbled_lines} garbled and {stats.spurious_lines} spurious answers; "
        f"{report.resends} resends, {report.probes} probes, {report.recoveries} recoveries"
    )
    return exact


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lines", type=int, default=2000, help="throughput job size")
    parser.add_argument("--faulty-lines", type=int, default=100_000, help="fault job size")
    args = parser.parse_args()
    ok = True
    print(f"1. throughput at {BAUD} baud, real byte timing, {args.lines}-line jobs")
    for protocol in ("marlin", "grbl"):
        for latency_ms in (0.0, 1.0):
            ahead, single, limit = throughput(protocol, args.lines, latency_ms)
            share = ahead / limit
            ok &= share >= 0.9 or latency_ms > 0
            print(
                f"  {protocol:6s} latency {latency_ms:g} ms: byte limit {limit:6.1f} lines/s; "
                f"send-ahead {ahead:6.1f} ({100 * share:5.1f} %), one line per ok "
                f"{single:6.1f} ({100 * single / limit:5.1f} %); ratio {ahead / single:.2f}"
            )
    print(f"2. {args.faulty_lines}-line jobs with injected faults (no byte timing)")
    n = args.faulty_lines
    ok &= faulty(
        "sim://marlin?time_scale=0&baud=0&corrupt=0.01&drop_ok=0.001&seed=3",
        marlin_job(n - 5),
        "marlin_generic",
    )
    ok &= faulty(
        "sim://grbl?time_scale=0&baud=0&drop_ok=0.001&garble=0.005&noise=0.01&seed=3",
        grbl_job(n - 5),
        "grbl_diw",
    )
    print("all requirements met" if ok else "REQUIREMENT NOT MET")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
