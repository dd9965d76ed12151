"""The toolpath data model: construction, lengths, and lossless save/load."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from fabkit.errors import FabkitError
from fabkit.toolpath import PRINT, TRAVEL, Layer, Move, Toolpath, load_toolpath, save_toolpath


def _toolpath() -> Toolpath:
    square = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], dtype=float)
    speed = np.array([5, 10, 15, 20.0])
    channels = {"print_speed_mm_s": speed, "ink_fraction": np.array([0.0, 0.25, 0.5, 1.0])}
    first = Move.make(PRINT, square, 0.2, 0.4, speed, 1.0, channels)
    nothing = {"print_speed_mm_s": np.nan, "ink_fraction": np.nan}
    travel = Move.make(TRAVEL, [[0, 10], [0, 20]], 0.2, 0.0, 100.0, 0.0, nothing)
    second = Move.make(PRINT, [[0, 20], [5, 20]], 0.4, 0.4, 10.0, 1.0, nothing)
    layers = (Layer(0.2, 0.2, (first, travel)), Layer(0.4, 0.2, (second,)))
    named = {"print_speed_mm_s": "eps1", "ink_fraction": "eps2"}
    return Toolpath(layers, named, {"source": "test", "w": 0.4})


def test_lengths_duration_and_bounds():
    toolpath = _toolpath()
    assert toolpath.print_length_mm == pytest.approx(35.0)
    assert toolpath.travel_length_mm == pytest.approx(10.0)
    # segment k uses the speed of its end vertex: 10/10 + 10/15 + 10/20 + 10/100 + 5/10
    assert toolpath.duration_s == pytest.approx(1 + 10 / 15 + 0.5 + 0.1 + 0.5)
    low, high = toolpath.bounds()
    assert low.tolist() == [0, 0, 0.2] and high.tolist() == [10, 20, 0.4]


@pytest.mark.parametrize("suffix", [".npz", ".json"])
def test_save_load_round_trip(tmp_path, suffix):
    toolpath = _toolpath()
    path = tmp_path / f"tp{suffix}"
    save_toolpath(toolpath, path)
    back = load_toolpath(path)
    assert back.channels == toolpath.channels and dict(back.meta) == dict(toolpath.meta)
    assert list(back.channels) == ["print_speed_mm_s", "ink_fraction"]  # order kept
    assert [len(layer.moves) for layer in back.layers] == [2, 1]
    for (i, a), (j, b) in zip(toolpath.moves(), back.moves(), strict=True):
        assert i == j and a.kind == b.kind
        np.testing.assert_array_equal(a.xyz, b.xyz)
        for name in ("width", "speed", "flow"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        for name in toolpath.channels:
            np.testing.assert_array_equal(a.channels[name], b.channels[name])
    assert math.isnan(back.layers[1].moves[0].channels["ink_fraction"][0])


def _format_one(toolpath: Toolpath) -> dict[str, np.ndarray]:
    """``toolpath`` as a format-1 file held it: one parameter and its values."""
    moves = [m for _, m in toolpath.moves()]
    counts = [len(m.xyz) for m in moves]
    return {
        "format": np.array("fabkit-toolpath/1"),
        "parameter": np.array("print_speed_mm_s"),
        "meta": np.array(json.dumps(dict(toolpath.meta))),
        "layer_z": np.array([layer.z_mm for layer in toolpath.layers]),
        "layer_height": np.array([layer.height_mm for layer in toolpath.layers]),
        "move_start": np.concatenate([[0], np.cumsum(counts)]),
        "move_kind": np.array([0 if m.kind == PRINT else 1 for m in moves], dtype=np.int8),
        "move_layer": np.array([i for i, _ in toolpath.moves()], dtype=np.int32),
        "xyz": np.concatenate([m.xyz for m in moves]),
        **{
            name: np.concatenate([getattr(m, name) for m in moves])
            for name in ("width", "speed", "flow")
        },
        "value": np.concatenate([m.channels["print_speed_mm_s"] for m in moves]),
    }


def test_format_one_files_are_read_as_one_channel(tmp_path):
    toolpath = _toolpath()
    path = tmp_path / "old.npz"
    np.savez(path, **_format_one(toolpath))
    back = load_toolpath(path)
    assert back.channels == {"print_speed_mm_s": ""}
    first = back.layers[0].moves[0]
    np.testing.assert_array_equal(first.channels["print_speed_mm_s"], [5, 10, 15, 20])


def test_bad_files_are_one_line_errors(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"format": "other"}))
    with pytest.raises(FabkitError, match="not a toolpath file"):
        load_toolpath(bad)
    broken = tmp_path / "broken.npz"
    broken.write_bytes(b"not a zip")
    with pytest.raises(FabkitError, match="broken.npz"):
        load_toolpath(broken)
    with pytest.raises(FabkitError, match="does not exist"):
        load_toolpath(tmp_path / "missing.npz")
    with pytest.raises(FabkitError, match="suffix"):
        save_toolpath(_toolpath(), tmp_path / "tp.txt")


def test_invalid_moves_are_refused():
    with pytest.raises(FabkitError, match="kind"):
        Move.make("jump", [[0, 0], [1, 0]], 0, 0.4, 10)
    with pytest.raises(FabkitError, match="vertices"):
        Move.make(PRINT, [[0, 0]], 0, 0.4, 10)
    with pytest.raises(FabkitError, match="non-finite"):
        Move.make(PRINT, [[0, 0], [np.nan, 0]], 0, 0.4, 10)
    with pytest.raises(FabkitError, match="channel 'colour' is not a parameter"):
        Toolpath((), {"colour": "eps"})
    plain = Move.make(PRINT, [[0, 0], [1, 0]], 0, 0.4, 10)
    with pytest.raises(FabkitError, match="has channels none"):
        Toolpath((Layer(0.2, 0.2, (plain,)),), {"print_speed_mm_s": "eps"})
