"""The duration estimate: trapezoids, junctions, look-ahead, and the emulator's own clock."""

from __future__ import annotations

import math
import random

import pytest

from fabkit.gcode.duration import Kinematics, estimate, trapezoid_time
from fabkit.gcode.read import Command, commands_from_lines
from fabkit.link.emulator.port import Emulator, config_from_url
from fabkit.link.host.session import send_eta
from fabkit.machines import load_machine

DIW = load_machine("marlin_diw_pneumatic")  # 500 mm/s^2 in X/Y, 100 in Z, 0.013 mm


def test_a_trapezoid_and_a_triangle():
    # 100 mm at 50 mm/s, 500 mm/s^2: 2.5 mm to accelerate, 2.5 to brake, 95 to cruise
    assert trapezoid_time(100, 0, 0, 50, 500) == pytest.approx(0.1 + 0.1 + 95 / 50)
    # 1 mm is too short to reach 50 mm/s: the peak is sqrt(a * L)
    assert trapezoid_time(1, 0, 0, 50, 500) == pytest.approx(2 * math.sqrt(500) / 500)
    assert trapezoid_time(10, 5, 5, 50, math.inf) == pytest.approx(10 / 50)


def test_straight_pieces_are_one_move_and_corners_slow_down():
    straight = ["G21", "G90", "G92 X0 Y0 Z0"] + [f"G1 X{10 * k} F3000" for k in range(1, 11)]
    one = ["G21", "G90", "G92 X0 Y0 Z0", "G1 X100 F3000"]
    assert estimate(lines(straight), DIW).total_s == pytest.approx(
        estimate(lines(one), DIW).total_s
    )
    square = ["G90", "G92 X0 Y0 Z0", "G1 X50 F3000", "G1 Y50", "G1 X0", "G1 Y0"]
    corner = math.sqrt(500 * 0.013 * math.sin(math.pi / 4) / (1 - math.sin(math.pi / 4)))
    expected = (
        trapezoid_time(50, 0, corner, 50, 500)
        + 2 * trapezoid_time(50, corner, corner, 50, 500)
        + trapezoid_time(50, corner, 0, 50, 500)
    )
    assert estimate(lines(square), DIW).total_s == pytest.approx(expected)


def test_dwells_count_waits_are_listed_and_axis_limits_cap_the_feed():
    job = lines(["G28", "G92 X0 Y0 Z0", "G4 P500", "M400", "G1 Z5 F6000"])
    result = estimate(job, DIW)
    z_only = trapezoid_time(5, 0, 0, DIW.limits.z_mm_s, DIW.limits.z_acceleration_mm_s2)
    assert result.total_s == pytest.approx(0.5 + z_only)  # Z is capped at 10 mm/s
    assert result.waits == ("G28",)
    assert result.remaining_s(3) == pytest.approx(z_only)
    assert "not counted: 1 waits for G28" in result.summary()


def test_grbl_rapids_run_at_the_travel_speed():
    grbl = load_machine("grbl_diw")
    kinematics = Kinematics.of(grbl)
    assert kinematics.rapid_mm_s == grbl.limits.travel_mm_s
    job = lines(["G90", "G92 X0 Y0 Z0", "G0 X100", "F600", "X0"])  # X0: modal G0
    expected = 2 * trapezoid_time(100, 0, 0, 60, 250)  # a reversal stops (0.05 mm/s)
    assert estimate(job, grbl).total_s == pytest.approx(expected, rel=1e-3)


def test_grbl_inverse_time_g93_takes_60_over_f_seconds_and_g94_is_mm_per_min_again():
    grbl = load_machine("grbl_diw")
    accel = grbl.limits.acceleration_mm_s2
    # after homing, G93 then F0.001 (1/min): 200 mm in 1/0.001 min = 1000 min, plus the
    # ramps (the move's speed is 200 mm * 0.001 / 60 s); before G93 was known: 0 s ($H
    # unknown) or 12,000,000 s (F read as mm/min)
    slow = estimate(lines(["$H", "G21", "G90", "G93", "G1 X200 F0.001"]), grbl)
    assert slow.total_s == pytest.approx(trapezoid_time(200, 0, 0, 200 * 0.001 / 60, accel))
    assert slow.total_s == pytest.approx(1000 * 60, rel=1e-6)
    assert slow.waits == ("$H",) and slow.positions[-1][:3] == (200.0, 0.0, 0.0)
    # a G94 feed does not reach into G93 (there F30 is 1/min: 90 mm in 2 s, 45 mm/s), and
    # back in G94 F600 is 10 mm/s again
    job = ["G21", "G90", "G92 X0 Y0 Z0", "G1 X10 F600", "G93", "G1 X100 F30", "G94"]
    job += ["G1 X0 F600"]
    expected = (
        trapezoid_time(10, 0, 10, 10, accel)  # straight on at 10 mm/s
        + trapezoid_time(90, 10, 0.05, 90 * 30 / 60, accel)  # then a reversal
        + trapezoid_time(100, 0.05, 0, 10, accel)
    )
    assert estimate(lines(job), grbl).total_s == pytest.approx(expected)
    # an arc: 60/F s over its length (a half circle of radius 10 mm, F6: 10 s), the same
    # arc as in G94 at its length times F mm/min
    arc = ["G21", "G90", "G92 X0 Y0 Z0", "G17", "G93", "G2 X20 Y0 I10 J0 F6"]
    inverse = estimate(lines(arc), grbl).total_s
    feed = estimate(lines(arc[:4] + [f"G2 X20 Y0 I10 J0 F{10 * math.pi * 6:.5f}"]), grbl)
    assert inverse == pytest.approx(feed.total_s) and inverse == pytest.approx(10.0, abs=0.02)
    # Marlin has no G93: F stays mm/min
    marlin = estimate(lines(["G90", "G92 X0 Y0 Z0", "G93", "G1 X100 F600"]), DIW)
    assert marlin.total_s == pytest.approx(trapezoid_time(100, 0, 0, 10, 500))


