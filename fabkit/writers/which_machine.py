"""Which machine a machine file is for: one rule for every command.

``--machine`` when given; else the machine the file names (the header a fabkit G-code file
starts with, ``;Generated with fabkit 0.1.0 for machine NAME``, or a laser pattern
folder's ``manifest.json``); else the command's default: the link's for ``fabkit send``
(a ``sim://grbl`` port drives a GRBL machine), the laser cutter for baromorph channels,
:data:`~fabkit.machines.DEFAULT_MACHINE` otherwise. ``fabkit run`` writes its file itself,
so its machine is its ``--machine`` or its default.

A ``--machine`` the file's header contradicts is refused unless ``force`` (``fabkit send
--force``: streaming a file to a machine it was not written for moves that machine in
ways nobody checked); ``fabkit verify`` reads a file as the machine asked for reads it,
and says so in its notes.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from fabkit.errors import FabkitError
from fabkit.files.readfile import read_json
from fabkit.machines import MachineProfile, load_machine

_HEADER = re.compile(r";\s*Generated with fabkit \S+ for machine (\S+)")
HEADER_LINES = 40
"""The header is within the first lines of a fabkit G-code file."""


def named_machine(path: str | Path) -> str | None:
    """The machine the file at ``path`` names: a G-code header's, a laser pattern folder's
    manifest's; None when it names none (or cannot be read: the caller reports that)."""
    path = Path(path)
    if path.is_dir():
        manifest = path / "manifest.json"
        if not manifest.is_file():
            return None
        data = read_json(manifest, "laser manifest")
        name = data.get("machine") if isinstance(data, dict) else None
        return name if isinstance(name, str) and name else None
    try:
        with open(path, encoding="ascii", errors="replace") as handle:
            for _, line in zip(range(HEADER_LINES), handle, strict=False):
                match = _HEADER.match(line.strip())
                if match:
                    return match.group(1)
    except OSError:
        return None
    return None


@dataclass(frozen=True)
class MachineChoice:
    """The ``profile`` chosen for a machine file, one line saying which and why
    (``note``), and the machine the file ``named`` (None: none)."""

    profile: MachineProfile
    note: str
    named: str | None

    @property
    def against_the_file(self) -> bool:
        """The file names another machine than the one chosen (``--force``)."""
        return self.named is not None and self.named != self.profile.name


def choose_machine(
    path: str | Path,
    requested: str | MachineProfile | None,
    default: str | None,
    *,
    force: bool = False,
) -> MachineChoice:
    """The profile for the machine file ``path`` (module docstring). ``requested``:
    ``--machine`` (a name, a .toml path or a profile loaded already); ``default``: the
    command's, None when there is none (a FabkitError asks for ``--machine``); ``force``:
    take a ``requested`` machine the header contradicts (else a FabkitError)."""
    named = named_machine(path)
    if requested is None:
        if named is not None:
            where = "its manifest" if Path(path).is_dir() else "the header"
            note = f"machine {named} (named in {where} of {path})"
            return MachineChoice(load_machine(named), note, named)
        if default is None:
            raise FabkitError(f"{path}: names no machine; give --machine")
        note = f"machine {default} (the default: {path} names no machine in its header)"
        return MachineChoice(load_machine(default), note, None)
    profile = requested if isinstance(requested, MachineProfile) else load_machine(requested)
    choice = MachineChoice(profile, f"machine {profile.name} (--machine)", named)
    if not choice.against_the_file:
        return choice
    if not force:
        raise FabkitError(
            f"{path} was written for machine {named} (its header), not {profile.name}: "
            f"send it with --machine {named}, or add --force"
        )
    return MachineChoice(
        profile, f"machine {profile.name} (--force: the header names {named})", named
    )
