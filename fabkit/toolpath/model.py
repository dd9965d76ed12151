"""The toolpath data model: plain data, independent of any output format.

A :class:`Toolpath` is a tuple of :class:`Layer` s; a layer is the ordered tuple of its
:class:`Move` s (print moves and the travels between them). A move is a polyline with
per-vertex data:

========= ======= ==========================================================================
field     shape   meaning
========= ======= ==========================================================================
xyz       (n, 3)  vertex positions, mm (machine-independent: the sheet's frame, z up)
width     (n,)    road width, mm (0 on travels)
speed     (n,)    feed rate, mm/s
flow      (n,)    extrusion multiplier: the volume deposited along a segment is
                  ``length * width * layer height * flow`` (1 = nominal road, 0 on travels)
value     (n,)    the encoded process parameter (see :attr:`Toolpath.parameter`); NaN if none
========= ======= ==========================================================================

Vertex ``k`` carries the settings of the segment that *ends* at it (the G-code convention:
a move to vertex ``k`` is made with ``speed[k]``, ``flow[k]``, ``width[k]``, ``value[k]``);
vertex 0 carries the settings at the start of the move. Writers (G-code, DXF, laser) read
only this model; :func:`save_toolpath` / :func:`load_toolpath` store it as ``.npz`` or
``.json`` with the same content.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fabkit.atomic import atomic_path
from fabkit.errors import FabkitError
from fabkit.limits import TOOLPATH_LAYERS, TOOLPATH_MOVES, TOOLPATH_VERTICES
from fabkit.npzfile import ArrayHeader, check_magnitude, read_npz
from fabkit.readfile import parse_json, read_json

FORMAT = "fabkit-toolpath/1"
"""Format tag stored in every saved toolpath."""

PRINT = "print"
TRAVEL = "travel"
KINDS = (PRINT, TRAVEL)
PARAMETERS = ("", "print_speed_mm_s", "extrusion_multiplier", "temperature_c", "line_spacing_mm")
"""Names :attr:`Toolpath.parameter` may take ("" = nothing encoded)."""

_VERTEX_FIELDS = ("width", "speed", "flow", "value")


@dataclass(frozen=True, eq=False)
class Move:
    """One continuous polyline move, printing or travelling (shapes in the module docstring)."""

    kind: str
    xyz: np.ndarray
    width: np.ndarray
    speed: np.ndarray
    flow: np.ndarray
    value: np.ndarray

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise FabkitError(f"toolpath: move kind '{self.kind}' is not one of {KINDS}")
        xyz = np.asarray(self.xyz, dtype=float)
        if xyz.ndim != 2 or xyz.shape[1] != 3 or len(xyz) < 2:
            raise FabkitError(f"toolpath: a move needs (n >= 2, 3) vertices, got {xyz.shape}")
        if not np.isfinite(xyz).all():
            raise FabkitError("toolpath: a move has non-finite coordinates")
        object.__setattr__(self, "xyz", xyz)
        for name in _VERTEX_FIELDS:
            values = np.asarray(getattr(self, name), dtype=float)
            if values.shape != (len(xyz),):  # broadcast_to is slow; skip it when not needed
                values = np.broadcast_to(values, (len(xyz),))
            object.__setattr__(self, name, values.copy())

    @classmethod
    def make(
        cls,
        kind: str,
        xy: np.ndarray,
        z: float,
        width: np.ndarray | float,
        speed: np.ndarray | float,
        flow: np.ndarray | float = 1.0,
        value: np.ndarray | float = math.nan,
    ) -> Move:
        """A move at height ``z`` (mm) from (n, 2) points; scalars are broadcast to vertices."""
        xy = np.asarray(xy, dtype=float)
        xyz = np.column_stack([xy, np.full(len(xy), float(z))])
        return cls(kind, xyz, width, speed, flow, value)

    @property
    def length_mm(self) -> float:
        """Polyline length, mm."""
        return float(np.linalg.norm(np.diff(self.xyz, axis=0), axis=1).sum())

    @property
    def duration_s(self) -> float:
        """Time to run the move at its per-segment speeds, s."""
        lengths = np.linalg.norm(np.diff(self.xyz, axis=0), axis=1)
        return float((lengths / np.maximum(self.speed[1:], 1e-9)).sum())


@dataclass(frozen=True, eq=False)
class Layer:
    """One layer: its nominal height z and thickness (mm) and its moves in machine order."""

    z_mm: float
    height_mm: float
    moves: tuple[Move, ...]

    @property
    def prints(self) -> tuple[Move, ...]:
        return tuple(m for m in self.moves if m.kind == PRINT)


@dataclass(frozen=True, eq=False)
class Toolpath:
    """Layers of moves plus the name of the encoded parameter and JSON-able metadata.

    ``parameter`` is one of :data:`PARAMETERS`: which process parameter ``Move.value``
    holds (``"print_speed_mm_s"`` etc.; ``""`` if nothing is encoded). ``meta`` holds
    provenance (source, machine, process settings, quality report) as plain JSON values.
    """

    layers: tuple[Layer, ...]
    parameter: str = ""
    meta: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.parameter not in PARAMETERS:
            raise FabkitError(
                f"toolpath: encoded parameter '{self.parameter}' is not one of {PARAMETERS[1:]}"
            )

    def moves(self) -> Iterator[tuple[int, Move]]:
        """Every move in machine order, with its layer index."""
        for index, layer in enumerate(self.layers):
            for move in layer.moves:
                yield index, move

    @property
    def print_length_mm(self) -> float:
        return sum(m.length_mm for _, m in self.moves() if m.kind == PRINT)

    @property
    def travel_length_mm(self) -> float:
        return sum(m.length_mm for _, m in self.moves() if m.kind == TRAVEL)

    @property
    def duration_s(self) -> float:
        """Machine time of all moves at their speeds (no acceleration), s."""
        return sum(m.duration_s for _, m in self.moves())

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(min xyz, max xyz) over all vertices, mm."""
        points = np.concatenate([m.xyz for _, m in self.moves()])
        return points.min(axis=0), points.max(axis=0)