def test_the_estimate_is_the_emulators_clock_on_a_dispensing_job():
    # the emulator plans as it receives, 16 blocks ahead; the estimate sees the whole
    # file: when the host keeps the planner full they agree (benchmarks/link_throughput.py
    # does the same on Fig. 1's G-code)
    job = diw_job(1500)
    planned = estimate(job, DIW).total_s
    assert planned == pytest.approx(emulator_clock(job, DIW), rel=0.02)


def test_where_the_machine_stopped_places_it_in_the_file():
    job = lines(["G90", "G92 X0 Y0 Z0", "G1 X10 F600", "G1 Y10", "G1 X0", "G1 Y0"])
    plan = estimate(job, DIW)
    assert plan.stopped_in((10.0, 4.0, 0.0), last=5, window=8) == 3  # inside G1 Y10
    assert plan.stopped_in((10.0, 10.0, 0.0), last=5, window=8) == 4  # at its end
    assert plan.stopped_in((3.0, 3.0, 0.0), last=5, window=8) is None  # on no move


def test_the_eta_is_the_slower_of_the_machine_and_the_host():
    plan = estimate(diw_job(200), DIW)
    eta_s = send_eta(plan, 206)
    assert eta_s(0, 0.0) == pytest.approx(plan.total_s)
    assert eta_s(103, 1.0) == pytest.approx(plan.remaining_s(103))
    quick = send_eta(plan, 206, time_scale=0.0)  # sim://...?time_scale=0
    assert quick(0, 0.0) == 0.0 and quick(103, 1.0) == pytest.approx(1.0)


def lines(texts: list[str]) -> list[Command]:
    return commands_from_lines(texts)


def diw_job(n: int, seed: int = 1) -> list[Command]:
    """Print lines of short segments with varying feeds, travels with Z lifts between."""
    rng = random.Random(seed)
    out = ["G21", "G90", "M42 P4 S0", "G28", "G1 Z1 F600"]
    x, y = 100.0, 100.0
    while len(out) < n:
        out += ["G0 Z1.3 F600", f"G0 X{x:.3f} Y{y:.3f} F1800", "G0 Z0.3 F600", "M42 P4 S255"]
        heading = rng.uniform(0, 2 * math.pi)
        for _ in range(rng.randint(20, 60)):
            heading += rng.gauss(0, 0.15)
            x = min(180, max(20, x + 0.3 * math.cos(heading)))
            y = min(180, max(20, y + 0.3 * math.sin(heading)))
            out.append(f"G1 X{x:.3f} Y{y:.3f} F{rng.uniform(300, 900):.1f}")
        out.append("M42 P4 S0")
    return lines(out)


def emulator_clock(job: list[Command], machine) -> float:
    """The emulator's own clock (s) from the first move to the last, fed by a host that
    answers at once (virtual time: the planner never starves for the host's sake)."""
    limits = machine.limits
    url = (
        f"sim://marlin?time_scale=1&baud=0&accel={limits.acceleration_mm_s2:g}"
        f"&z_accel={limits.z_acceleration_mm_s2:g}&e_accel={limits.e_acceleration_mm_s2:g}"
        f"&jd={limits.junction_deviation_mm:g}"
    )
    emulator = Emulator(config_from_url(url, 115200), now=0.0)
    t = 0.0
    emulator.poll(t)
    for command in job:
        emulator.host_write(command.text.encode() + b"\n", t)
        while b"ok" not in emulator.poll(t):
            t = emulator.next_time()
    end = emulator.firmware.motion.idle_time(t)
    first = next(e.t_s for e in emulator.trace if e.command.startswith(("G0", "G1")))
    return end - first
