"""Read a DXF back as a machine that takes drawings would: its roads and their settings.

The ``PATHS`` layer holds one polyline per printed road (or several consecutive ones for
a long road), drawn at the road's constant width, with the process values of every
vertex as extended data of the application ``FABKIT`` (a name, then one real per
vertex): a segment takes the values of the vertex it ends at. Polylines that start where
the previous one ended continue its road. The sheet's placement is read from the
header's custom properties ``fabkit_offset_mm`` and ``fabkit_mm_per_unit`` when the
drawing has them. Nothing of the writer is used.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from fabkit.errors import FabkitError
from fabkit.verify.read_gcode import Placement

APP_ID = "FABKIT"
PATHS = "PATHS"


def read_dxf(
    path: str | Path, road_width_mm: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray], Placement]:
    """Segments of the drawing's roads (drawing frame, mm): start (n, 2), end (n, 2),
    width (n,) (``road_width_mm`` where a polyline has none), road (n,), values name ->
    (n,), and the placement its header records."""
    import ezdxf
    from ezdxf.lldxf.const import DXFError

    path = Path(path)
    try:
        document = ezdxf.readfile(path)
    except (OSError, DXFError, UnicodeDecodeError, ValueError) as exc:
        raise FabkitError(f"{path}: not a readable DXF ({exc})") from None
    parts: list[tuple[np.ndarray, float, dict[str, np.ndarray]]] = []
    for entity in document.modelspace():
        if entity.dxf.get("layer") != PATHS or entity.dxftype() not in ("LWPOLYLINE", "POLYLINE"):
            continue
        if entity.dxftype() == "LWPOLYLINE":
            points = np.array([(p[0], p[1]) for p in entity.get_points("xy")], dtype=float)
            width = float(entity.dxf.get("const_width", 0.0)) or road_width_mm
        else:
            points = np.array([tuple(v.dxf.location)[:2] for v in entity.vertices], dtype=float)
            width = road_width_mm
        if len(points) < 2:
            continue
        parts.append((points, width, _channels(entity, len(points), path)))
    if not parts:
        raise FabkitError(f"{path}: no road on layer {PATHS} (nothing printed)")
    starts, ends, widths, roads, values = [], [], [], [], {}
    names = sorted({name for _, _, channels in parts for name in channels})
    road = -1
    last_end = None
    for points, width, channels in parts:
        if last_end is None or not np.allclose(points[0], last_end, atol=1e-6):
            road += 1
        last_end = points[-1]
        count = len(points) - 1
        starts.append(points[:-1])
        ends.append(points[1:])
        widths.append(np.full(count, width))
        roads.append(np.full(count, road))
        for name in names:
            values.setdefault(name, []).append(channels.get(name, np.full(count + 1, np.nan))[1:])
    return (
        np.concatenate(starts),
        np.concatenate(ends),
        np.concatenate(widths),
        np.concatenate(roads),
        {name: np.concatenate(parts_) for name, parts_ in values.items()},
        _placement(document, path),
    )


def _channels(entity, count: int, path: Path) -> dict[str, np.ndarray]:
    """The per-vertex values of the entity's FABKIT extended data."""
    if not entity.has_xdata(APP_ID):
        return {}
    out: dict[str, list[float]] = {}
    name = None
    for code, value in entity.get_xdata(APP_ID):
        if code == 1000:
            name = str(value)
            out[name] = []
        elif code == 1040 and name is not None:
            out[name].append(float(value))
    for name, values in out.items():
        if len(values) != count:
            raise FabkitError(
                f"{path}: a {PATHS} polyline has {count} vertices but {len(values)} values "
                f"of {name}"
            )
    return {name: np.array(values) for name, values in out.items()}


def _placement(document, path: Path) -> Placement:
    custom = document.header.custom_vars
    offset, scale = None, None
    if custom.has_tag("fabkit_offset_mm"):
        try:
            values = [float(v) for v in custom.get("fabkit_offset_mm").split(",")]
            offset = (values[0], values[1])
        except (ValueError, IndexError):
            offset = None
    if custom.has_tag("fabkit_mm_per_unit"):
        try:
            scale = float(custom.get("fabkit_mm_per_unit"))
        except ValueError:
            scale = None
    if scale is not None and not (math.isfinite(scale) and scale > 0):
        scale = None
    return Placement(offset, scale, f"{path.name} header")
