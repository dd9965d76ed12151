"""Flat-sheet fields: from design files (along the grid), expressions, grids and TOML files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import shapely
from hypothesis import given
from hypothesis import strategies as st

from fabkit.errors import FabkitError
from fabkit.field.design_field import field_from_design
from fabkit.field.director_file import load_director_file
from fabkit.field.flat import (
    director_angle,
    field_from_expression,
    field_from_grid,
    planar_expression,
)
from fabkit.field.outlines import parse_shape
from fabkit.field.part import DEFAULT_SIZE_MM, SIZE_TOLERANCE

EXAMPLES = Path(__file__).resolve().parent.parent / "examples" / "directors"


def bent_map(u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A smooth injective map of the material plane to the flat sheet (design units)."""
    return u + 0.15 * v**2, v + 0.1 * u * v


def bent_director(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The unit vector along r_u of :func:`bent_map`, (..., 2)."""
    ru = np.stack([np.ones_like(u), 0.1 * v], axis=-1)
    return ru / np.linalg.norm(ru, axis=-1, keepdims=True)


def write_design(
    path: Path,
    mapping=bent_map,
    director=bent_director,
    eps=lambda u, v: 0.3 + 0.2 * u,
    half: int = 40,
    step: float = 0.05,
    reach: float = 1.8,
) -> Path:
    """A synthetic design.npz obeying the solver's contract: NaN outside the |u|+|v| domain."""
    u = step * np.arange(-half, half + 1)
    grid_u, grid_v = np.meshgrid(u, u, indexing="ij")
    valid = np.abs(grid_u) + np.abs(grid_v) <= reach
    x, y = mapping(grid_u, grid_v)
    r = np.stack([np.stack([x, y], axis=-1)] * 3)
    n = np.stack([director(grid_u, grid_v)] * 3)
    features = eps(grid_u, grid_v)[None].astype(float)
    r[:, ~valid] = n[:, ~valid] = np.nan
    features[:, ~valid] = np.nan
    scale = np.where(valid, 1.0, np.nan)
    np.savez_compressed(
        path,
        u=u,
        v=u.copy(),
        valid=valid,
        alpha=scale,
        beta=scale,
        eps=features,
        r=r,
        n=n,
        error=np.where(valid, 0.0, np.nan),
        stimuli=np.array([[0.0], [1.0], [2.0]]),
        spec=np.array(json.dumps({"synthetic": True, "material": {"features": ["eps"]}})),
    )
    return path


def test_design_field_follows_the_grid(tmp_path):
    path = write_design(tmp_path / "d.npz")
    field = field_from_design(path, mm_per_unit=2.0)
    rng = np.random.default_rng(1)
    u, v = rng.uniform(-0.7, 0.7, (2, 200))  # off the grid nodes, inside the domain
    points = 2.0 * np.column_stack(bent_map(u, v))
    director = bent_director(u, v)
    expected = np.arctan2(director[:, 1], director[:, 0])
    assert np.abs(field.theta(points) - expected).max() < 2e-3
    assert np.abs(field.eps(points) - (0.3 + 0.2 * u)).max() < 1e-4  # O(h^2)
    sized = field_from_design(path, size_mm=30.0)  # the size is the part's longest side
    assert 30.0 * (1 - SIZE_TOLERANCE) <= max(sized.part.extent()) <= 30.0
    assert sized.outline.difference(sized.part.outline_mm()).area == 0.0
    default = field_from_design(path)  # neither size nor scale: fabkit run's 60 mm
    assert DEFAULT_SIZE_MM * (1 - SIZE_TOLERANCE) <= max(default.part.extent()) <= DEFAULT_SIZE_MM


def test_design_solved_region_is_the_union_of_cell_images(tmp_path):
    """The part (the field's outline) is cut from the union of the solved cells' images."""
    field = field_from_design(write_design(tmp_path / "d.npz"), mm_per_unit=1.0)
    u = 0.05 * np.arange(-40, 41)
    grid_u, grid_v = np.meshgrid(u, u, indexing="ij")
    x, y = bent_map(grid_u, grid_v)
    valid = np.abs(grid_u) + np.abs(grid_v) <= 1.8
    cells = valid[:-1, :-1] & valid[1:, :-1] & valid[1:, 1:] & valid[:-1, 1:]
    i, j = np.nonzero(cells)
    quads = np.stack(
        [
            np.column_stack([x[i, j], y[i, j]]),
            np.column_stack([x[i + 1, j], y[i + 1, j]]),
            np.column_stack([x[i + 1, j + 1], y[i + 1, j + 1]]),
            np.column_stack([x[i, j + 1], y[i, j + 1]]),
        ],
        axis=1,
    )
    solved = field.part.solved
    assert solved.is_valid and field.outline.is_valid
    assert solved.area == pytest.approx(shapely.area(shapely.polygons(quads)).sum())
    assert field.outline.difference(solved).area <= 1e-9 * solved.area
    assert 0.85 * solved.area < field.outline.area < solved.area


def test_self_overlapping_design_takes_the_preimage_nearest_the_origin(tmp_path):
    def folded(u, v):
        return (u - 0.3) ** 2 + 0.01 * u, v

    def split_director(u, v):
        return (
            np.stack([np.where(u < 0.3, 1.0, 0.0), np.where(u < 0.3, 0.0, 1.0)], axis=-1)
            + 0 * v[..., None]
        )

    path = write_design(tmp_path / "fold.npz", folded, split_director)
    field = field_from_design(path, mm_per_unit=1.0)
    assert field.outline.is_valid and field.outline.area > 0
    # (0.05, 0.0) has preimages near u = 0.09 and u = 0.5: the first is nearer the origin
    assert field.theta(np.array([[0.05, 0.0]]))[0] == pytest.approx(0.0)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda a: a.pop("r"), "no 'r' array"),
        (lambda a: a.update(eps=a["eps"][:, :-1]), "'eps' has shape"),
    ],
)
def test_bad_design_files_are_one_line_errors(tmp_path, change, message):
    path = write_design(tmp_path / "d.npz")
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    change(arrays)
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(FabkitError, match=message):
        field_from_design(tmp_path / "bad.npz", size_mm=10)


