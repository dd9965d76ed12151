"""Machine profiles: every shipped profile loads; every kind of mistake is one clear line."""

from __future__ import annotations

from pathlib import Path

import pytest

from fabkit.calibration import CALIBRATION_PARAMETERS
from fabkit.cli import main
from fabkit.errors import FabkitError
from fabkit.machines import (
    FLAVOURS,
    KINDS,
    MACHINES_DIR,
    list_machines,
    load_machine,
)

SHIPPED = [
    "marlin_generic",
    "marlin_diw_pneumatic",
    "grbl_diw",
    "klipper_generic",
    "hyrel_pulse",
    "dmd_photoalign",
    "scan_photoalign",
    "laser_cutter",
]
BASE = (MACHINES_DIR / "marlin_generic.toml").read_text()


def _edited(tmp_path: Path, old: str, new: str, text: str = BASE) -> Path:
    """A copy of a shipped profile with one edit."""
    assert old in text
    path = tmp_path / "edited.toml"
    path.write_text(text.replace(old, new, 1))
    return path


def _error(path: Path) -> str:
    with pytest.raises(FabkitError) as caught:
        load_machine(path)
    message = str(caught.value)
    assert "\n" not in message and "edited.toml" in message
    return message


def test_every_shipped_profile_loads_with_consistent_fields():
    profiles = {p.name: p for p in list_machines()}
    assert set(SHIPPED) <= set(profiles)
    assert list(profiles) == sorted(profiles)
    for name, p in profiles.items():
        assert p.path.stem == name
        assert p.kind in KINDS and p.flavour in FLAVOURS
        assert (p.serial is None) == (p.gcode is None) == (p.flavour == "none")
        for axis in "xyz":
            lo, hi = p.envelope.axis(axis)
            assert lo < hi
        for channel in p.process.encodes:
            assert set(channel.parameters) <= set(CALIBRATION_PARAMETERS)
        assert p.process.source == f"machine {name}"
        if p.gcode is not None:
            assert p.render("safe_stop_gcode"), name
            assert all("{" not in line for line in p.render("start_gcode"))


def test_kinds_cover_all_four_machine_types():
    assert {p.kind for p in list_machines()} == set(KINDS)


def test_name_or_path_load_the_same_profile():
    by_name = load_machine("grbl_diw")
    by_path = load_machine(MACHINES_DIR / "grbl_diw.toml")
    assert by_name == by_path
    assert by_name.serial.protocol == "grbl" and by_name.serial.rx_buffer_bytes == 128


def test_render_fills_placeholders_in_gcode_units():
    machine = load_machine("marlin_generic")
    start = machine.render("start_gcode")
    assert "M109 S210" in start and "G1 Z0.4 F300" in start  # z_mm_s 5 -> F300 mm/min
    assert machine.placeholders()["travel_feed_mm_min"] == "7200"


def test_optional_keys_have_documented_defaults_and_are_read_when_given(tmp_path):
    plain = load_machine(_edited(tmp_path, 'e_units = "filament"\n', ""))
    assert plain.tool.e_mode is None and plain.tool.e_units is None
    assert plain.tool.filament_diameter_mm == 1.75 and plain.tool.pulses_per_mm3 is None
    assert plain.laser is None and plain.process.encodes[0].table.clip is False
    assert plain.pressure is None and plain.inks is None
    assert plain.gcode.ink2_on_gcode == "" and plain.gcode.ink2_off_gcode == ""
    edits = 'e_units = "pulses"\npulses_per_mm3 = 90\ne_mode = "relative"\n'
    tuned = load_machine(_edited(tmp_path, 'e_units = "filament"\n', edits))
    assert (tuned.tool.e_units, tuned.tool.pulses_per_mm3, tuned.tool.e_mode) == (
        "pulses",
        90.0,
        "relative",
    )
    clipped = load_machine(
        _edited(tmp_path, "value = [25, 15, 8, 4]", "value = [25, 15, 8, 4]\nclip = true")
    )
    assert clipped.process.encodes[0].table.clip is True


def test_laser_writer_reads_its_light_table():
    laser = load_machine("dmd_photoalign")
    assert laser.laser.relation == "perpendicular" and laser.laser.pixel_pitch_mm == 0.01
    assert laser.laser.intensity_mw_cm2 == 10 and laser.laser.max_power_mw is None
    assert [c.parameters for c in laser.process.encodes] == [
        ("dose_mj_cm2",),
        ("cure_dose_mj_cm2",),
    ]
    assert laser.laser.dose_levels == 24 and laser.laser.bins == 90


