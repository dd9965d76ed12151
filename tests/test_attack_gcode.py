"""Attack rows for the pre-flight check: hostile G-code given to ``fabkit send``.

Every row is a job that would move a machine outside its envelope or above its limits,
heat it above its maximum, or do something the check cannot follow, if the check read it
differently from the firmware or let the command through. Each must be refused before
the port is opened (exit 2, one line naming the file line and the command).
"""

from __future__ import annotations

import pytest

from tests.attack import assert_refused, case, write_texts

pytestmark = pytest.mark.filterwarnings("error")  # a warning would be a second line on stderr

GRBL_SIM = "sim://grbl?baud=0&time_scale=0"
MARLIN_SIM = "sim://marlin?baud=0&time_scale=0"
GRBL = ["G21", "G90", "G94", "G17"]
MARLIN = ["G21", "G90", "G28", "M82", "G92 E0"]

JOBS = {
    # GRBL: blanks inside words are dropped before parsing
    "grbl_space_x": [*GRBL, "G0 X4 00"],
    "grbl_space_f": [*GRBL, "G1 X10 F6 000"],
    "grbl_long_number": [*GRBL, "G0 X000000000100"],
    "grbl_repeated": [*GRBL, "G0 X10 X400"],
    "grbl_e_word": [*GRBL, "G1 X10 E5 F60"],
    # GRBL arcs, both forms, every plane
    "grbl_r_long": [*GRBL, "G0 X100 Y100", "G2 X120 Y110 R-500 F600"],
    "grbl_r_impossible": [*GRBL, "G0 X100 Y100", "G2 X200 Y100 R10 F600"],
    "grbl_ij_out": [*GRBL, "G0 X10 Y10", "G2 X10 Y10 I100 F600"],
    "grbl_zx_arc": [*GRBL, "G0 X100 Y100 Z40", "G18 G3 X100 Z40 K25 F600"],
    "grbl_off_circle": [*GRBL, "G0 X100 Y100", "G2 X110 Y100 I10 J3 F60"],
    # GRBL offsets
    "grbl_g10_l2": [*GRBL, "G0 X100", "G10 L2 P1 X200", "G0 X150"],
    "grbl_g10_l20": [*GRBL, "G0 X250", "G10 L20 P1 X0", "G0 X100"],
    "grbl_g55": [*GRBL, "G0 X100", "G55 G0 X10"],
    "grbl_g92": [*GRBL, "G0 X250", "G92 X0", "G0 X100"],
    "grbl_g92_1": [*GRBL, "G0 X10", "G92.1 X400"],
    "grbl_g43_1": [*GRBL, "G0 Z5", "G43.1 Z100", "G0 Z0"],
    "grbl_g53": [*GRBL, "G53 G0 X400"],
    # GRBL homing with axis words, stored positions, probes, inverse time
    "grbl_g28_axis": [*GRBL, "G0 X10 Y10 Z10", "G28.1", "G28 X400"],
    "grbl_g30_axis": [*GRBL, "G0 X10 Y10 Z10", "G30.1", "G30 Z500"],
    "grbl_g28_stored": [*GRBL, "G0 X10 Y10 Z10", "G28"],
    "grbl_probe": [*GRBL, "G0 Z5", "G38.2 Z-10 F100"],
    "grbl_probe_zero": [*GRBL, "G0 X100 Y100 Z5", "G38.2 Z0 F100", "G92 Z0", "G0 Z78"],
    "grbl_g93": [*GRBL, "G0 X10", "G93 G1 X100 F60"],
    "grbl_g93_no_f": [*GRBL, "G0 X10", "G93 G1 X100"],
    # GRBL system commands and modes a job must set
    "grbl_jog": [*GRBL, "$J=G91X500F100"],
    "grbl_startup_block": [*GRBL, "$N0=G0X400"],
    "grbl_modal_unknown": [*GRBL, "X10"],
    "grbl_no_g90": ["G21", "G94", "G0 X10"],
    "grbl_relative_unknown": [*GRBL, "G91 G0 X10"],
    "grbl_flow_inline": [*GRBL, "G0 X10", "G1 X50 F2400 M8"],
    "grbl_program_end": [*GRBL, "G1 X10 F600", "M2", "X400"],
    "scan_power": [*GRBL, "G0 X10 Y10 A20", "M3 S50", "G1 X20 F300"],
    # Marlin and the Marlin-like firmwares
    "marlin_space_x": [*MARLIN, "G1 X4 00 F600"],
    "marlin_r_long": [*MARLIN, "G1 X100 Y100 F600", "G2 X120 Y110 R-500"],
    "marlin_r_impossible": [*MARLIN, "G1 X100 Y100 F600", "G2 X200 Y100 R10"],
    "marlin_turns": [*MARLIN, "G1 X100 Y100 F600", "G2 I100 J0 P1"],
    "marlin_m220": [*MARLIN, "M220 S500", "G1 X100 F3000"],
    "marlin_m221": [*MARLIN, "G1 X10 F600", "M221 S500", "G1 X20 E20"],
    "marlin_m42_i": [*MARLIN, "M42 P13 S255 I"],
    "diw_m42_pin": ["G21", "G90", "G28", "M42 P6 S255"],
    "marlin_g92_unknown": ["G21", "G90", "G92 X0", "G1 X200 F600"],
    "marlin_lowercase": [*MARLIN, "g1 x500 f600"],
    "marlin_repeated": [*MARLIN, "G1 X10 X500 F600"],
    "marlin_brace": [*MARLIN, "G1 X{500} F600"],
    "marlin_tool": [*MARLIN, "T1"],
    "marlin_m110": [*MARLIN, "M110 N100"],
    "marlin_g28_raise": [*MARLIN, "G28 R50"],
    "marlin_negative_temp": [*MARLIN, "M104 S-65236"],
    "marlin_autotemp": [*MARLIN, "M104 S200 B400"],
    "marlin_z_unknown": ["G90", "G1 Z10 F6000"],
    "marlin_no_feed": [*MARLIN, "G1 X10"],
    "marlin_motors_off": [*MARLIN, "G1 X10 F600", "M84", "G91", "G1 X10"],
    "marlin_absolute_e": ["G21", "G90", "G28", "G1 X10 E5 F600"],
    "klipper_force_move": ["G21", "G90", "G28", "FORCE_MOVE STEPPER=stepper_x DISTANCE=500"],
    "klipper_kinematic": ["SET_KINEMATIC_POSITION X=0", "G90", "G1 X-100 F600"],
    "klipper_macro": ["PRINT_START"],
    "klipper_r_arc": ["G21", "G90", "G28", "G1 X100 Y100 F600", "G2 X120 Y100 R10"],
    "klipper_heater": ["SET_HEATER_TEMPERATURE HEATER=extruder TARGET=400"],
    "hyrel_prime": ["G21", "G90", "G28", "M721 S100"],
    "hyrel_g0_feed": ["G21", "G90", "G28", "G1 F99999", "G0 X10 F600", "G1 X20"],
}


