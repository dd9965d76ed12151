"""Print order: a raster with alternating direction and short travels.

Lines are chained greedily -- from the current nozzle position, the nearest free line end
(any vertex of a closed loop, which is then rotated to start there) -- and the order is
then improved by 2-opt on the end points: reversing a run of lines (and each line in it)
whenever that shortens the two travels around the run. Parallel lines come out as a
boustrophedon raster.
"""

from __future__ import annotations

import numpy as np

from fabkit.toolpath.lines import is_closed


def order_lines(
    lines: list[np.ndarray], start: np.ndarray | None = None, sweeps: int = 8
) -> list[np.ndarray]:
    """``lines`` ((n, 2) polylines, mm) in print order and direction, from ``start`` (mm)."""
    if not lines:
        return []
    ordered = _nearest_neighbour(lines, np.zeros(2) if start is None else np.asarray(start))
    return _two_opt(ordered, sweeps)


def travel_length(lines: list[np.ndarray]) -> float:
    """Total length (mm) of the straight travels between consecutive lines."""
    if len(lines) < 2:
        return 0.0
    ends = np.array([line[-1] for line in lines[:-1]])
    starts = np.array([line[0] for line in lines[1:]])
    return float(np.linalg.norm(starts - ends, axis=1).sum())


def _nearest_neighbour(lines: list[np.ndarray], position: np.ndarray) -> list[np.ndarray]:
    """Greedy chaining; candidates are both ends of open lines and every vertex of loops."""
    candidates, owner, vertex = [], [], []
    for index, line in enumerate(lines):
        if is_closed(line):
            candidates.append(line[:-1])
            vertex.append(np.arange(len(line) - 1))
        else:
            candidates.append(line[[0, -1]])
            vertex.append(np.array([0, len(line) - 1]))
        owner.append(np.full(len(candidates[-1]), index))
    points, owner, vertex = (np.concatenate(a) for a in (candidates, owner, vertex))
    free = np.ones(len(points), bool)
    ordered = []
    for _ in range(len(lines)):
        distance = np.where(free, np.hypot(*(points - position).T), np.inf)
        best = int(np.argmin(distance))
        line = lines[owner[best]]
        if is_closed(line):
            line = np.vstack([line[vertex[best] : -1], line[: vertex[best] + 1]])
        elif vertex[best] != 0:
            line = line[::-1]
        ordered.append(line)
        free[owner == owner[best]] = False
        position = line[-1]
    return ordered


def _two_opt(lines: list[np.ndarray], sweeps: int) -> list[np.ndarray]:
    """Reverse runs of lines while that shortens the travels (best move per position)."""
    n = len(lines)
    order = np.arange(n)
    flipped = np.zeros(n, bool)
    starts = np.array([line[0] for line in lines])
    ends = np.array([line[-1] for line in lines])
    for _ in range(sweeps):
        improved = False
        for i in range(n - 2):
            j = np.arange(i + 1, n)
            nxt = np.minimum(j + 1, n - 1)
            has_next = j < n - 1
            before = np.linalg.norm(starts[i + 1] - ends[i])
            after = np.where(has_next, np.linalg.norm(starts[nxt] - ends[j], axis=1), 0.0)
            new_first = np.linalg.norm(ends[j] - ends[i], axis=1)
            new_second = np.where(has_next, np.linalg.norm(starts[nxt] - starts[i + 1], axis=1), 0)
            gain = before + after - new_first - new_second
            best = int(np.argmax(gain))
            if gain[best] > 1e-9:
                run = slice(i + 1, j[best] + 1)
                order[run], flipped[run] = order[run][::-1], ~flipped[run][::-1]
                starts[run], ends[run] = ends[run][::-1].copy(), starts[run][::-1].copy()
                improved = True
        if not improved:
            break
    return [lines[k][::-1] if flip else lines[k] for k, flip in zip(order, flipped, strict=True)]