def test_design_takes_at_most_one_scale(tmp_path):
    path = write_design(tmp_path / "d.npz")
    with pytest.raises(FabkitError, match="--size MM. or --scale, not both"):
        field_from_design(path, size_mm=10, mm_per_unit=1)
    with pytest.raises(FabkitError, match="does not exist"):
        field_from_design(tmp_path / "missing.npz", size_mm=1)


def test_expressions_allow_arctan2_and_polar_names():
    theta = planar_expression("arctan2(y, x) + 0*r - phi", "t")
    points = np.random.default_rng(2).normal(size=(50, 2))
    assert np.abs(theta(points[:, 0], points[:, 1])).max() < 1e-12
    with pytest.raises(FabkitError, match="other than 2 argument"):
        planar_expression("arctan2(y)", "t")
    with pytest.raises(FabkitError, match="not allowed"):
        planar_expression("x.__class__", "t")


@pytest.mark.parametrize(
    ("text", "area"),
    [
        ("disc:10", np.pi * 100),
        ("square:20", 400),
        ("rect:10,4", 40),
        ("annulus:2,10", np.pi * 96),
        ("ellipse:3,2", np.pi * 6),
    ],
)
def test_shapes(text, area):
    assert parse_shape(text).area == pytest.approx(area, rel=1e-3)


@pytest.mark.parametrize("text", ["disc", "disc:-1", "star:3", "rect:1", "disc:x"])
def test_bad_shapes(text):
    with pytest.raises(FabkitError, match="shape"):
        parse_shape(text)


def test_director_angles_are_reduced_mod_pi():
    field = field_from_expression("phi + 3*pi", parse_shape("disc:1"))
    theta = field.theta(np.array([[1.0, 1.0], [-1.0, 0.001]]))
    assert theta == pytest.approx([np.pi / 4, -0.001], abs=1e-6)


def test_grid_field_interpolates_the_director_as_a_tensor():
    xs = np.linspace(-5, 5, 101)
    grid = np.meshgrid(xs, xs, indexing="ij")
    theta = np.arctan2(grid[1], grid[0]) + np.pi / 2  # azimuthal, wraps at -x
    mask = np.hypot(*grid) <= 4.5
    field = field_from_grid(theta, mask, 0.1, origin=(-5.0, -5.0), eps=grid[0])
    assert field.outline.area == pytest.approx(np.pi * 4.5**2, rel=0.01)
    angle = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    points = 3 * np.column_stack([np.cos(angle), np.sin(angle)]) + 0.037
    expected = np.arctan2(points[:, 1], points[:, 0]) + np.pi / 2
    difference = np.angle(np.exp(2j * (field.theta(points) - expected))) / 2
    assert np.abs(difference).max() < 5e-3
    assert field.eps(points) == pytest.approx(points[:, 0], abs=1e-9)


def test_director_files_and_clipping(tmp_path):
    field = load_director_file(EXAMPLES / "radial.toml")
    assert field.outline.area == pytest.approx(np.pi * 100, rel=1e-3)
    assert field.clipped(parse_shape("square:10")).outline.area == pytest.approx(100)
    bad = tmp_path / "bad.toml"
    bad.write_text('[director]\ntheta = "phi"\n')
    with pytest.raises(FabkitError, match="exactly one of shape and outline"):
        load_director_file(bad)
    bad.write_text('[director]\ntheta = "phi"\nshape = "disc:1"\ncolour = 1\n')
    with pytest.raises(
        FabkitError, match=r"bad\.toml: director\.colour: unknown key \(allowed: eps, grid"
    ):
        load_director_file(bad)
    outline = tmp_path / "outline.toml"
    outline.write_text('[director]\ntheta = "0"\noutline = [[0, 0], [4, 0], [4, 3]]\n')
    assert load_director_file(outline).outline.area == pytest.approx(6)


