"""Outlines a user gives, in mm on the flat sheet: a named shape or closed paths from a file.

:func:`read_outline` takes the text of ``--outline``:

* a named shape centred on the origin (:func:`parse_shape`): ``disc:R``, ``annulus:R1,R2``,
  ``square:S``, ``rect:W,H``, ``ellipse:A,B``;
* a polygon file: GeoJSON (``.geojson``/``.json``: Polygon and MultiPolygon geometries, bare
  or in a Feature or FeatureCollection) or CSV (``.csv``: one ``x,y`` pair per line, mm; a
  blank line starts another ring; a first line that is not two numbers is a header);
* the closed paths of a drawing: DXF (``.dxf``: closed LWPOLYLINE and POLYLINE, CIRCLE,
  full ELLIPSE, closed SPLINE; arcs, bulges and splines flattened to 0.01 mm) or SVG
  (``.svg``: ``<path d>`` subpaths closed by ``z``, ``<polygon>``, ``<rect>``, ``<circle>``,
  ``<ellipse>``, with their ``transform`` attributes; user units are mm and the SVG's y
  axis, which points down, is turned up).

Several rings combine by the even-odd rule (a ring inside another cuts a hole), as a
drawing program fills them. Coordinates are in the sheet frame, the frame of the toolpath
and of ``fabkit toolpath --shape``. Every file is bounded like fabkit's other readers: at
most :data:`OUTLINE_BYTES` (DXF :data:`OUTLINE_DXF_BYTES`), at most
:data:`OUTLINE_VERTICES` vertices once flattened, coordinates within
:data:`~fabkit.limits.MAGNITUDE`; an SVG with a DOCTYPE or an entity is refused before it
is parsed. Bad input is a one-line :class:`~fabkit.errors.FabkitError`.

The SVG reader is fabkit's own (about 200 lines): the standard library's XML parser with
DOCTYPEs refused (so no entity expansion and no external reference), and a path parser
that knows the eight SVG path commands. It was preferred to svgelements or svgpathtools
because an outline needs only closed fills and a handful of elements, and a small reader
can bound every loop by the input's size.
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import shapely
import shapely.affinity
import shapely.geometry

from fabkit.errors import FabkitError
from fabkit.files.readfile import check_size, decode_utf8, read_json, read_limited
from fabkit.limits import MAGNITUDE, MIB

OUTLINE_BYTES = 16 * MIB
"""Largest polygon (GeoJSON, CSV) or SVG outline file."""
OUTLINE_DXF_BYTES = 64 * MIB
"""Largest DXF outline file."""
OUTLINE_VERTICES = 1_000_000
"""Most vertices of a user outline, once its curves are flattened."""
FLATTEN_MM = 0.01
"""Largest distance between a curve of a drawing and its flattened polyline, mm."""
CURVE_SEGMENTS = 64
"""Segments of one flattened SVG curve command (Bezier or arc)."""
SHAPES = {"disc": 1, "square": 1, "annulus": 2, "rect": 2, "ellipse": 2}
"""The named shapes and their number of sizes."""
SHAPE_MIN_MM = 1e-3
"""Smallest size of a named shape, mm (a micrometre, finer than any machine draws); the
largest is :data:`~fabkit.limits.MAGNITUDE`. Sizes outside both are refused before shapely
sees them (it would warn of an overflow, or build an empty or degenerate polygon)."""


def parse_shape(text: Any, where: str = "shape") -> shapely.Polygon:
    """A named outline centred on the origin, in mm.

    ``disc:R`` (radius R), ``annulus:R1,R2``, ``square:S`` (side S), ``rect:W,H``,
    ``ellipse:A,B`` (semi-axes); every size from :data:`SHAPE_MIN_MM` to
    :data:`~fabkit.limits.MAGNITUDE` mm.
    """
    if not isinstance(text, str) or ":" not in text:
        raise FabkitError(f"{where}: expected e.g. 'disc:10' or 'square:20', got {text!r}")
    kind, _, arguments = text.partition(":")
    try:
        values = [float(v) for v in arguments.split(",")]
    except ValueError:
        raise FabkitError(f"{where}: '{arguments}' is not a list of numbers") from None
    if kind not in SHAPES:
        raise FabkitError(f"{where}: unknown shape '{kind}' (use {', '.join(SHAPES)})")
    if len(values) != SHAPES[kind] or not all(v > 0 for v in values):  # NaN is not > 0
        raise FabkitError(f"{where}: '{kind}' needs {SHAPES[kind]} positive number(s)")
    for value in values:
        if not SHAPE_MIN_MM <= value <= MAGNITUDE:  # infinity too
            raise FabkitError(
                f"{where}: '{kind}' sizes must be between {SHAPE_MIN_MM:g} and {MAGNITUDE:g} "
                f"mm, got {value!r}"
            )
    if kind == "disc":
        return shapely.Point(0, 0).buffer(values[0], quad_segs=128)
    if kind == "square":
        return shapely.box(-values[0] / 2, -values[0] / 2, values[0] / 2, values[0] / 2)
    if kind == "rect":
        return shapely.box(-values[0] / 2, -values[1] / 2, values[0] / 2, values[1] / 2)
    if kind == "ellipse":
        circle = shapely.Point(0, 0).buffer(1.0, quad_segs=128)
        return shapely.affinity.scale(circle, values[0], values[1], origin=(0, 0))
    inner, outer = sorted(values)
    if inner == outer:
        raise FabkitError(f"{where}: the annulus radii must differ")
    disc = shapely.Point(0, 0).buffer(outer, quad_segs=128)
    return disc.difference(shapely.Point(0, 0).buffer(inner, quad_segs=128))


def read_outline(text: str, where: str = "--outline") -> shapely.Polygon | shapely.MultiPolygon:
    """The outline named by ``text`` (a shape or a file, see the module docstring), mm."""
    if not isinstance(text, str) or not text:
        raise FabkitError(f"{where}: expected a shape like 'disc:20' or an outline file")
    kind = text.partition(":")[0]
    if kind in SHAPES and not Path(text).exists():
        return parse_shape(text, where)
    path = Path(text)
    suffix = path.suffix.lower()
    readers = {".dxf": _dxf_rings, ".svg": _svg_rings, ".csv": _csv_rings}
    readers |= {".geojson": _geojson_rings, ".json": _geojson_rings}
    if suffix not in readers:
        raise FabkitError(
            f"{where} {text}: expected a shape ({', '.join(f'{k}:...' for k in SHAPES)}) or "
            "an outline file (.dxf, .svg, .geojson, .json, .csv)"
        )
    label = f"{where} '{path}'"
    rings = readers[suffix](path, label)
    return _even_odd(rings, label)


def _even_odd(rings: list[np.ndarray], label: str) -> shapely.Polygon | shapely.MultiPolygon:
    """The region of closed ``rings`` (each (n, 2), mm) by the even-odd rule."""
    total = sum(len(r) for r in rings)
    if total > OUTLINE_VERTICES:
        raise FabkitError(
            f"{label}: {total} vertices, more than the limit of {OUTLINE_VERTICES} (simplify it)"
        )
    region = shapely.Polygon()
    for ring in rings:
        if len(ring) < 3:
            continue
        if not np.isfinite(ring).all() or np.abs(ring).max() > MAGNITUDE:
            raise FabkitError(f"{label}: a coordinate is not finite or beyond +-{MAGNITUDE:g} mm")
        polygon = shapely.make_valid(shapely.Polygon(ring))
        region = shapely.symmetric_difference(region, polygonal(polygon))
    region = polygonal(region)
    if region.is_empty or region.area <= 0:
        raise FabkitError(f"{label}: no closed path with an area (an outline must be closed)")
    return region


def polygonal(geometry: shapely.Geometry) -> shapely.Polygon | shapely.MultiPolygon:
    """The polygonal part of a geometry (drops points and lines from intersections)."""
    parts = [g for g in shapely.get_parts(geometry) if isinstance(g, shapely.Polygon)]
    parts = [p for p in parts if p.area > 0]
    if not parts:
        return shapely.Polygon()
    return parts[0] if len(parts) == 1 else shapely.MultiPolygon(parts)


# --------------------------------------------------------------------------- polygon files


def _geojson_rings(path: Path, label: str) -> list[np.ndarray]:
    """The rings of every Polygon and MultiPolygon of a GeoJSON file."""
    data = read_json(path, f"{label.split(' ')[0]} file", OUTLINE_BYTES)
    geometries = []
    items = [data]
    while items:
        item = items.pop()
        if not isinstance(item, dict):
            raise FabkitError(f"{label}: not GeoJSON (expected objects, got {type(item).__name__})")
        kind = item.get("type")
        if kind == "FeatureCollection" and isinstance(item.get("features"), list):
            items.extend(item["features"])
        elif kind == "Feature":
            items.append(item.get("geometry"))
        elif kind in ("Polygon", "MultiPolygon"):
            try:
                geometries.append(shapely.geometry.shape(item))
            except (KeyError, TypeError, ValueError, AttributeError, IndexError) as exc:
                raise FabkitError(f"{label}: a {kind} is malformed ({exc})") from None
        else:
            raise FabkitError(
                f"{label}: not a polygon (GeoJSON type {kind!r}; expected Polygon, "
                "MultiPolygon, Feature or FeatureCollection)"
            )
    rings = []
    for polygon in (p for g in geometries for p in shapely.get_parts(g)):
        rings.append(np.asarray(polygon.exterior.coords, dtype=float)[:, :2])
        rings.extend(np.asarray(r.coords, dtype=float)[:, :2] for r in polygon.interiors)
    return rings


def _csv_rings(path: Path, label: str) -> list[np.ndarray]:
    """Rings of ``x,y`` lines (mm), separated by blank lines; an optional header line."""
    text = decode_utf8(read_limited(path, "outline file", OUTLINE_BYTES), "outline file", path)
    rings: list[list[tuple[float, float]]] = [[]]
    count = 0
    for number, line in enumerate(text.splitlines(), start=1):
        cells = [c.strip() for c in line.replace(";", ",").split(",")]
        if not any(cells):
            if rings[-1]:
                rings.append([])
            continue
        try:
            if len(cells) != 2:
                raise ValueError
            rings[-1].append((float(cells[0]), float(cells[1])))
        except ValueError:
            if number == 1:
                continue  # a header
            raise FabkitError(
                f"{label} line {number}: expected 'x,y' in mm, got {line[:60]!r}"
            ) from None
        count += 1
        if count > OUTLINE_VERTICES:
            raise FabkitError(f"{label}: more than the limit of {OUTLINE_VERTICES} vertices")
    return [np.array(r, dtype=float) for r in rings if r]


# --------------------------------------------------------------------------- DXF


def _dxf_rings(path: Path, label: str) -> list[np.ndarray]:
    """The closed paths of a DXF's modelspace, flattened to FLATTEN_MM."""
    import ezdxf
    from ezdxf import path as dxfpath
    from ezdxf.lldxf.const import DXFError

    check_size(path, "outline file", OUTLINE_DXF_BYTES)
    try:
        document = ezdxf.readfile(path)
    except (OSError, DXFError, UnicodeDecodeError, ValueError) as exc:
        raise FabkitError(f"{label}: not a readable DXF ({exc})") from None
    rings, count = [], 0
    kinds = ("LWPOLYLINE", "POLYLINE", "CIRCLE", "ELLIPSE", "SPLINE")
    for entity in document.modelspace():
        if entity.dxftype() not in kinds or not _dxf_closed(entity):
            continue
        try:
            outline = dxfpath.make_path(entity)
            control = np.array([tuple(v)[:2] for v in outline.control_vertices()], dtype=float)
            if len(control) == 0 or not np.isfinite(control).all():
                continue
            if np.abs(control).max() > MAGNITUDE:
                raise FabkitError(f"{label}: a coordinate is beyond +-{MAGNITUDE:g} mm")
            size = float(np.ptp(control, axis=0).max())
            distance = max(FLATTEN_MM, 1e-5 * size)
            points = np.array([tuple(v)[:2] for v in outline.flattening(distance)], dtype=float)
        except (DXFError, ValueError, TypeError, ZeroDivisionError, AttributeError) as exc:
            raise FabkitError(f"{label}: a {entity.dxftype()} cannot be read ({exc})") from None
        count += len(points)
        if count > OUTLINE_VERTICES:
            raise FabkitError(f"{label}: more than the limit of {OUTLINE_VERTICES} vertices")
        rings.append(points)
    if not rings:
        raise FabkitError(
            f"{label}: no closed path (closed LWPOLYLINE or POLYLINE, CIRCLE, ELLIPSE, SPLINE)"
        )
    return rings


