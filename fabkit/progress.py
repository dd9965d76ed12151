"""Progress of long jobs on stderr: a redrawn bar on a terminal, plain lines when asked.

The rule, the same for every command that can take more than a few seconds (``solve``,
``simulate``, ``verify``, ``swimmer``; ``run`` prints its stages on stdout and shows its
solve's bar): progress goes to stderr only, never stdout, so a command's output is the
same whether it is watched or piped. On a terminal it is shown by default, a bar redrawn
in place. Where stderr is not a terminal (a pipe, a log file, the test suite) nothing is
shown unless the command's ``--progress`` asks for it; then it is written as plain
lines, one per tenth of the job (no carriage returns in a log).
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from typing import TextIO

STEPS = 10
"""Lines a job writes when stderr is not a terminal (one per tenth, and the end)."""


class ProgressBar:
    """``bar(done, total)`` shows ``label [#####.....] 50% ETA 3 s``; ``bar.close()`` ends it.

    Shown when ``stream`` (default stderr) is a terminal, or when ``force`` is true (the
    ``--progress`` option), as plain lines then if it is not a terminal. The clock (elapsed
    time, ETA) starts when the bar is made, or when the bar ``after`` (the stage before,
    made at the same time) finished. ``eta_s(done, elapsed_s)`` gives the seconds left
    (default: the rate so far); on a terminal the bar is redrawn at most every
    ``interval_s``. A call may add a ``detail`` (where the job is, what it waits for).
    """

    def __init__(
        self,
        label: str,
        stream: TextIO | None = None,
        width: int = 30,
        force: bool = False,
        after: ProgressBar | None = None,
        eta_s: Callable[[int, float], float] | None = None,
        interval_s: float = 0.0,
    ):
        self.label, self.width = label, width
        self.stream = stream if stream is not None else sys.stderr
        self.terminal = self.stream.isatty()
        self.enabled = self.terminal or force
        self.made = time.perf_counter()
        self.after = after
        self.eta_s = eta_s
        self.interval_s = interval_s
        self.finished: float | None = None
        self.drawn = False
        self.last_step = self.last_done = -1
        self.last_draw = -math.inf

    @property
    def started(self) -> float:
        """When this bar's job started (perf_counter s)."""
        before = self.after.finished if self.after is not None else None
        return max(self.made, before) if before is not None else self.made

    def due(self, done: int, total: int, force: bool = False) -> bool:
        """Whether ``bar(done, total, force=force)`` writes anything now: a caller called
        for every line of a job makes its ``detail`` only then."""
        if not self.enabled or total <= 0:
            return False
        fraction = min(done / total, 1.0)
        if self.terminal:
            quiet = time.perf_counter() - self.last_draw < self.interval_s
            return not (quiet and fraction < 1 and not force)
        step = int(fraction * STEPS)
        return not ((step == self.last_step and not force) or (force and done == self.last_done))

    def __call__(self, done: int, total: int, detail: str = "", force: bool = False) -> None:
        """Show ``done`` of ``total`` (``force``: now, whatever the interval or step)."""
        if not self.enabled or total <= 0:
            return
        fraction = min(done / total, 1.0)
        now = time.perf_counter()
        if fraction >= 1 and self.finished is None:
            self.finished = now
        if not self.due(done, total, force):
            return  # the ETA is worked out only for what is written
        elapsed = now - self.started
        eta = self._eta(done, fraction, elapsed)
        tail = f"  {detail}" if detail else ""
        if self.terminal:
            self.last_draw = now
            filled = int(round(self.width * fraction))
            bar = "#" * filled + "." * (self.width - filled)
            self.stream.write(
                f"\r{self.label} [{bar}] {100 * fraction:3.0f}% ETA {seconds(eta)}{tail}\x1b[K"
            )
            self.drawn = fraction < 1
            if not self.drawn:  # done: the next bar starts on a line of its own
                self.stream.write("\n")
        else:
            self.last_step, self.last_done = int(fraction * STEPS), done
            self.stream.write(
                f"{self.label}: {done}/{total} ({100 * fraction:.0f}%), "
                f"{elapsed:.0f} s, ETA {seconds(eta)}{tail}\n"
            )
        self.stream.flush()

    def _eta(self, done: int, fraction: float, elapsed: float) -> float:
        if self.eta_s is not None:
            return self.eta_s(done, elapsed)
        return elapsed * (1 - fraction) / fraction if fraction > 0 else math.nan

    def close(self) -> None:
        if self.drawn:
            self.stream.write("\n")
            self.stream.flush()
            self.drawn = False


def seconds(value: float) -> str:
    """A time left: ``42 s`` under two minutes, else ``h:mm:ss`` (``? s`` unknown)."""
    if not math.isfinite(value):
        return "? s"
    return f"{value:.0f} s" if value < 120 else clock(value)


def clock(seconds: float) -> str:
    """``h:mm:ss``."""
    whole = int(round(seconds))
    return f"{whole // 3600}:{whole // 60 % 60:02d}:{whole % 60:02d}"


def add_progress(parser) -> None:
    """The ``--progress`` option of a command that can take more than a few seconds."""
    parser.add_argument(
        "--progress",
        action="store_true",
        help="show progress on stderr even when it is not a terminal (plain lines, one "
        "per tenth; on a terminal a bar is always shown)",
    )