def test_the_default_diw_profile_encodes_two_features_with_two_inks_and_a_pressure():
    diw = load_machine("marlin_diw_pneumatic")
    assert [(c.features, c.parameters) for c in diw.process.encodes] == [
        ((0,), ("print_speed_mm_s",)),
        ((1,), ("ink_fraction",)),
    ]
    assert diw.inks.method == "alternate" and diw.inks.piece_mm == 0.5
    assert diw.render("ink2_on_gcode") == ["M42 P5 S255"]
    assert "M42 P5 S0" in diw.render("safe_stop_gcode")
    assert diw.pressure.command == "M106 P1" and diw.pressure.s_value(350.0) == 128.0
    assert diw.pressure.kpa(255) == pytest.approx(700.0)


DIW = (MACHINES_DIR / "marlin_diw_pneumatic.toml").read_text()


@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        ("feature = 1\n", 'feature = "1 2"\n', None),
        ("feature = 1\n", "feature = -1\n", "feature: expected a feature name or its position"),
        ("feature = 1\n", "feature = true\n", "feature: expected a feature name or its position"),
        (
            'method = "alternate"',
            'method = "blend"',
            "inks.method: expected one of alternate, mixing, got 'blend'",
        ),
        ('method = "alternate"', 'method = "mixing"', "mixing needs a Marlin-like mixing"),
        (
            'ink2_on_gcode = "M42 P5 S255"\n',
            "",
            "gcode.ink2_on_gcode: expected G-code switching to ink 2",
        ),
        (
            "piece_mm = 0.5",
            "piece_mm = 0",
            "inks.piece_mm: expected a positive number at most 1e+06, got 0",
        ),
        (
            "max_kpa = 600",
            "max_kpa = 800",
            "pressure.max_kpa: expected at most full_scale_kpa = 700, got 800",
        ),
        (
            'command = "M106 P1"',
            'command = ""',
            "pressure.command: expected one G-code command, got ''",
        ),
        ("s_max = 255", "s_max = 2.5", "pressure.s_max: expected a positive integer, got 2.5"),
        ("[[process.encode]]              # the design's second", "[[process.joint]]  #", None),
        (
            'parameter = "ink_fraction"',
            'parameter = "dose_mj_cm2"',
            "encode[1].parameter: expected one of print_speed_mm_s",
        ),
        (
            "value = [0.0, 0.3, 0.65, 1.0]",
            "value = [0, 0.3, 0.6, 1.2]",
            "in [0, 1]",
        ),
    ],
)
def test_channel_inks_and_pressure_mistakes(tmp_path, old, new, expected):
    path = _edited(tmp_path, old, new, DIW)
    if expected is None:  # a string feature name is fine; a joint table needs its keys
        if "joint" in new:
            assert "process.joint[0].features: missing (expected" in _error(path)
        else:
            assert load_machine(path).process.encodes[1].features == ("1 2",)
        return
    assert expected in _error(path)


def test_unknown_machine_names_the_known_ones():
    with pytest.raises(FabkitError, match=r"unknown machine 'nope'; known machines: .*grbl_diw"):
        load_machine("nope")
    with pytest.raises(FabkitError, match="does not exist"):
        load_machine("missing/profile.toml")