def _dxf_closed(entity) -> bool:
    """Whether a DXF entity is a closed curve."""
    kind = entity.dxftype()
    if kind == "CIRCLE":
        return True
    if kind == "ELLIPSE":
        start, end = entity.dxf.get("start_param", 0.0), entity.dxf.get("end_param", math.tau)
        return math.isclose(abs(end - start), math.tau, rel_tol=1e-9)
    if kind == "SPLINE":
        return bool(entity.closed)
    return bool(entity.is_closed)


# --------------------------------------------------------------------------- SVG

_SVG_ELEMENTS = ("path", "polygon", "rect", "circle", "ellipse")
_NUMBER = re.compile(r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?")
_PATH_TOKEN = re.compile(r"([MmLlHhVvCcSsQqTtAaZz])|([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)")
_ARGUMENTS = {"m": 2, "l": 2, "h": 1, "v": 1, "c": 6, "s": 4, "q": 4, "t": 2, "a": 7, "z": 0}
_TRANSFORM = re.compile(r"\s*(matrix|translate|scale|rotate|skewX|skewY)\s*\(([^)]*)\)\s*,?")


def _svg_rings(path: Path, label: str) -> list[np.ndarray]:
    """The closed fills of an SVG (module docstring), y turned up."""
    import xml.etree.ElementTree as ElementTree

    data = read_limited(path, "outline file", OUTLINE_BYTES)
    head = data.lower()
    if b"<!doctype" in head or b"<!entity" in head:
        raise FabkitError(f"{label}: an SVG with a DOCTYPE or entities is not read (remove it)")
    try:
        root = ElementTree.fromstring(data)
    except ElementTree.ParseError as exc:
        raise FabkitError(f"{label}: not a readable SVG ({exc})") from None
    if _local(root.tag) != "svg":
        raise FabkitError(f"{label}: not an SVG (root element <{_local(root.tag)}>)")
    rings: list[np.ndarray] = []
    stack = [(root, np.eye(3))]
    while stack:
        element, parent = stack.pop()
        matrix = parent @ _svg_transform(element.get("transform", ""), label)
        name = _local(element.tag)
        if name in ("defs", "clipPath", "mask", "symbol", "pattern", "marker"):
            continue
        if name in _SVG_ELEMENTS:
            for ring in _svg_element(element, name, label):
                moved = np.column_stack([ring, np.ones(len(ring))]) @ matrix.T
                rings.append(moved[:, :2] * np.array([1.0, -1.0]))
                if sum(len(r) for r in rings) > OUTLINE_VERTICES:
                    raise FabkitError(f"{label}: more than {OUTLINE_VERTICES} vertices")
        stack.extend((child, matrix) for child in element)
    if not rings:
        raise FabkitError(
            f"{label}: no closed path (<path> closed by z, <polygon>, <rect>, <circle>, <ellipse>)"
        )
    return rings


def _local(tag: Any) -> str:
    """An XML tag without its namespace."""
    return str(tag).rpartition("}")[2]


def _numbers(text: str | None, label: str, what: str) -> list[float]:
    values = [float(v) for v in _NUMBER.findall(text or "")]
    if not all(math.isfinite(v) for v in values):
        raise FabkitError(f"{label}: {what} has a number that is not finite")
    return values


def _svg_length(element, key: str, label: str, default: float | None = None) -> float:
    values = _numbers(element.get(key), label, f"<{_local(element.tag)}> {key}")
    if not values:
        if default is None:
            raise FabkitError(f"{label}: <{_local(element.tag)}> has no {key}")
        return default
    return values[0]


def _svg_element(element, name: str, label: str) -> list[np.ndarray]:
    """The closed rings of one SVG element (user units, y down)."""
    if name == "path":
        return _svg_path(element.get("d", ""), label)
    if name == "polygon":
        values = _numbers(element.get("points"), label, "<polygon> points")
        return [np.array(values[: len(values) // 2 * 2], dtype=float).reshape(-1, 2)]
    if name == "rect":
        x, y = _svg_length(element, "x", label, 0.0), _svg_length(element, "y", label, 0.0)
        w, h = _svg_length(element, "width", label), _svg_length(element, "height", label)
        return [np.array([[x, y], [x + w, y], [x + w, y + h], [x, y + h]], dtype=float)]
    cx, cy = _svg_length(element, "cx", label, 0.0), _svg_length(element, "cy", label, 0.0)
    if name == "circle":
        rx = ry = _svg_length(element, "r", label)
    else:
        rx, ry = _svg_length(element, "rx", label), _svg_length(element, "ry", label)
    angle = np.linspace(0, 2 * np.pi, 4 * CURVE_SEGMENTS, endpoint=False)
    return [np.column_stack([cx + rx * np.cos(angle), cy + ry * np.sin(angle)])]


def _svg_transform(text: str, label: str) -> np.ndarray:
    """The 3 x 3 matrix of an SVG ``transform`` attribute (identity when empty)."""
    matrix = np.eye(3)
    position = 0
    while position < len(text.strip()):
        found = _TRANSFORM.match(text, position)
        if found is None:
            raise FabkitError(f"{label}: transform {text[:60]!r} is not understood")
        position = found.end()
        kind, values = found.group(1), _numbers(found.group(2), label, "a transform")
        matrix = matrix @ _transform_matrix(kind, values, label)
        if not text[position:].strip():
            break
    return matrix


def _transform_matrix(kind: str, values: list[float], label: str) -> np.ndarray:
    counts = {"matrix": (6,), "translate": (1, 2), "scale": (1, 2), "rotate": (1, 3)}
    if len(values) not in counts.get(kind, (1,)):
        raise FabkitError(f"{label}: {kind}() with {len(values)} numbers")
    if kind == "matrix":
        a, b, c, d, e, f = values
        return np.array([[a, c, e], [b, d, f], [0, 0, 1]])
    if kind == "translate":
        tx, ty = values[0], values[1] if len(values) > 1 else 0.0
        return np.array([[1, 0, tx], [0, 1, ty], [0, 0, 1]])
    if kind == "scale":
        sx, sy = values[0], values[1] if len(values) > 1 else values[0]
        return np.diag([sx, sy, 1.0])
    angle = math.radians(values[0])
    if kind == "skewX":
        return np.array([[1, math.tan(angle), 0], [0, 1, 0], [0, 0, 1]])
    if kind == "skewY":
        return np.array([[1, 0, 0], [math.tan(angle), 1, 0], [0, 0, 1]])
    cos, sin = math.cos(angle), math.sin(angle)
    rotation = np.array([[cos, -sin, 0], [sin, cos, 0], [0, 0, 1]])
    if len(values) == 3:
        shift = np.array([[1, 0, values[1]], [0, 1, values[2]], [0, 0, 1]])
        return shift @ rotation @ np.linalg.inv(shift)
    return rotation


def _svg_path(text: str, label: str) -> list[np.ndarray]:
    """The subpaths of a path's ``d`` that are closed (by z, or ending where they start),
    read token by token (a file's worth of numbers is never held as a list)."""
    state = _PathState(label)
    command, pending, done = "", [], True
    for match in _PATH_TOKEN.finditer(text):
        letter, number = match.group(1), match.group(2)
        if letter:
            if pending or not done:
                raise FabkitError(f"{label}: path command {command} lacks numbers")
            command, done = letter, letter in "Zz"
            if done:
                state.finish(explicit=True)
            continue
        if not command or command in "Zz":
            raise FabkitError(f"{label}: a number in a path's d follows no drawing command")
        pending.append(float(number))
        if len(pending) == _ARGUMENTS[command.lower()]:
            state.step(command, np.array(pending))
            pending, done = [], True
            if command in "Mm":
                command = "l" if command == "m" else "L"  # further pairs are line-tos
    if pending or not done:
        raise FabkitError(f"{label}: path command {command} lacks numbers")
    state.finish(explicit=False)
    return state.rings


class _PathState:
    """The pen of an SVG path: where it is, the subpath being drawn and the closed rings."""

    def __init__(self, label: str):
        self.label = label
        self.rings: list[np.ndarray] = []
        self.current: list[np.ndarray] = []
        self.point = self.start = np.zeros(2)
        self.control: np.ndarray | None = None  # the last Bezier control point (S, T)
        self.count = 0

    def finish(self, explicit: bool) -> None:
        """End the subpath; keep it if it is closed."""
        current = self.current
        if len(current) > 2 and (explicit or np.allclose(current[0], current[-1])):
            self.rings.append(np.array(current))
        self.current, self.point, self.control = [], self.start, None

    def step(self, command: str, values: np.ndarray) -> None:
        """Draw one command with its numbers."""
        if not np.isfinite(values).all():
            raise FabkitError(f"{self.label}: a path has a number that is not finite")
        kind, relative = command.lower(), command.islower()
        base = self.point if relative else np.zeros(2)
        if kind == "m":
            self.finish(explicit=False)
            self.point = self.start = base + values
            self.current = [self.point]
            return
        if not self.current:
            self.current = [self.point]
        control = None
        if kind == "l":
            points = [base + values]
        elif kind == "h":
            points = [np.array([values[0] + (self.point[0] if relative else 0.0), self.point[1]])]
        elif kind == "v":
            points = [np.array([self.point[0], values[0] + (self.point[1] if relative else 0.0)])]
        elif kind in "cs":
            reflected = 2 * self.point - self.control if self.control is not None else self.point
            first = base + values[0:2] if kind == "c" else reflected
            control, end = base + values[-4:-2], base + values[-2:]
            points = _bezier([self.point, first, control, end])
        elif kind in "qt":
            reflected = 2 * self.point - self.control if self.control is not None else self.point
            control = base + values[0:2] if kind == "q" else reflected
            points = _bezier([self.point, control, base + values[-2:]])
        else:
            points = _arc(self.point, *values[:5], base + values[5:7])
        self.current.extend(points)
        self.point, self.control = points[-1], control
        self.count += len(points)
        if self.count > OUTLINE_VERTICES:
            raise FabkitError(f"{self.label}: more than the limit of {OUTLINE_VERTICES} vertices")


def _bezier(points: list[np.ndarray]) -> list[np.ndarray]:
    """A Bezier curve of the given control points, CURVE_SEGMENTS points after the first."""
    t = np.linspace(0, 1, CURVE_SEGMENTS + 1)[1:, None]
    degree = len(points) - 1
    curve = sum(
        math.comb(degree, k) * (1 - t) ** (degree - k) * t**k * points[k] for k in range(degree + 1)
    )
    return list(curve)


def _arc(
    start: np.ndarray,
    rx: float,
    ry: float,
    rotation_deg: float,
    large: float,
    sweep: float,
    end: np.ndarray,
) -> list[np.ndarray]:
    """An SVG elliptical arc from ``start`` to ``end`` (the SVG specification's endpoint to
    centre conversion), CURVE_SEGMENTS points after the first."""
    rx, ry = abs(rx), abs(ry)
    if rx == 0 or ry == 0 or np.allclose(start, end):
        return [end]
    phi = math.radians(rotation_deg)
    cos, sin = math.cos(phi), math.sin(phi)
    half = (start - end) / 2
    x1 = cos * half[0] + sin * half[1]
    y1 = -sin * half[0] + cos * half[1]
    scale = x1**2 / rx**2 + y1**2 / ry**2
    if scale > 1:
        rx, ry = rx * math.sqrt(scale), ry * math.sqrt(scale)
    numerator = max(rx**2 * ry**2 - rx**2 * y1**2 - ry**2 * x1**2, 0.0)
    factor = math.sqrt(numerator / (rx**2 * y1**2 + ry**2 * x1**2))
    if bool(large) == bool(sweep):
        factor = -factor
    cx1, cy1 = factor * rx * y1 / ry, -factor * ry * x1 / rx
    centre = np.array([cos * cx1 - sin * cy1, sin * cx1 + cos * cy1]) + (start + end) / 2
    theta1 = math.atan2((y1 - cy1) / ry, (x1 - cx1) / rx)
    theta2 = math.atan2((-y1 - cy1) / ry, (-x1 - cx1) / rx)
    delta = theta2 - theta1
    if sweep and delta < 0:
        delta += 2 * math.pi
    elif not sweep and delta > 0:
        delta -= 2 * math.pi
    angles = theta1 + delta * np.linspace(0, 1, CURVE_SEGMENTS + 1)[1:]
    ex, ey = rx * np.cos(angles), ry * np.sin(angles)
    points = np.column_stack([cos * ex - sin * ey, sin * ex + cos * ey]) + centre
    return list(points)
