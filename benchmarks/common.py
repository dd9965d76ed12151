"""What the timing benchmark scripts share: their command line, and timing repeated calls
of one function.

Every time is taken both as wall time and as CPU time of this process
(``time.process_time``): on a machine shared with other jobs the second moves less with
their load.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any


def timing_arguments(doc: str, repeat: int) -> argparse.ArgumentParser:
    """A timing benchmark's command line: described by the first line of its docstring
    ``doc``, with ``--repeat N``, the calls per timed figure (``repeat`` by default)."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument(
        "--repeat", type=int, default=repeat, help=f"calls per timed figure (default {repeat})"
    )
    return parser


@dataclass(frozen=True)
class Runs:
    """``len(wall)`` calls of one function: the last call's ``result`` and each call's
    ``wall`` and ``cpu`` time, s, in the order they ran."""

    result: Any
    wall: tuple[float, ...]
    cpu: tuple[float, ...]

    @property
    def best(self) -> float:
        """The shortest wall time, s."""
        return min(self.wall)

    @property
    def median(self) -> float:
        """The median wall time, s."""
        return statistics.median(self.wall)

    @property
    def best_cpu(self) -> float:
        """The shortest CPU time, s."""
        return min(self.cpu)


def repeat_runs(function: Callable[[], Any], repeat: int = 1) -> Runs:
    """Call ``function()`` ``repeat`` times in turn, timing each call."""
    result, walls, cpus = None, [], []
    for _ in range(repeat):
        wall, cpu = time.perf_counter(), time.process_time()
        result = function()
        walls.append(time.perf_counter() - wall)
        cpus.append(time.process_time() - cpu)
    return Runs(result, tuple(walls), tuple(cpus))