@pytest.mark.parametrize(
    ("theta", "eps", "message"),
    [
        ("sqrt(x - 100)", None, r"--director: not finite at (\d+) of \1 points of the sheet"),
        ("log(r)", None, r"--director: not finite at 1 of \d+ points .*x = 0, y = 0 mm"),
        ("1/(x - x)", None, "--director: not finite at"),
        ("phi", "log(x)", r"--eps: not finite at \d+ of \d+ points of the sheet"),
        ("phi", "log(0)", r"--eps: log\(0\) is not finite"),
    ],
)
def test_fields_must_be_finite_on_the_whole_sheet(theta, eps, message):
    with pytest.raises(FabkitError, match=message):
        field_from_expression(theta, parse_shape("disc:10"), eps)


def test_a_field_singular_between_the_samples_is_refused_where_it_is_evaluated():
    field = field_from_expression("0.1/(x - 0.123456789)", parse_shape("disc:10"))
    assert np.isfinite(field.theta(np.array([[1.0, 2.0]]))).all()
    with pytest.raises(FabkitError, match=r"--director: not finite at 1 of 2 points on the"):
        field.theta(np.array([[1.0, 2.0], [0.123456789, 0.0]]))


def test_a_field_undefined_beyond_the_edge_takes_the_nearest_edge_value():
    field = field_from_expression("arccos(r/10)", parse_shape("disc:10"), eps="sqrt(10 - r)")
    outside = np.array([[12.0, 0.0], [0.0, -15.0]])
    assert field.theta(outside) == pytest.approx(0.0, abs=1e-4)
    assert field.eps(outside) == pytest.approx(0.0, abs=1e-2)
    inside = np.array([[5.0, 0.0]])
    assert field.theta(inside) == pytest.approx(np.arccos(0.5))


def test_fields_from_files_name_their_keys(tmp_path):
    path = tmp_path / "d.toml"
    path.write_text('[director]\ntheta = "phi"\nshape = "disc:5"\neps = "1/(x - 1)"\n')
    with pytest.raises(FabkitError, match=r"d.toml: director.eps: not finite at"):
        load_director_file(path)


def test_grid_fields_must_be_finite_on_their_mask(tmp_path):
    theta, mask = np.zeros((6, 6)), np.ones((6, 6), dtype=bool)
    theta[2, 3] = np.nan
    with pytest.raises(FabkitError, match=r"theta is not finite at 1 of 36 nodes .*\(2, 3\)"):
        field_from_grid(theta, mask, 1.0)
    mask[2, 3] = False
    assert field_from_grid(theta, mask, 1.0).theta(np.array([[2.0, 3.0]])).shape == (1,)
    with pytest.raises(FabkitError, match="eps is not finite at 35 of 35"):
        field_from_grid(theta, mask, 1.0, eps=np.full((6, 6), np.inf))


@pytest.mark.parametrize(
    ("arrays", "message"),
    [
        ({"theta": np.zeros((3, 3, 3))}, "'theta' must be a 2-D array of real numbers"),
        ({"pixel_mm": np.ones(2)}, "'pixel_mm' must be a 0-D array"),
        ({"theta": np.zeros((4, 4)) + 1j}, "'theta' holds complex128 values; expected real"),
        ({"mask": np.array([["a"] * 4] * 4)}, "'mask' holds <U1 values; expected real"),
        ({"origin": np.zeros(3)}, "origin must be 2 finite numbers"),
        ({"origin": np.array([np.nan, 0.0])}, "origin must be 2 finite numbers"),
        pytest.param(
            {"theta": np.random.default_rng(0).integers(0, 9, (5001, 5001), np.int8)},
            "more than 25000000",
            marks=pytest.mark.slow,  # writes a 25 MB file
        ),
    ],
)
def test_bad_director_grid_files_are_one_line_errors(tmp_path, arrays, message):
    base = {"theta": np.zeros((4, 4)), "mask": np.ones((4, 4), dtype=bool), "pixel_mm": 0.5}
    np.savez_compressed(tmp_path / "grid.npz", **{**base, **arrays})
    (tmp_path / "d.toml").write_text('[director]\ngrid = "grid.npz"\n')
    with pytest.raises(FabkitError, match=message) as info:
        load_director_file(tmp_path / "d.toml")
    assert "\n" not in str(info.value)


@given(st.floats(-1e3, 1e3, allow_nan=False))
def test_a_director_angle_is_taken_mod_pi_into_the_half_open_half_turn(angle):
    wrapped = float(director_angle(np.array(angle)))
    assert -np.pi / 2 < wrapped <= np.pi / 2
    turns = (angle - wrapped) / np.pi
    assert abs(turns - round(turns)) < 1e-9 * max(1.0, abs(angle))