@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        (
            'flavour = "marlin"',
            'flavour = "marlin"\ncolour = "red"',
            "colour: unknown key (allowed: description, envelope",
        ),
        ("x_mm_s = 300", "x_mm_s = 300\nw_mm_s = 3", "limits.w_mm_s: unknown key (allowed: "),
        ("y_mm_s = 300\n", "", "limits.y_mm_s: missing (expected a positive number"),
        ('name = "marlin_generic"\n', "", "name: missing (expected a string)"),
        (
            "x_mm_s = 300",
            'x_mm_s = "fast"',
            "limits.x_mm_s: expected a positive number at most 1e+06, got 'fast' (a string)",
        ),
        (
            "x_mm_s = 300",
            "x_mm_s = true",
            "limits.x_mm_s: expected a positive number at most 1e+06, got true (a boolean)",
        ),
        (
            "z_mm_s = 5",
            "z_mm_s = -5",
            "limits.z_mm_s: expected a positive number at most 1e+06, got -5",
        ),
        (
            "retract_mm = 1.0",
            "retract_mm = -1.0",
            "tool.retract_mm: expected a number >= 0 at most 1e+06, got -1.0",
        ),
        (
            "baud = 115200",
            "baud = 115200.5",
            "serial.baud: expected a positive integer, got 115200.5",
        ),
        (
            'protocol = "marlin"',
            'protocol = "smoothie"',
            "serial.protocol: expected one of marlin, grbl, got 'smoothie'",
        ),
        (
            'kind = "extrusion_printer"',
            'kind = "printer"',
            "kind: expected one of extrusion_printer, pneumatic_diw",
        ),
        (
            "x_mm = [0, 220]",
            "x_mm = [220, 0]",
            "envelope.x_mm: expected [min, max] with min < max, got [220",
        ),
        ("x_mm = [0, 220]", "x_mm = [0, 220, 5]", "envelope.x_mm: expected an array of 2 numbers"),
        (
            "nozzle_c = 210",
            "nozzle_c = 300",
            "temperature.nozzle_c: expected at most nozzle_max_c = 260, got 300",
        ),
        ("value = [25, 15, 8, 4]", "value = [25, 15, 8]", "same length"),
        ("eps = [-0.40, -0.30, -0.20, -0.10]", "eps = [-0.4, -0.2, -0.3, -0.1]", "increasing"),
        ('parameter = "print_speed_mm_s"', 'parameter = "colour"', "parameter: expected one of"),
        ("M109 S{nozzle_c}", "M109 S{hot}", "gcode.start_gcode: expected placeholders among"),
        (
            "rx_buffer_bytes = 128",
            "rx_buffer_bytes = 8",
            "serial.rx_buffer_bytes: expected an integer >= 32, got 8",
        ),
        ("[envelope]", "envelope = 3\n[envelopes]", "envelope: expected a table, got 3"),
        (
            'e_units = "filament"',
            'e_units = "grams"',
            "tool.e_units: expected one of filament, volume, pulses, got 'grams'",
        ),
        (
            'e_units = "filament"',
            'e_mode = "both"',
            "tool.e_mode: expected one of absolute, relative, got 'both'",
        ),
        (
            "filament_diameter_mm = 1.75",
            "filament_diameter_mm = 0",
            "tool.filament_diameter_mm: expected a positive number at most 1e+06, got 0",
        ),
        (
            "value = [25, 15, 8, 4]",
            "value = [25, 15, 8, 4]\nclip = 1",
            "process.encode[0].clip: expected true or false, got 1",
        ),
        ("value = [25, 15, 8, 4]", "value = [25, 15, 15, 4]", "strictly increasing or decr"),
        (
            'parameter = "print_speed_mm_s"',
            'parameter = "dose_mj_cm2"',
            "parameter: expected one of",
        ),
        (
            "[serial]",
            "[laser]\nrelation = 'parallel'\n\n[serial]",
            "laser: expected no table for kind extrusion_printer",
        ),
    ],
)
def test_mistakes_are_one_line_naming_file_and_key(tmp_path, old, new, expected):
    assert expected in _error(_edited(tmp_path, old, new))


def test_bad_toml_is_one_line(tmp_path):
    assert "not valid TOML" in _error(_edited(tmp_path, "[envelope]", "[envelope"))


@pytest.mark.parametrize(
    ("old", "new", "expected"),
    [
        (
            'relation = "perpendicular"',
            'relation = "sideways"',
            "laser.relation: expected one of perpendicular, parallel, got 'sideways'",
        ),
        (
            "input_polarisation_deg = 0",
            "input_polarisation_deg = 180",
            "laser.input_polarisation_deg: expected an angle in [0, 180), got 180",
        ),
        (
            "intensity_mw_cm2 = 10",
            "intensity_mw_cm2 = 0",
            "laser.intensity_mw_cm2: expected a positive number at most 1e+06, got 0",
        ),
        ("intensity_mw_cm2 = 10", "power = 3", "laser.power: unknown key (allowed: bins"),
    ],
)
def test_laser_table_mistakes(tmp_path, old, new, expected):
    text = (MACHINES_DIR / "dmd_photoalign.toml").read_text()
    assert expected in _error(_edited(tmp_path, old, new, text))


def test_flavour_none_must_not_carry_serial_or_gcode(tmp_path):
    text = (MACHINES_DIR / "dmd_photoalign.toml").read_text()
    path = _edited(tmp_path, "[process]", "[serial]\nbaud = 9600\n\n[process]", text)
    assert "serial: expected no table for flavour none" in _error(path)
    with pytest.raises(FabkitError, match="takes no G-code"):
        load_machine("dmd_photoalign").render("start_gcode")


def test_fabkit_machines_lists_name_kind_flavour_envelope_protocol(capsys):
    assert main(["machines"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].split() == ["NAME", "KIND", "FLAVOUR", "ENVELOPE", "PROTOCOL"]
    rows = {line.split()[0]: line.split() for line in out[1:]}
    assert rows["grbl_diw"] == ["grbl_diw", "pneumatic_diw", "grbl", "300x300x80", "mm", "grbl"]
    assert rows["dmd_photoalign"][-1] == "-"
