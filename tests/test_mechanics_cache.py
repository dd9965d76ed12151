"""Simulations kept by everything they depend on: a hit is the computed result, bit for bit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fabkit.mechanics import cache
from fabkit.mechanics.simulate import Settings, simulate
from fabkit.mechanics.verdict import design_verdict
from tests.conftest import coarse_design


@pytest.fixture
def fresh(tmp_path, monkeypatch):
    monkeypatch.setenv(cache.CACHE_ENV, str(tmp_path / "cache"))
    return tmp_path / "cache"


def square() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A small square sheet whose metric grows across it: it must buckle."""
    x, y = np.meshgrid(np.linspace(0, 1, 7), np.linspace(0, 1, 7))
    points = np.column_stack([x.ravel(), y.ravel()])
    cells = [(i * 7 + j, i * 7 + j + 1, i * 7 + j + 8) for i in range(6) for j in range(6)]
    cells += [(i * 7 + j, i * 7 + j + 8, i * 7 + j + 7) for i in range(6) for j in range(6)]
    triangles = np.array(cells)
    metrics = np.broadcast_to(np.diag([1.1, 1.0]), (len(triangles), 2, 2)).copy()
    return points, triangles, metrics


def test_a_verdict_read_back_is_the_verdict_computed(fresh):
    design = coarse_design()
    computed = design_verdict(design)
    assert len(list(fresh.glob("*.npz"))) == 8  # 2 targets x 4 starts (2 more reflected)
    kept = design_verdict(design)
    assert [s.starts for s in kept.shapes] == [s.starts for s in computed.shapes]
    assert kept.lines() == computed.lines()


def test_every_input_and_the_start_change_the_key():
    points, triangles, metrics = square()
    base = (points, triangles, metrics, 0.01, 0.5, Settings(), None)
    name = cache.simulation_key(*base)
    changed = [
        (points + 1e-12, triangles, metrics, 0.01, 0.5, Settings(), None),
        (points, triangles[::-1], metrics, 0.01, 0.5, Settings(), None),
        (points, triangles, metrics * (1 + 1e-15), 0.01, 0.5, Settings(), None),
        (points, triangles, metrics, 0.0100001, 0.5, Settings(), None),
        (points, triangles, metrics, 0.01, 0.4, Settings(), None),
        (points, triangles, metrics, 0.01, 0.5, Settings(seed="dome-down"), None),
        (points, triangles, metrics, 0.01, 0.5, Settings(tolerance=1e-7), None),
        (points, triangles, metrics, 0.01, 0.5, Settings(), metrics),
    ]
    assert len({name, *(cache.simulation_key(*args) for args in changed)}) == 1 + len(changed)
    assert cache.simulation_key(*base) == name


def test_a_result_round_trips_and_a_broken_one_is_computed_again(fresh):
    points, triangles, metrics = square()
    result = simulate(points, triangles, metrics, 0.01)
    name = cache.simulation_key(points, triangles, metrics, 0.01, 0.5, Settings(), None)
    cache.store(name, result)
    back = cache.load(name)
    assert np.array_equal(back.positions, result.positions)
    assert dataclasses.astuple(back)[1:] == dataclasses.astuple(result)[1:]
    (fresh / f"{name}.npz").write_bytes(b"not a zip")
    assert cache.load(name) is None


def test_off_keeps_nothing_and_an_unwritable_folder_stops_nothing(tmp_path, monkeypatch):
    points, triangles, metrics = square()
    result = simulate(points, triangles, metrics, 0.01)
    monkeypatch.setenv(cache.CACHE_ENV, "off")
    cache.store("x", result)
    assert cache.load("x") is None
    blocked = tmp_path / "file"
    blocked.write_text("a file where the folder would be")
    monkeypatch.setenv(cache.CACHE_ENV, str(blocked / "cache"))
    cache.store("x", result)  # no error
    assert cache.load("x") is None


def test_the_oldest_results_go_beyond_the_limit(fresh, monkeypatch):
    points, triangles, metrics = square()
    result = simulate(points, triangles, metrics, 0.01)
    monkeypatch.setattr(cache, "KEEP", 3)
    for k in range(5):
        cache.store(f"r{k}", result)
    assert sorted(p.stem for p in fresh.glob("*.npz")) == ["r2", "r3", "r4"]