def save_toolpath(toolpath: Toolpath, path: str | Path) -> None:
    """Write ``toolpath`` atomically as ``.npz`` (compact) or ``.json`` (readable)."""
    path = Path(path)
    if path.suffix == ".npz":
        arrays = _to_arrays(toolpath)
        with atomic_path(path) as tmp, open(tmp, "wb") as handle:
            np.savez_compressed(handle, **arrays)
    elif path.suffix == ".json":
        with atomic_path(path) as tmp:
            tmp.write_text(json.dumps(_to_json(toolpath), allow_nan=False), encoding="utf-8")
    else:
        raise FabkitError(f"toolpath file '{path}': use a .npz or .json suffix")


def load_toolpath(path: str | Path) -> Toolpath:
    """Read a toolpath written by :func:`save_toolpath`; a bad file is a one-line error.

    An ``.npz`` is checked from its zip directory and array headers before any array is
    read (:mod:`fabkit.npzfile`; at most TOOLPATH_MOVES moves, TOOLPATH_VERTICES vertices,
    TOOLPATH_LAYERS layers); a ``.json`` is at most JSON_BYTES and NESTING_DEPTH deep.
    Coordinates, widths, speeds and flows must be finite and within +-MAGNITUDE.
    """
    path = Path(path)
    if not path.is_file():
        raise FabkitError(f"toolpath file '{path}' does not exist")
    if path.suffix == ".npz":
        where = f"{path}: cannot read toolpath file"
        arrays = read_npz(
            path,
            where,
            text=_TEXT_KEYS,
            keys=lambda found: _check_keys(found, path),
            check=lambda headers: _check_headers(headers, path),
        )
        return _loaded(path, lambda: _from_arrays(arrays))
    if path.suffix == ".json":
        table = read_json(path, "toolpath file")
        return _loaded(path, lambda: _from_json(table))
    raise FabkitError(f"toolpath file '{path}': use a .npz or .json suffix")


