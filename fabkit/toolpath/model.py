"""The toolpath data model: plain data, independent of any output format.

A :class:`Toolpath` is a tuple of :class:`Layer` s; a layer is the ordered tuple of its
:class:`Move` s (print moves and the travels between them). A move is a polyline with
per-vertex data:

=========== ======= ========================================================================
field       shape   meaning
=========== ======= ========================================================================
xyz         (n, 3)  vertex positions, mm (machine-independent: the sheet's frame, z up)
width       (n,)    road width, mm (0 on travels)
speed       (n,)    feed rate, mm/s
flow        (n,)    extrusion multiplier: the volume deposited along a segment is
                    ``length * width * layer height * flow`` (1 = nominal road, 0 on travels)
channels    {name:  one array per encoded process parameter (:attr:`Toolpath.channels`),
            (n,)}   named by the parameter (``print_speed_mm_s``, ``ink_fraction``, ...);
                    NaN on travels
=========== ======= ========================================================================

The channels are the values the process gives each feature of the design (see
:mod:`fabkit.process`); ``speed`` and ``flow`` already hold the print speed and extrusion
multiplier channels where those are encoded. Vertex ``k`` carries the settings of the
segment that *ends* at it (the G-code convention: a move to vertex ``k`` is made with
``speed[k]``, ``flow[k]``, ``width[k]`` and every channel's ``[k]``); vertex 0 carries the
settings at the start of the move. Writers (G-code, DXF, laser) read only this model;
:func:`save_toolpath` / :func:`load_toolpath` store it as ``.npz`` or ``.json`` with the
same content (format ``fabkit-toolpath/2``; files of format 1, with one encoded
``parameter`` and its ``value`` per vertex, are read as one channel).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fabkit.calibration import PARAMETERS
from fabkit.errors import FabkitError
from fabkit.files.atomic import atomic_path
from fabkit.files.npzfile import ArrayHeader, check_magnitude, read_npz
from fabkit.files.readfile import parse_json, read_json
from fabkit.limits import TOOLPATH_LAYERS, TOOLPATH_MOVES, TOOLPATH_VERTICES

FORMAT = "fabkit-toolpath/2"
"""Format tag stored in every saved toolpath."""
OLD_FORMATS = ("fabkit-toolpath/1",)
"""Older tags :func:`load_toolpath` still reads."""

PRINT = "print"
TRAVEL = "travel"
KINDS = (PRINT, TRAVEL)

_VERTEX_FIELDS = ("width", "speed", "flow")
_CHANNEL_KEY = "channel_"
"""Prefix of the per-vertex channel arrays in a ``.npz`` toolpath."""


@dataclass(frozen=True, eq=False)
class Move:
    """One continuous polyline move, printing or travelling (shapes in the module docstring)."""

    kind: str
    xyz: np.ndarray
    width: np.ndarray
    speed: np.ndarray
    flow: np.ndarray
    channels: Mapping[str, np.ndarray] = field(default_factory=dict)

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
            object.__setattr__(self, name, _per_vertex(getattr(self, name), len(xyz)))
        channels = {str(k): _per_vertex(v, len(xyz)) for k, v in self.channels.items()}
        object.__setattr__(self, "channels", channels)

    @classmethod
    def make(
        cls,
        kind: str,
        xy: np.ndarray,
        z: float,
        width: np.ndarray | float,
        speed: np.ndarray | float,
        flow: np.ndarray | float = 1.0,
        channels: Mapping[str, np.ndarray | float] | None = None,
    ) -> Move:
        """A move at height ``z`` (mm) from (n, 2) points; scalars are broadcast to vertices."""
        xy = np.asarray(xy, dtype=float)
        xyz = np.column_stack([xy, np.full(len(xy), float(z))])
        return cls(kind, xyz, width, speed, flow, dict(channels or {}))

    @property
    def length_mm(self) -> float:
        """Polyline length, mm."""
        return float(np.linalg.norm(np.diff(self.xyz, axis=0), axis=1).sum())

    @property
    def duration_s(self) -> float:
        """Time to run the move at its per-segment speeds, s."""
        lengths = np.linalg.norm(np.diff(self.xyz, axis=0), axis=1)
        return float((lengths / np.maximum(self.speed[1:], 1e-9)).sum())


def _per_vertex(values: Any, count: int) -> np.ndarray:
    values = np.asarray(values, dtype=float)
    if values.shape != (count,):  # broadcast_to is slow; skip it when not needed
        values = np.broadcast_to(values, (count,))
    return values.copy()


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
    """Layers of moves, the encoded channels, and JSON-able metadata; every move's vertices
    ``xyz`` (n, 3), widths (n,) in mm, speeds (n,) in mm/s (module docstring).

    ``channels`` maps every encoded parameter (one of :data:`fabkit.calibration.PARAMETERS`)
    to the feature(s) it encodes (``"eps1"``, or ``"eps1+eps2"`` for a joint table; ``""``
    when unknown, as in a format-1 file); every move carries exactly these channels.
    ``meta`` holds provenance (sources, process, scale, ignored features) as plain JSON.
    """

    layers: tuple[Layer, ...]
    channels: Mapping[str, str] = field(default_factory=dict)
    meta: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "channels", dict(self.channels))
        for name in self.channels:
            if name not in PARAMETERS:
                raise FabkitError(
                    f"toolpath: channel '{name}' is not a parameter ({', '.join(PARAMETERS)})"
                )
        wanted = set(self.channels)
        for index, layer in enumerate(self.layers):
            for move in layer.moves:
                if set(move.channels) != wanted:
                    raise FabkitError(
                        f"toolpath: a move of layer {index} has channels "
                        f"{sorted(move.channels) or 'none'}, the toolpath "
                        f"{sorted(wanted) or 'none'}"
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
    read (:mod:`fabkit.files.npzfile`; at most TOOLPATH_MOVES moves, TOOLPATH_VERTICES vertices,
    TOOLPATH_LAYERS layers); a ``.json`` is at most JSON_BYTES and NESTING_DEPTH deep.
    Coordinates, widths, speeds and flows must be finite, and every number (channels
    included) within +-MAGNITUDE. Files of format 1 are read with their one ``parameter``
    as a channel.
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


_INDEX_KEYS = ("move_start", "move_kind", "move_layer")
_BASE_KEYS = ("format", "meta", "layer_z", "layer_height", *_INDEX_KEYS, "xyz", *_VERTEX_FIELDS)
_TEXT_KEYS = ("format", "meta", "channels", "parameter")
_OLD_KEYS = ("parameter", "value")
"""Format 1's arrays beyond the base ones: the one encoded parameter and its values."""


