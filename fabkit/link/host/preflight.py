"""Check a job against a machine profile before a single byte is sent.

:func:`check_job` reads every command as the machine's firmware will
(:func:`~fabkit.gcode.read.read_grbl` for GRBL, :func:`~fabkit.gcode.read.read_marlin`
for Marlin, Klipper, RepRapFirmware and Hyrel), follows the firmware's modal state in
machine coordinates (:mod:`~fabkit.link.host.preflight_grbl`,
:mod:`~fabkit.link.host.preflight_marlin`, :mod:`~fabkit.link.host.tracker`) and refuses
the job at the first problem with one line naming the file line: a position outside the
envelope (arcs through their extreme points, probes, homing's intermediate points), a
feed or axis speed above the profile's limits (after G93 inverse time and M220/M221
overrides), a temperature above the maximum, a line the link cannot send or the firmware
reads differently from the check, an unknown command, and any command that can move or
heat but that the check cannot follow (``... cannot be checked: <why>``).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from fabkit.errors import FabkitError
from fabkit.gcode.columns import MoveRun, job_spans, plain_codes
from fabkit.gcode.read import (
    Block,
    Command,
    GcodeError,
    extra_axes,
    firmware_reader,
    job_texts,
    strip_comment,
)
from fabkit.link.host.preflight_columns import MarlinRuns, switch_code
from fabkit.link.host.preflight_grbl import GrblDialect
from fabkit.link.host.preflight_marlin import MarlinDialect
from fabkit.link.host.tracker import Tracker
from fabkit.machines import GCODE_KEYS, MachineProfile

MAX_MARLIN_CHARS = 80  # Marlin keeps 95 characters, of which "N<n> " and "*<xor>" take some
MAX_GRBL_CHARS = 79  # GRBL's line buffer is 80 bytes
_CONTROL = re.compile(r"[^\x20-\x7e]")


@dataclass(frozen=True)
class JobCheck:
    """The outcome of a successful check (mm, s)."""

    source: str
    machine: str
    commands: int
    moves: int
    bounds_mm: tuple[tuple[float, float] | None, ...]

    def summary(self) -> str:
        """A few lines for the user."""
        spans = "  ".join(
            f"{axis} {lo:.3f}..{hi:.3f}" if span else f"{axis} -"
            for axis, span in zip("XYZ", self.bounds_mm, strict=True)
            for lo, hi in [span or (0.0, 0.0)]
        )
        return "\n".join(
            [
                f"{self.source}: {self.commands} commands, {self.moves} moves fit machine "
                f"{self.machine}",
                f"positions (mm): {spans}",
            ]
        )


def _normal(text: str) -> str:
    return " ".join(text.upper().split())


class _Checker:
    """One job on one machine: text rules, the firmware reader, flow, the dialect."""

    def __init__(self, machine: MachineProfile) -> None:
        if machine.gcode is None or machine.serial is None:
            raise FabkitError(f"machine {machine.name} has flavour none and takes no G-code")
        self.machine = machine
        self.grbl = machine.flavour == "grbl"
        self.read = firmware_reader(machine)  # text -> Block, as the firmware reads it
        self.tracker = Tracker(machine)
        snippets = {key: self._snippet(key) for key in GCODE_KEYS}
        self.flow_on_codes = {code for line in snippets["flow_on_gcode"] for code in line.codes}
        self.flow_off = [line for line in snippets["flow_off_gcode"] if line.codes]
        self.ink2_on = [line for line in snippets["ink2_on_gcode"] if line.codes]
        self.ink2_off = [line for line in snippets["ink2_off_gcode"] if line.codes]
        self.inks_on = [False, False]  # the first ink (flow on/off), the second (ink2 on/off)
        if self.grbl:
            self.dialect: GrblDialect | MarlinDialect = GrblDialect(
                self.tracker, extra_axes(machine)
            )
        else:
            writes = [b for blocks in snippets.values() for b in blocks if b.codes == ("M42",)]
            trusted = {_normal(line) for key in GCODE_KEYS for line in machine.render(key)}
            self.dialect = MarlinDialect(self.tracker, machine.flavour, writes, trusted)
        self.runs = self._runs()

    def _runs(self) -> MarlinRuns | None:
        """Runs of plain moves (and the profile's own pin writes) checked at once, unless
        GRBL's, or a flow line of the profile is a G0/G1 (then a move may switch the flow,
        which only the per-command path follows)."""
        moves = {"G0", "G1"}
        lines = [*self.flow_off, *self.ink2_on, *self.ink2_off]
        if self.grbl or moves & self.flow_on_codes or any(moves & set(b.codes) for b in lines):
            return None
        assert isinstance(self.dialect, MarlinDialect)
        return MarlinRuns(self.dialect)

    def apply(self, run: MoveRun) -> bool:
        """Check ``run`` at once and apply it (:meth:`MarlinRuns.apply`); False, with
        nothing changed, when the per-command path must take it."""
        if self.runs is None:
            return False
        inks = self.runs.apply(run, self.inks_on)
        if inks is None:
            return False
        self.inks_on = inks
        self.tracker.flow_on = any(inks)
        return True

    def _snippet(self, key: str) -> list[Block]:
        try:
            return [self.read(line) for line in self.machine.render(key)]
        except GcodeError as exc:
            raise FabkitError(f"machine {self.machine.name}: [gcode] {key}: {exc}") from None

    def check(self, text: str) -> Block:
        """Check one command (GcodeError without the file line); the command as the
        firmware reads it."""
        self._check_text(text)
        block = self.read(text)
        if "G20" in block.codes or "G70" in block.codes:
            raise GcodeError("inch units (G20) are not supported: use millimetres (G21)")
        self._flow(block)
        self.dialect.run(text, block)
        if not self.tracker.flow_on:  # the firmware stopped the flow (GRBL's M2, M30)
            self.inks_on = [False, False]
        return block

    def _check_text(self, text: str) -> None:
        limit = MAX_GRBL_CHARS if self.grbl else MAX_MARLIN_CHARS
        if len(text) > limit:
            raise GcodeError(f"command is {len(text)} characters long, the limit is {limit}")
        if _CONTROL.search(text):
            raise GcodeError("control character in command")
        forbidden = "?!~" if self.grbl else "*"
        for char in forbidden:
            if char in text:
                raise GcodeError(f"'{char}' is not allowed in a command ({self.machine.flavour})")
        if not self.grbl and re.match(r"N[-+\d]", text, re.IGNORECASE):
            raise GcodeError("the line already carries a line number: remove N words and checksums")

    def _flow(self, block: Block) -> None:
        """The first ink's flow off when the block holds a flow-off line of the profile, on
        when it shares a command with a flow-on line (a valve, coolant output, spindle or
        laser); a second ink's (the profile's ink2 lines) off and on when the block holds
        one of its lines. Material flows while either flows."""
        switch = self._switch(block)
        if switch is not None:
            ink, on = switch
            self.inks_on[ink] = on
        self.tracker.flow_on = any(self.inks_on)

    def _switch(self, block: Block) -> tuple[int, bool] | None:
        """The ink ``block`` turns on or off (0: the first, 1: the second) and how, or None
        (:meth:`_flow`)."""
        if any(_holds(block, line) for line in self.ink2_off):
            return 1, False
        if any(_holds(block, line) for line in self.ink2_on):
            return 1, True
        if any(_holds(block, line) for line in self.flow_off):
            return 0, False
        if not self.flow_on_codes.isdisjoint(block.codes):
            return 0, True
        return None

    def pin_writes(self) -> dict[str, int]:
        """The texts of the profile's own flow lines that are M42 pin writes (a valve),
        as :class:`~fabkit.link.host.preflight_columns.MarlinRuns` takes them in a run:
        text -> :func:`~fabkit.link.host.preflight_columns.switch_code` of what it does.
        Each is checked here once: a pin write changes nothing but the flow."""
        out = {}
        for key in ("flow_on_gcode", "flow_off_gcode", "ink2_on_gcode", "ink2_off_gcode"):
            for text in map(strip_comment, self.machine.render(key)):
                try:
                    self._check_text(text)
                    block = self.read(text)
                    if block.codes == ("M42",):
                        self.dialect.run(text, block)
                        out[text] = switch_code(self._switch(block))
                except GcodeError:
                    continue  # the per-command path refuses it in a job
        return out


def _holds(block: Block, line: Block) -> bool:
    """``block`` has every command and value word of ``line``."""
    return set(line.codes) <= set(block.codes) and all(
        block.values.get(letter) == value for letter, value in line.values.items()
    )


def check_job(
    job: Sequence[Command],
    machine: MachineProfile,
    source: str = "job",
    also: Callable[[Block], None] | None = None,
    also_run: Callable[[MoveRun], None] | None = None,
    *,
    fast: bool = True,
) -> JobCheck:
    """Walk ``job`` and refuse it (FabkitError naming ``source`` and the file line) at the
    first command the machine must not get; ``also`` gets every command checked, as the
    firmware reads it (the duration's planner: the file is read once).

    On a Marlin-like firmware, runs of plain moves (:mod:`fabkit.gcode.columns`) are
    checked at once (:mod:`fabkit.link.host.preflight_columns`) and handed to
    ``also_run`` instead of ``also`` (without ``also_run`` when ``also`` is given, or with
    ``fast=False``, every command goes through the per-command path); any run not certain
    to pass goes through the per-command path, so that the outcome and every message are
    the per-command path's."""
    checker = _Checker(machine)
    runs = checker.runs if fast and (also is None or also_run is not None) else None
    if runs is None:
        _check_each(checker, job, source, also)
    else:
        codes, switches = plain_codes(machine.flavour), checker.pin_writes()
        for start, stop, run in job_spans(job_texts(job), MAX_MARLIN_CHARS, codes, switches):
            if run is not None and checker.apply(run):
                if also_run is not None:
                    also_run(run)
            else:
                _check_each(checker, job[start:stop], source, also)
    tracker = checker.tracker
    return JobCheck(
        source=source,
        machine=machine.name,
        commands=len(job),
        moves=tracker.moves,
        bounds_mm=tuple(tuple(span) if span else None for span in tracker.bounds),
    )


def _check_each(
    checker: _Checker,
    commands: Sequence[Command],
    source: str,
    also: Callable[[Block], None] | None,
) -> None:
    """The per-command path: check each of ``commands`` in turn."""
    for command in commands:
        try:
            block = checker.check(command.text)
        except GcodeError as exc:
            raise FabkitError(f"{source}:{command.file_line}: {exc}") from None
        if also is not None:
            also(block)