def _loaded(path: Path, build: Callable[[], Toolpath]) -> Toolpath:
    """``build()``, its errors one line naming ``path``."""
    try:
        return build()
    except FabkitError as exc:
        raise FabkitError(f"{path}: {exc}") from None
    except (ValueError, KeyError, TypeError, AttributeError, IndexError) as exc:
        raise FabkitError(f"{path}: not a fabkit toolpath ({type(exc).__name__}: {exc})") from None


_TEXT_KEYS = ("format", "parameter", "meta")
_INDEX_KEYS = ("move_start", "move_kind", "move_layer")
_ARRAY_KEYS = (*_TEXT_KEYS, "layer_z", "layer_height", *_INDEX_KEYS, "xyz", *_VERTEX_FIELDS)


def _check_keys(found: set[str], path: Path) -> None:
    """Refuse a file that is not a toolpath from its member names alone."""
    if "format" not in found:
        raise FabkitError(f"{path}: not a toolpath file of format {FORMAT}")
    missing = [key for key in _ARRAY_KEYS if key not in found]
    unknown = sorted(found - set(_ARRAY_KEYS))
    if missing or unknown:
        which = f"no '{missing[0]}' array" if missing else f"unknown array '{unknown[0]}'"
        raise FabkitError(f"{path}: not a toolpath file of format {FORMAT} ({which})")


def _check_headers(headers: Mapping[str, ArrayHeader], path: Path) -> None:
    """Refuse a toolpath .npz from its array headers: index dtypes, shapes, counts."""
    for key in _INDEX_KEYS:
        if headers[key].dtype.kind not in "iu":
            raise FabkitError(f"{path}: '{key}' holds {headers[key].dtype} values, not integers")
    shapes = {key: headers[key].shape for key in _ARRAY_KEYS}
    # a 0-d array counts -1 items, so that no expected shape matches it
    layers, moves, vertices = (
        shapes[key][0] if shapes[key] else -1 for key in ("layer_z", "move_kind", "xyz")
    )
    expected = {
        "layer_z": (layers,),
        "layer_height": (layers,),
        "move_start": (moves + 1,),
        "move_kind": (moves,),
        "move_layer": (moves,),
        "xyz": (vertices, 3),
        **{name: (vertices,) for name in _VERTEX_FIELDS},
    }
    for key, shape in expected.items():
        if shapes[key] != shape:
            raise FabkitError(f"{path}: '{key}' has shape {shapes[key]}, expected {shape}")
    for count, name, limit in (
        (layers, "layers", TOOLPATH_LAYERS),
        (moves, "moves", TOOLPATH_MOVES),
        (vertices, "vertices", TOOLPATH_VERTICES),
    ):
        if count > limit:
            raise FabkitError(f"{path}: {count} {name}, more than the limit of {limit}")


def _to_arrays(toolpath: Toolpath) -> dict[str, np.ndarray]:
    moves = [(i, m) for i, m in toolpath.moves()]
    counts = [len(m.xyz) for _, m in moves]
    arrays = {
        "format": np.array(FORMAT),
        "parameter": np.array(toolpath.parameter),
        "meta": np.array(json.dumps(toolpath.meta)),
        "layer_z": np.array([layer.z_mm for layer in toolpath.layers], dtype=float),
        "layer_height": np.array([layer.height_mm for layer in toolpath.layers], dtype=float),
        "move_start": np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
        "move_kind": np.array([KINDS.index(m.kind) for _, m in moves], dtype=np.int8),
        "move_layer": np.array([i for i, _ in moves], dtype=np.int32),
        "xyz": np.concatenate([m.xyz for _, m in moves]) if moves else np.zeros((0, 3)),
    }
    for name in _VERTEX_FIELDS:
        parts = [getattr(m, name) for _, m in moves]
        arrays[name] = np.concatenate(parts) if parts else np.zeros(0)
    return arrays