def _check_keys(found: set[str], path: Path) -> None:
    """Refuse a file that is not a toolpath from its member names alone: the base arrays,
    then ``channels`` and one ``channel_<parameter>`` array per channel (format 2), or
    ``parameter`` and ``value`` (format 1)."""
    if "format" not in found:
        raise FabkitError(f"{path}: not a toolpath file of format {FORMAT}")
    if "channels" in found or "parameter" not in found:  # format 2
        extra: tuple[str, ...] = ("channels",)
        named = {key for key in found if key.removeprefix(_CHANNEL_KEY) in PARAMETERS}
        channel_arrays = {key for key in named if key.startswith(_CHANNEL_KEY)}
    else:  # format 1
        extra, channel_arrays = _OLD_KEYS, set()
    missing = [key for key in (*_BASE_KEYS, *extra) if key not in found]
    unknown = sorted(found - {*_BASE_KEYS, *extra} - channel_arrays)
    if missing or unknown:
        which = f"no '{missing[0]}' array" if missing else f"unknown array '{unknown[0]}'"
        raise FabkitError(f"{path}: not a toolpath file of format {FORMAT} ({which})")


def _check_headers(headers: Mapping[str, ArrayHeader], path: Path) -> None:
    """Refuse a toolpath .npz from its array headers: index dtypes, shapes, counts."""
    for key in _INDEX_KEYS:
        if headers[key].dtype.kind not in "iu":
            raise FabkitError(f"{path}: '{key}' holds {headers[key].dtype} values, not integers")
    shapes = {key: header.shape for key, header in headers.items()}
    # a 0-d array counts -1 items, so that no expected shape matches it
    layers, moves, vertices = (
        shapes[key][0] if shapes[key] else -1 for key in ("layer_z", "move_kind", "xyz")
    )
    per_vertex = [key for key in shapes if key.startswith(_CHANNEL_KEY) or key == "value"]
    expected = {
        "layer_z": (layers,),
        "layer_height": (layers,),
        "move_start": (moves + 1,),
        "move_kind": (moves,),
        "move_layer": (moves,),
        "xyz": (vertices, 3),
        **{name: (vertices,) for name in (*_VERTEX_FIELDS, *per_vertex)},
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
        "channels": np.array(json.dumps(list(toolpath.channels.items()))),
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
    for name in toolpath.channels:
        parts = [m.channels[name] for _, m in moves]
        arrays[_CHANNEL_KEY + name] = np.concatenate(parts) if parts else np.zeros(0)
    return arrays


def _from_arrays(data: Mapping[str, np.ndarray]) -> Toolpath:
    """The toolpath of checked arrays (:func:`_check_headers`); values checked here."""
    tag = str(data["format"])
    if tag != FORMAT and tag not in OLD_FORMATS:
        raise FabkitError(f"not a toolpath file of format {FORMAT}")
    if "channels" in data:
        if tag != FORMAT:
            raise FabkitError(f"a file of format {tag} holds no channels")
        channels = dict(_channel_pairs(parse_json(str(data["channels"]), "channels")))
        present = {key.removeprefix(_CHANNEL_KEY) for key in data if key.startswith(_CHANNEL_KEY)}
        if present != set(channels):
            raise FabkitError("the channel arrays do not match the channels listed")
        vertex_channels = {name: data[_CHANNEL_KEY + name] for name in channels}
    else:  # format 1: one parameter, its values in "value"
        if tag == FORMAT:
            raise FabkitError("no 'channels' array")
        parameter = str(data["parameter"])
        channels = {parameter: ""} if parameter else {}
        vertex_channels = {parameter: data["value"]} if parameter else {}
    start, kinds, owners = (data[key].astype(np.int64) for key in _INDEX_KEYS)
    n_layers = len(data["layer_z"])
    steps = np.diff(start)
    if len(start) == 0 or start[0] != 0 or start[-1] != len(data["xyz"]) or (steps < 2).any():
        raise FabkitError("move index arrays do not match the vertex arrays")
    if len(kinds) and (owners.min() < 0 or owners.max() >= n_layers or kinds.min() < 0):
        raise FabkitError("a move refers to a missing layer or an unknown kind")
    if len(kinds) and kinds.max() >= len(KINDS):
        raise FabkitError("a move refers to a missing layer or an unknown kind")
    for key in ("layer_z", "layer_height", "xyz", *_VERTEX_FIELDS):
        values = data[key].astype(float)
        if not np.isfinite(values).all():
            raise FabkitError(f"'{key}' has non-finite values")
        check_magnitude(values, key)
    for name, values in vertex_channels.items():
        check_magnitude(values.astype(float), name)
    meta = parse_json(str(data["meta"]), "meta")
    if not isinstance(meta, dict):
        raise FabkitError("meta: expected a JSON object")
    per_layer: list[list[Move]] = [[] for _ in range(n_layers)]
    for k, (a, b) in enumerate(zip(start[:-1], start[1:], strict=True)):
        fields = {name: data[name][a:b] for name in _VERTEX_FIELDS}
        values = {name: array[a:b] for name, array in vertex_channels.items()}
        per_layer[owners[k]].append(
            Move(KINDS[kinds[k]], data["xyz"][a:b], **fields, channels=values)
        )
    layers = tuple(
        Layer(float(z), float(h), tuple(moves))
        for z, h, moves in zip(data["layer_z"], data["layer_height"], per_layer, strict=True)
    )
    return Toolpath(layers, channels, meta)


def _channel_pairs(pairs: Any) -> list[tuple[str, str]]:
    """The ``[[parameter, features], ...]`` list of a saved toolpath, checked."""
    if not isinstance(pairs, list) or not all(
        isinstance(p, list) and len(p) == 2 and all(isinstance(x, str) for x in p) for p in pairs
    ):
        raise FabkitError("channels must be a list of [parameter, features] pairs")
    return [(p[0], p[1]) for p in pairs]


def _to_json(toolpath: Toolpath) -> dict[str, Any]:
    def listed(values: np.ndarray) -> list[float | None]:
        return [None if math.isnan(v) else float(v) for v in values]

    return {
        "format": FORMAT,
        "channels": [list(pair) for pair in toolpath.channels.items()],
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
                        "channels": {name: listed(v) for name, v in m.channels.items()},
                    }
                    for m in layer.moves
                ],
            }
            for layer in toolpath.layers
        ],
    }