def send(job: str, machine: str, port: str | None) -> str:
    where = f"--port {port}" if port else "--dry-run"
    return f"send {{{job}}} {where} --machine {machine}"


def grbl(job: str) -> str:
    return send(job, "grbl_diw", GRBL_SIM)


def marlin(job: str, machine: str = "marlin_generic") -> str:
    return send(job, machine, MARLIN_SIM)


CASES = [
    # ------------------------------------------------------------------ GRBL reading
    case(grbl("grbl_space_x"), "outside the envelope", "X=400.000", ":5:", id="gcode-grbl-space-x"),
    case(grbl("grbl_space_f"), "exceeds [limits]", "feed 100.000", ":5:", id="gcode-grbl-space-f"),
    case(grbl("grbl_long_number"), "more than 8 digits", ":5:", id="gcode-grbl-long-number"),
    case(grbl("grbl_repeated"), "GRBL rejects", "X given twice", id="gcode-grbl-repeated-word"),
    case(grbl("grbl_e_word"), "GRBL rejects", "no E word", id="gcode-grbl-e-word"),
    # ------------------------------------------------------------------ GRBL arcs
    case(grbl("grbl_r_long"), "outside the envelope", "X=386.449", ":6:", id="gcode-grbl-r-arc"),
    case(
        grbl("grbl_r_impossible"),
        "is shorter than half the distance",
        "R10",
        ":6:",
        id="gcode-grbl-r-arc-impossible",
    ),
    case(grbl("grbl_ij_out"), "outside the envelope", "Y=-90.000", id="gcode-grbl-ij-arc"),
    case(grbl("grbl_zx_arc"), "outside the envelope", "Z=90.000", id="gcode-grbl-g18-arc"),
    case(grbl("grbl_off_circle"), "off its circle", ":6:", id="gcode-grbl-arc-off-circle"),
    # ------------------------------------------------------------------ GRBL offsets
    case(grbl("grbl_g10_l2"), "outside the envelope", "X=350.000", ":7:", id="gcode-grbl-g10-l2"),
    case(grbl("grbl_g10_l20"), "outside the envelope", "X=350.000", id="gcode-grbl-g10-l20"),
    case(grbl("grbl_g55"), "cannot be checked", "G55 G0 X10", "G55 offset", id="gcode-grbl-g55"),
    case(grbl("grbl_g92"), "outside the envelope", "X=350.000", ":7:", id="gcode-grbl-g92"),
    case(grbl("grbl_g92_1"), "outside the envelope", "X=400.000", ":6:", id="gcode-grbl-g92-1"),
    case(grbl("grbl_g43_1"), "outside the envelope", "Z=100.000", ":7:", id="gcode-grbl-g43-1"),
    case(grbl("grbl_g53"), "outside the envelope", "X=400.000", id="gcode-grbl-g53"),
    # ------------------------------------------------------------------ GRBL homing, probes
    case(grbl("grbl_g28_axis"), "outside the envelope", "X=400.000", ":7:", id="gcode-grbl-g28"),
    case(grbl("grbl_g30_axis"), "outside the envelope", "Z=500.000", ":7:", id="gcode-grbl-g30"),
    case(
        grbl("grbl_g28_stored"),
        "cannot be checked",
        "G28 cannot be checked",
        "G28.1",
        id="gcode-grbl-g28-stored",
    ),
    case(grbl("grbl_probe"), "outside the envelope", "Z=-10.000", id="gcode-grbl-g38-probe"),
    case(grbl("grbl_probe_zero"), "outside the envelope", "Z=83.000", id="gcode-grbl-probe-g92"),
    case(grbl("grbl_g93"), "exceeds [limits]", "feed 90.000", ":6:", id="gcode-grbl-g93"),
    case(grbl("grbl_g93_no_f"), "GRBL rejects", "error:22", id="gcode-grbl-g93-no-f"),
    # ------------------------------------------------------------------ GRBL modes, system
    case(grbl("grbl_jog"), "unknown command", "$J", id="gcode-grbl-jog"),
    case(grbl("grbl_startup_block"), "unknown command", "$N0", id="gcode-grbl-startup-block"),
    case(grbl("grbl_modal_unknown"), "cannot be checked", "motion mode", id="gcode-grbl-modal"),
    case(grbl("grbl_no_g90"), "cannot be checked", "distance mode", id="gcode-grbl-no-g90"),
    case(
        grbl("grbl_relative_unknown"),
        "cannot be checked",
        "X position is unknown",
        id="gcode-grbl-relative-unknown",
    ),
    case(grbl("grbl_flow_inline"), "exceeds [limits]", "print_mm_s", id="gcode-grbl-flow-inline"),
    case(grbl("grbl_program_end"), "outside the envelope", "X=400.000", id="gcode-grbl-m2-g1"),
    case(
        send("scan_power", "scan_photoalign", None),
        "exceeds [laser] max_power_mw",
        "S50",
        id="gcode-scan-laser-power",
    ),
    # ------------------------------------------------------------------ Marlin-like reading
    case(marlin("marlin_space_x"), "stray number", "'00'", ":6:", id="gcode-marlin-space-x"),
    case(marlin("marlin_lowercase"), "lower-case", "'g'", id="gcode-marlin-lowercase"),
    case(marlin("marlin_repeated"), "given twice", "X", id="gcode-marlin-repeated"),
    case(marlin("marlin_brace"), "unexpected character", "'{'", id="gcode-marlin-expression"),
    # ------------------------------------------------------------------ Marlin arcs
    case(marlin("marlin_r_long"), "outside the envelope", "X=386.449", id="gcode-marlin-r-arc"),
    case(
        marlin("marlin_r_impossible"),
        "is shorter than half the distance",
        ":7:",
        id="gcode-marlin-r-arc-impossible",
    ),
    case(marlin("marlin_turns"), "outside the envelope", "X=300.000", id="gcode-marlin-arc-p"),
    # ------------------------------------------------------------------ Marlin overrides
    case(marlin("marlin_m220"), "exceeds [limits]", "feed 250.000", ":7:", id="gcode-marlin-m220"),
    case(marlin("marlin_m221"), "exceeds [limits]", "E speed 100.000", id="gcode-marlin-m221"),
    # ------------------------------------------------------------------ Marlin commands
    case(marlin("marlin_m42_i"), "cannot be checked", "M42 P13 S255 I", id="gcode-marlin-m42-i"),
    case(
        marlin("diw_m42_pin", "marlin_diw_pneumatic"),
        "cannot be checked",
        "M42 P6 S255",
        "M42 P4 S0",
        id="gcode-diw-m42-pin",
    ),
    case(
        marlin("marlin_g92_unknown"),
        "cannot be checked",
        "G92 X0",
        "X position is unknown",
        id="gcode-marlin-g92-unknown",
    ),
    case(marlin("marlin_tool"), "cannot be checked", "T1", id="gcode-marlin-tool-change"),
    case(marlin("marlin_m110"), "cannot be checked", "M110 N100", id="gcode-marlin-m110"),
    case(marlin("marlin_g28_raise"), "cannot be checked", "R in G28", id="gcode-marlin-g28-r"),
    case(
        marlin("marlin_negative_temp"), "negative temperature", "M104", id="gcode-marlin-temp-wrap"
    ),
    case(marlin("marlin_autotemp"), "exceeds [temperature]", "B400", id="gcode-marlin-autotemp"),
    case(marlin("marlin_z_unknown"), "exceeds [limits]", "Z speed", id="gcode-marlin-z-unknown"),
    case(marlin("marlin_no_feed"), "before any feed rate (F) was set", id="gcode-marlin-no-feed"),
    case(marlin("marlin_motors_off"), "cannot be checked", "M84", id="gcode-marlin-motors-off"),
    case(
        marlin("marlin_absolute_e"),
        "cannot be checked",
        "unknown E position",
        id="gcode-marlin-absolute-e",
    ),
    # ------------------------------------------------------------------ Klipper, Hyrel
    case(
        marlin("klipper_force_move", "klipper_generic"),
        "cannot be checked",
        "FORCE_MOVE",
        id="gcode-klipper-force-move",
    ),
    case(
        marlin("klipper_kinematic", "klipper_generic"),
        "cannot be checked",
        "SET_KINEMATIC_POSITION",
        ":1:",
        id="gcode-klipper-set-position",
    ),
    case(
        marlin("klipper_macro", "klipper_generic"),
        "cannot be checked",
        "PRINT_START",
        id="gcode-klipper-macro",
    ),
    case(
        marlin("klipper_r_arc", "klipper_generic"),
        "Klipper refuses R arcs",
        ":5:",
        id="gcode-klipper-r-arc",
    ),
    case(
        send("klipper_heater", "klipper_generic", None),
        "exceeds [temperature]",
        "TARGET=400",
        id="gcode-klipper-heater",
    ),
    case(marlin("hyrel_prime", "hyrel_pulse"), "cannot be checked", "M721", id="gcode-hyrel-prime"),
    case(
        marlin("hyrel_g0_feed", "hyrel_pulse"),
        "exceeds [limits]",
        "feed 1666.650",
        ":6:",
        id="gcode-hyrel-g0-feed",
    ),
    # ------------------------------------------------------------------ the file itself
    case(marlin("huge"), "is larger than the limit", "64 MiB", id="gcode-file-too-large"),
    case(marlin("wide"), "line longer than", "4096", ":2:", id="gcode-line-too-long"),
    case(marlin("folder"), "not a regular file", id="gcode-not-a-file"),
]


@pytest.fixture(scope="module")
def jobs(folder) -> dict[str, str]:
    """Every job of :data:`JOBS` as a file, a sparse file over the size limit, a file with
    a line over the length limit and a folder."""
    texts = {name: "\n".join(lines) + "\n" for name, lines in JOBS.items()}
    places = write_texts(folder, texts, ".gcode")
    with (folder / "huge.gcode").open("wb") as handle:
        handle.truncate(64 * 2**20 + 1)
    (folder / "wide.gcode").write_text("G21\nG1 X1 F60 ;" + "x" * 5000 + "\n")
    (folder / "folder.gcode").mkdir()
    return {
        **places,
        **{name: str(folder / f"{name}.gcode") for name in ("huge", "wide", "folder")},
    }


@pytest.mark.parametrize("bad", CASES)
def test_hostile_gcode_is_refused_before_the_port_opens(bad, jobs, run_cli, tmp_path):
    assert_refused(bad, jobs, tmp_path, run_cli)
