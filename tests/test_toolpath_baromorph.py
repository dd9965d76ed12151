"""Baromorph channels and their mould: valid polygons, walls, widths, connectivity, STL."""

from __future__ import annotations

from pathlib import Path

import pytest
import trimesh

from fabkit.errors import FabkitError
from fabkit.field.flat import field_from_expression
from fabkit.field.outlines import parse_shape
from fabkit.toolpath.baromorph import check_channels, layout_channels, load_baromorph
from fabkit.toolpath.mould import mould_mesh, save_mould

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "directors" / "baromorph.toml"


@pytest.mark.slow
@pytest.mark.parametrize("theta", ["phi + pi/2", "phi/2"], ids=["azimuthal loops", "+1/2 defect"])
def test_channels_meet_the_specification(tmp_path, theta):
    settings = load_baromorph(EXAMPLE)
    field = field_from_expression(theta, parse_shape("disc:30"), eps="0.5 + 0.5*x/30")
    layout = layout_channels(field, settings)
    report = check_channels(layout, settings)
    assert report.channels >= 5
    assert report.valid and report.connected
    assert report.min_wall_mm >= settings.min_wall_mm - 1e-6
    assert report.width_samples > 100 and report.max_width_error <= 0.01
    mesh = mould_mesh(layout, settings)
    assert mesh.is_watertight and mesh.is_volume
    save_mould(mesh, tmp_path / "mould.stl")
    back = trimesh.load(tmp_path / "mould.stl")
    assert back.is_watertight
    assert back.bounds[1][2] == pytest.approx(settings.plate_mm + settings.part_thickness_mm)


def test_a_pitch_too_small_for_the_walls_is_refused(tmp_path):
    text = EXAMPLE.read_text().replace("pitch_mm = 3.0", "pitch_mm = 2.5")
    (tmp_path / "b.toml").write_text(text)
    settings = load_baromorph(tmp_path / "b.toml")
    field = field_from_expression("0", parse_shape("disc:20"), eps="1.0")
    with pytest.raises(FabkitError, match="increase pitch_mm"):
        layout_channels(field, settings)


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        (
            "min_wall_mm = 0.6",
            "min_wall_mm = -1",
            r"b\.toml: baromorph\.min_wall_mm: expected a positive number .*, got -1",
        ),
        (
            "inlet = [0.0, -31.0]",
            "inlet = [0.0]",
            r"baromorph\.inlet: expected an array of 2 numbers, got \[0\.0\]",
        ),
        ("value = [0.8, 1.4, 2.2]", "value = [0.8, 1.4]", "same length"),
        (
            "part_thickness_mm = 2.5",
            "part_thickness_mm = 0.5",
            r"part_thickness_mm: expected more than channel_depth_mm = 1, got 0\.5",
        ),
    ],
)
def test_bad_baromorph_files(tmp_path, old, new, message):
    (tmp_path / "b.toml").write_text(EXAMPLE.read_text().replace(old, new))
    with pytest.raises(FabkitError, match=message):
        load_baromorph(tmp_path / "b.toml")
