"""Where the toolpath's process comes from: a machine profile or a ``--process`` file.

The settings and the channels are :class:`fabkit.process.Process` (one type for every
stage). They live in the ``[process]`` table of a machine profile (``machines/*.toml``,
read by :mod:`fabkit.machines`); ``--process FILE`` replaces that table with the one in
FILE, read by :func:`load_process` with the profile's parser
(:func:`fabkit.process.parse_process`, the same keys)::

    [process]
    road_width_mm = 0.4
    layer_height_mm = 0.3
    print_speed_mm_s = 8
    travel_speed_mm_s = 30

    [[process.encode]]             # one table per feature of the design
    feature = "eps1"               # a feature name of the spec, or its position (0 = first)
    parameter = "print_speed_mm_s" # see fabkit.calibration.PARAMETERS
    eps = [0.0, 0.1, 0.2, 0.3]     # strictly increasing
    value = [16.0, 11.0, 7.0, 4.0] # strictly monotone
    clip = false                   # true: clip eps to the table (with a warning)

``[[process.joint]]`` tables encode two features with two parameters that each move
both; the one-feature format's ``[process.calibration]`` table is read as the channel of
the design's first feature (``docs/toolpath.md``).
"""

from __future__ import annotations

from pathlib import Path

from fabkit.errors import FabkitError
from fabkit.files.tomlfile import Table, read_toml
from fabkit.machines import DEFAULT_MACHINE, list_machines, load_machine
from fabkit.process import Process, Resolution, parse_process


def machine_process(name_or_path: str | None) -> Process:
    """The ``[process]`` of a machine profile (name or path), or of the default DIW one."""
    return load_machine(name_or_path or DEFAULT_MACHINE).process


def load_process(path: str | Path) -> Process:
    """Read the ``[process]`` table of a TOML file (module docstring); one-line errors."""
    path = Path(path)
    top = Table(read_toml(path, "process"), str(path))
    return parse_process(top.table("process"), source=str(path))


def resolve_channels(
    process: Process, features: tuple[str, ...], ignore: tuple[str, ...] = ()
) -> Resolution:
    """``process.resolve``, whose refusal of a feature without a channel also names the
    shipped machines whose own process encodes every feature (when the process is a
    machine's)."""
    try:
        return process.resolve(features, ignore)
    except FabkitError:
        if not process.source.startswith("machine "):
            raise
        able = [m.name for m in list_machines() if _encodes_all(m.process, features, ignore)]
        if not able:
            raise
        hint = f"; machines whose process encodes every feature: {', '.join(able)}"
        return process.resolve(features, ignore, hint)


def _encodes_all(process: Process, features: tuple[str, ...], ignore: tuple[str, ...]) -> bool:
    try:
        process.resolve(features, ignore)
    except FabkitError:
        return False
    return True
