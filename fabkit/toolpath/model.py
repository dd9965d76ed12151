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
import zipfile
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fabkit.atomic import atomic_path
from fabkit.errors import FabkitError
from fabkit.process import PARAMETERS

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
    return np.broadcast_to(np.asarray(values, dtype=float), (count,)).copy()


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
    """Layers of moves, the encoded channels, and JSON-able metadata.

    ``channels`` maps every encoded parameter (one of :data:`fabkit.process.PARAMETERS`)
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
    """Read a toolpath written by :func:`save_toolpath`; a bad file is a one-line error."""
    path = Path(path)
    if not path.is_file():
        raise FabkitError(f"toolpath file '{path}' does not exist")
    try:
        if path.suffix == ".npz":
            with np.load(path, allow_pickle=False) as data:
                return _from_arrays({k: data[k] for k in data.files})
        if path.suffix == ".json":
            return _from_json(json.loads(path.read_text(encoding="utf-8")))
    except FabkitError as exc:
        raise FabkitError(f"{path}: {exc}") from None
    except (OSError, ValueError, KeyError, TypeError, zipfile.BadZipFile, EOFError) as exc:
        raise FabkitError(f"{path}: not a fabkit toolpath ({type(exc).__name__}: {exc})") from None
    raise FabkitError(f"toolpath file '{path}': use a .npz or .json suffix")


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
    tag = str(data.get("format", ""))
    if tag != FORMAT and tag not in OLD_FORMATS:
        raise FabkitError(f"not a toolpath file of format {FORMAT}")
    if tag == FORMAT:
        channels = dict(_channel_pairs(json.loads(str(data["channels"]))))
        vertex_channels = {name: data[_CHANNEL_KEY + name] for name in channels}
    else:  # format 1: one parameter, its values in "value"
        parameter = str(data["parameter"])
        channels = {parameter: ""} if parameter else {}
        vertex_channels = {parameter: data["value"]} if parameter else {}
    start, kinds, owners = data["move_start"], data["move_kind"], data["move_layer"]
    n_layers = len(data["layer_z"])
    if len(start) != len(kinds) + 1 or len(owners) != len(kinds) or start[-1] != len(data["xyz"]):
        raise FabkitError("move index arrays do not match the vertex arrays")
    if len(kinds) and (owners.min() < 0 or owners.max() >= n_layers or kinds.max() >= 2):
        raise FabkitError("a move refers to a missing layer or an unknown kind")
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
    return Toolpath(layers, channels, json.loads(str(data["meta"])))


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
    return Toolpath(tuple(layers), channels, table["meta"])