def _from_arrays(data: Mapping[str, np.ndarray]) -> Toolpath:
    """The toolpath of checked arrays (:func:`_check_headers`); values checked here."""
    if str(data["format"]) != FORMAT:
        raise FabkitError(f"not a toolpath file of format {FORMAT}")
    start, kinds, owners = (data[key].astype(np.int64) for key in _INDEX_KEYS)
    n_layers = len(data["layer_z"])
    steps = np.diff(start)
    if len(start) == 0 or start[0] != 0 or start[-1] != len(data["xyz"]) or (steps < 2).any():
        raise FabkitError("move index arrays do not match the vertex arrays")
    if len(kinds) and (owners.min() < 0 or owners.max() >= n_layers or kinds.min() < 0):
        raise FabkitError("a move refers to a missing layer or an unknown kind")
    if len(kinds) and kinds.max() >= len(KINDS):
        raise FabkitError("a move refers to a missing layer or an unknown kind")
    for key in ("layer_z", "layer_height", "xyz", "width", "speed", "flow", "value"):
        values = data[key].astype(float)
        if key != "value" and not np.isfinite(values).all():
            raise FabkitError(f"'{key}' has non-finite values")
        check_magnitude(values, key)
    meta = parse_json(str(data["meta"]), "meta")
    if not isinstance(meta, dict):
        raise FabkitError("meta: expected a JSON object")
    per_layer: list[list[Move]] = [[] for _ in range(n_layers)]
    for k, (a, b) in enumerate(zip(start[:-1], start[1:], strict=True)):
        fields = {name: data[name][a:b] for name in _VERTEX_FIELDS}
        per_layer[owners[k]].append(Move(KINDS[kinds[k]], data["xyz"][a:b], **fields))
    layers = tuple(
        Layer(float(z), float(h), tuple(moves))
        for z, h, moves in zip(data["layer_z"], data["layer_height"], per_layer, strict=True)
    )
    return Toolpath(layers, str(data["parameter"]), meta)


def _to_json(toolpath: Toolpath) -> dict[str, Any]:
    def listed(values: np.ndarray) -> list[float | None]:
        return [None if math.isnan(v) else float(v) for v in values]

    return {
        "format": FORMAT,
        "parameter": toolpath.parameter,
        "meta": dict(toolpath.meta),
        "layers": [
            {
                "z_mm": layer.z_mm,
                "height_mm": layer.height_mm,
                "moves": [
                    {
                        "kind": m.kind,
                        "x": m.xyz[:, 0].tolist(),
                        "y": m.xyz[:, 1].tolist(),
                        "z": m.xyz[:, 2].tolist(),
                        **{name: listed(getattr(m, name)) for name in _VERTEX_FIELDS},
                    }
                    for m in layer.moves
                ],
            }
            for layer in toolpath.layers
        ],
    }


def _from_json(table: Mapping[str, Any]) -> Toolpath:
    if table.get("format") != FORMAT:
        raise FabkitError(f"not a toolpath file of format {FORMAT}")

    def array(values: list[float | None]) -> np.ndarray:
        return np.array([math.nan if v is None else v for v in values], dtype=float)

    count = sum(len(layer["moves"]) for layer in table["layers"])
    if count > TOOLPATH_MOVES:
        raise FabkitError(f"{count} moves, more than the limit of {TOOLPATH_MOVES}")
    layers = []
    for layer in table["layers"]:
        moves = tuple(
            Move(
                m["kind"],
                np.column_stack([m["x"], m["y"], m["z"]]).astype(float),
                **{name: array(m[name]) for name in _VERTEX_FIELDS},
            )
            for m in layer["moves"]
        )
        layers.append(Layer(float(layer["z_mm"]), float(layer["height_mm"]), moves))
    toolpath = Toolpath(tuple(layers), table["parameter"], dict(table["meta"]))
    _check_values(toolpath)
    return toolpath


def _check_values(toolpath: Toolpath) -> None:
    """Finite widths, speeds and flows, and every number within +-MAGNITUDE."""
    layers = np.array([(layer.z_mm, layer.height_mm) for layer in toolpath.layers], float)
    if not np.isfinite(layers).all():
        raise FabkitError("layer heights must be finite")
    check_magnitude(layers, "layers")
    for _, move in toolpath.moves():
        for name in ("xyz", *_VERTEX_FIELDS):
            values = getattr(move, name)
            if name != "value" and not np.isfinite(values).all():
                raise FabkitError(f"'{name}' has non-finite values")
            check_magnitude(values, name)
