"""Write files so that an interrupted or failed job never leaves a half-written output."""

from __future__ import annotations

import contextlib
import os
import re
import tempfile
from collections.abc import Iterator
from pathlib import Path

from fabkit.errors import FabkitError


@contextlib.contextmanager
def atomic_path(final: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``final``; rename it to ``final`` only on success.

    The temporary file keeps ``final``'s suffix so that writers which pick a format
    from the suffix (numpy, PIL, trimesh) still work.
    """
    final = Path(final)
    if final.is_dir():
        raise FabkitError(f"cannot write {final}: a folder of that name exists")
    make_folder(final.parent, f"cannot write {final}")
    fd, tmp = tempfile.mkstemp(
        prefix=f".{final.stem}.", suffix=f".part{final.suffix}", dir=final.parent
    )
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, 0o666 & ~_umask())
        os.replace(tmp_path, final)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def check_folder(folder: str | os.PathLike[str], what: str) -> Path:
    """Refuse, before any work, an output folder that a file is in the way of.

    ``what`` starts the one-line message, e.g. ``"--out out"``. Nothing is created.
    """
    folder = Path(folder)
    blocker = next((p for p in (folder, *folder.parents) if p.exists()), None)
    if blocker is not None and not blocker.is_dir():
        raise FabkitError(f"{what}: {blocker} exists and is not a folder")
    return folder


def make_folder(folder: str | os.PathLike[str], what: str) -> Path:
    """Create ``folder`` and its parents; a file in the way is a one-line error."""
    folder = check_folder(folder, what)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise FabkitError(f"{what}: cannot create folder {folder} ({exc.strerror})") from None
    return folder


def _umask() -> int:
    """The process umask (read by setting and restoring it)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.+-]{0,63}")
"""A name that may become part of a file name: a letter or digit, then up to 63 letters,
digits and ``_ . + -``; never a separator, never ``..``."""


def check_name(name: object, where: str) -> str:
    """``name`` if it can safely be part of a file name; else a one-line FabkitError.

    Surface, feature and layer names end up in output file names (``patches/1_<name>.ply``);
    a name like ``x/../../y`` must never move a file outside the output folder.
    """
    if not isinstance(name, str) or not NAME_PATTERN.fullmatch(name) or ".." in name:
        raise FabkitError(
            f"{where}: name {str(name)[:40]!r} must be 1-64 letters, digits, '_', '.', '+' "
            "or '-', starting with a letter or digit (it becomes part of file names)"
        )
    return name


def inside(folder: str | os.PathLike[str], name: str) -> Path:
    """``folder / name``, refused (FabkitError) unless it stays inside ``folder``."""
    base = Path(folder).resolve()
    path = (base / name).resolve()
    if path != base and base not in path.parents:
        raise FabkitError(f"{name}: would be written outside the output folder {folder}")
    return Path(folder) / name
