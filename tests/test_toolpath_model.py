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
    first = Move.make(PRINT, square, 0.2, 0.4, np.array([5, 10, 15, 20.0]), 1.0, 12.5)
    travel = Move.make(TRAVEL, [[0, 10], [0, 20]], 0.2, 0.0, 100.0, 0.0)
    second = Move.make(PRINT, [[0, 20], [5, 20]], 0.4, 0.4, 10.0)
    layers = (Layer(0.2, 0.2, (first, travel)), Layer(0.4, 0.2, (second,)))
    return Toolpath(layers, "print_speed_mm_s", {"source": "test", "w": 0.4})


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
    assert back.parameter == toolpath.parameter and dict(back.meta) == dict(toolpath.meta)
    assert [len(layer.moves) for layer in back.layers] == [2, 1]
    for (i, a), (j, b) in zip(toolpath.moves(), back.moves(), strict=True):
        assert i == j and a.kind == b.kind
        np.testing.assert_array_equal(a.xyz, b.xyz)
        for name in ("width", "speed", "flow", "value"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert math.isnan(back.layers[1].moves[0].value[0])


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
    with pytest.raises(FabkitError, match="encoded parameter"):
        Toolpath((), "colour")
