"""Print order: boustrophedon rasters, loops entered where convenient, short travels."""

from __future__ import annotations

import numpy as np
import pytest

from fabkit.toolpath.order import order_lines, travel_length


def test_parallel_lines_become_an_alternating_raster():
    rng = np.random.default_rng(3)
    lines = [np.array([[0.0, 0.4 * k], [10.0, 0.4 * k]]) for k in range(30)]
    shuffled = [line[::-1] if rng.random() < 0.5 else line for line in rng.permutation(lines)]
    ordered = order_lines(shuffled, start=np.array([0.0, 0.0]))
    assert travel_length(ordered) == pytest.approx(29 * 0.4)
    directions = np.sign([line[-1, 0] - line[0, 0] for line in ordered])
    assert np.all(directions[:-1] == -directions[1:])


def test_closed_loops_start_near_the_nozzle():
    angle = np.linspace(0, 2 * np.pi, 65)
    loop = np.column_stack([np.cos(angle), np.sin(angle)])
    loop[-1] = loop[0]
    (ordered,) = order_lines([loop], start=np.array([0.0, -1.2]))
    assert ordered[0] == pytest.approx([0.0, -1.0], abs=0.1)
    assert np.array_equal(ordered[0], ordered[-1])


def test_two_opt_never_lengthens_the_greedy_order():
    rng = np.random.default_rng(4)
    lines = [rng.uniform(0, 20, (2, 2)) for _ in range(80)]
    greedy = order_lines(lines, sweeps=0)
    improved = order_lines(lines)
    assert travel_length(improved) <= travel_length(greedy) + 1e-9
    assert sorted(map(len, improved)) == sorted(map(len, lines))
