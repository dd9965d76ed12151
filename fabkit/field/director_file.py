"""A director file (``.toml``, see ``docs/toolpath.md``) as a
:class:`~fabkit.field.flat.FlatField`: :func:`load_director_file` reads its ``[director]``
table, ``theta`` (and ``eps``) as expressions on a named shape or an outline
(:func:`~fabkit.field.flat.field_from_expression`), or a theta grid and mask in an
``.npz`` file (:func:`~fabkit.field.flat.field_from_grid`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
import shapely

from fabkit.errors import FabkitError
from fabkit.field.flat import FlatField, field_from_expression, field_from_grid
from fabkit.field.outlines import parse_shape, polygonal
from fabkit.files.npzfile import ArrayHeader, read_npz
from fabkit.files.shipped import user_or_example
from fabkit.files.tomlfile import Table, expected, read_toml


def load_director_file(path: str | Path) -> FlatField:
    """A director field from a TOML file (see ``docs/toolpath.md``)::

    [director]
    theta = "phi + pi/2"      # radians; names x, y, r, phi; arctan2(a, b) allowed
    shape = "disc:10"         # or outline = [[x, y], ...] (mm)
    eps = "0.3"               # optional: the feature eps; or { eps1 = "...", eps2 = "..." }
    # or, instead of theta/eps: grid = "theta.npz" with theta, mask, pixel_mm (, eps)
    """
    path = user_or_example(path)
    top = Table(read_toml(path, "director"), str(path))
    top.check_keys({"director"})
    director = top.table("director")
    where = director.at()
    director.check_keys({"theta", "shape", "outline", "eps", "grid"})
    if "grid" in director:
        return _grid_file(path.parent / str(director["grid"]), where)
    director.require(("theta",), "an expression in x, y, r and phi (or grid, an .npz file)")
    if ("shape" in director) == ("outline" in director):
        given = [key for key in ("shape", "outline") if key in director]
        director.expected(None, "exactly one of shape and outline", given)
    if "shape" in director:
        outline = parse_shape(director["shape"], director.at("shape"))
    else:
        outline = _outline_points(director["outline"], director.at("outline"))
    field = field_from_expression(director["theta"], outline, director.get("eps"), where)
    return replace(field, source=f"{path}")


def _outline_points(value: Any, where: str) -> shapely.Polygon:
    try:
        points = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        points = np.zeros((0,))
    if points.ndim != 2 or points.shape[1] != 2 or len(points) < 3 or not np.isfinite(points).all():
        _refuse_points(value, where)
    polygon = shapely.Polygon(points)
    if not polygon.is_valid:
        polygon = polygonal(shapely.make_valid(polygon))
    return polygon


def _refuse_points(value: Any, where: str) -> NoReturn:
    """Refuse an outline that is not at least 3 [x, y] points, naming the first bad item."""
    if isinstance(value, list) and len(value) >= 3:
        for i, point in enumerate(value):
            if not isinstance(point, list) or len(point) != 2:
                expected(f"{where}[{i}]", "an [x, y] point (mm)", point)
            for j, coordinate in enumerate(point):
                try:
                    finite = bool(np.isfinite(float(coordinate)))
                except (TypeError, ValueError):
                    finite = False
                if not finite:
                    expected(f"{where}[{i}][{j}]", "a finite number", coordinate)
    expected(where, "a list of at least 3 [x, y] points (mm)", value)


GRID_ARRAYS = {"theta": 2, "mask": 2, "pixel_mm": 0, "eps": 2, "origin": 1}
"""Arrays of a director grid file (.npz) by name, with their number of dimensions."""


MAX_GRID_NODES = 25_000_000
"""Most nodes of a director grid file's theta (5000 x 5000)."""


def _grid_file(path: Path, where: str) -> FlatField:
    """A director grid file: theta (nx, ny) rad, mask (nx, ny), pixel_mm, optional eps
    (nx, ny) and origin (2,) mm; every array is checked before it is used."""
    if not path.is_file():
        raise FabkitError(f"{where}.grid: file '{path}' does not exist")
    label = f"{where}.grid: '{path}'"
    arrays = read_npz(
        path,
        f"{where}.grid: cannot read '{path}'",
        check=lambda headers: _check_grid_headers(headers, label),
    )
    missing = [k for k in ("theta", "mask", "pixel_mm") if k not in arrays]
    if missing:
        raise FabkitError(f"{label} has no '{missing[0]}' array")
    origin = np.asarray(arrays.get("origin", np.zeros(2)), dtype=float)
    if origin.shape != (2,) or not np.all(np.isfinite(origin)):
        raise FabkitError(f"{label}: origin must be 2 finite numbers (mm)")
    return field_from_grid(
        arrays["theta"],
        arrays["mask"],
        float(arrays["pixel_mm"]),
        (float(origin[0]), float(origin[1])),
        arrays.get("eps"),
        str(path),
    )


def _check_grid_headers(headers: Mapping[str, ArrayHeader], where: str) -> None:
    """Refuse a director grid file from its headers: known arrays only, each real or
    boolean, of the expected dimensions, and at most MAX_GRID_NODES nodes."""
    for key, header in headers.items():
        if key not in GRID_ARRAYS:
            raise FabkitError(f"{where}: unknown array '{key}' (expected {', '.join(GRID_ARRAYS)})")
        if len(header.shape) != GRID_ARRAYS[key] or header.dtype.kind not in "biuf":
            raise FabkitError(
                f"{where}: '{key}' must be a {GRID_ARRAYS[key]}-D array of real numbers, got "
                f"shape {header.shape} of {header.dtype}"
            )
        nodes = int(np.prod(header.shape))
        if nodes > MAX_GRID_NODES:
            raise FabkitError(f"{where}: '{key}' has {nodes} nodes, more than {MAX_GRID_NODES}")