def _from_json(table: Mapping[str, Any]) -> Toolpath:
    tag = table.get("format")
    if tag != FORMAT and tag not in OLD_FORMATS:
        raise FabkitError(f"not a toolpath file of format {FORMAT}")

    def array(values: list[float | None]) -> np.ndarray:
        return np.array([math.nan if v is None else v for v in values], dtype=float)

    if tag == FORMAT:
        channels = dict(_channel_pairs(table["channels"]))
    else:
        channels = {table["parameter"]: ""} if table["parameter"] else {}

    def move_channels(m: Mapping[str, Any]) -> dict[str, np.ndarray]:
        if tag == FORMAT:
            return {name: array(values) for name, values in m["channels"].items()}
        return {name: array(m["value"]) for name in channels}

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
                channels=move_channels(m),
            )
            for m in layer["moves"]
        )
        layers.append(Layer(float(layer["z_mm"]), float(layer["height_mm"]), moves))
    toolpath = Toolpath(tuple(layers), channels, dict(table["meta"]))
    _check_values(toolpath)
    return toolpath


def _check_values(toolpath: Toolpath) -> None:
    """Finite widths, speeds and flows, and every number (channels included) within
    +-MAGNITUDE."""
    layers = np.array([(layer.z_mm, layer.height_mm) for layer in toolpath.layers], float)
    if not np.isfinite(layers).all():
        raise FabkitError("layer heights must be finite")
    check_magnitude(layers, "layers")
    for _, move in toolpath.moves():
        for name in ("xyz", *_VERTEX_FIELDS):
            values = getattr(move, name)
            if not np.isfinite(values).all():
                raise FabkitError(f"'{name}' has non-finite values")
            check_magnitude(values, name)
        for name, values in move.channels.items():
            check_magnitude(values, name)
