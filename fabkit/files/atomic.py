"""Write files so that an interrupted or failed job never leaves a half-written output.

A command that writes a folder claims it first (:func:`output_folder`): every file then
written through :func:`atomic_path` inside it is listed in the folder's manifest
(:data:`MANIFEST`, one relative path a line) before it gets its final name. A later
command into the same folder refuses (one line naming what is there) unless asked to
``--overwrite``, which removes exactly the listed files; a folder holding anything fabkit
did not write is always refused, so a user's file is never touched.
"""

from __future__ import annotations

import contextlib
import os
import re
import tempfile
from collections.abc import Iterator
from contextvars import ContextVar
from dataclasses import dataclass, field
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
        record(final)  # listed before it exists under its name: never an unlisted output
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


MANIFEST = ".fabkit-files"
"""The manifest of a claimed output folder: the files fabkit wrote there, one relative
POSIX path a line, appended as each is written (an interrupted run's files are listed too)."""
MANIFEST_BYTES = 16 * 2**20
"""A manifest larger than this was not written by fabkit."""
SHOWN = 4
"""Names shown in a refusal before "and N more"."""


@dataclass
class _Claim:
    """A claimed output folder (resolved), the earlier files still to remove, and the
    files listed in its manifest so far (a file written twice, such as a run's design
    file rewritten with its layers, is listed once)."""

    folder: Path
    earlier: list[str] | None
    listed: set[str] = field(default_factory=set)


_CLAIMED: ContextVar[_Claim | None] = ContextVar("fabkit_output_folder", default=None)


@contextlib.contextmanager
def output_folder(
    folder: str | os.PathLike[str], what: str, overwrite: bool = False, whole: bool = False
) -> Iterator[Path]:
    """Claim ``folder`` for a command's outputs while the ``with`` block runs.

    A folder that holds files fabkit did not write (not in its manifest) is refused; one
    that holds an earlier run's files is refused unless ``overwrite``: then exactly those
    files (and the sub-folders they leave empty) are removed just before the first new
    file is written, so a command that fails on bad input first leaves them alone.
    ``what`` starts the one-line message, e.g. ``"--out out"``. Files written through
    :func:`atomic_path` inside the folder are listed in its manifest. ``whole``: the
    writer replaces the folder itself as one (a laser pattern), so nothing is removed
    file by file; the caller then lists the new files with :func:`record`.
    """
    folder = check_folder(folder, what)
    earlier = earlier_outputs(folder, what)
    if earlier and not overwrite:
        raise FabkitError(
            f"{what}: holds {_count(earlier)} of an earlier fabkit run ({_names(earlier)}): "
            "give --overwrite to replace them, or another folder"
        )
    token = _CLAIMED.set(_Claim(folder.resolve(), None if whole else earlier))
    try:
        yield folder
    finally:
        _CLAIMED.reset(token)


def earlier_outputs(folder: Path, what: str) -> list[str]:
    """The files of ``folder`` that its manifest lists (relative, sorted).

    Anything else in the folder (a file fabkit did not write there, or a symbolic link,
    which fabkit never writes) is a one-line error.
    """
    if not folder.is_dir():
        return []
    listed = set(_read_manifest(folder, what))
    entries = [p for p in folder.rglob("*") if p.is_symlink() or not p.is_dir()]
    present = sorted(p.relative_to(folder).as_posix() for p in entries if p.name != MANIFEST)
    links = {p.relative_to(folder).as_posix() for p in entries if p.is_symlink()}
    foreign = [name for name in present if name not in listed or name in links]
    if foreign:
        raise FabkitError(
            f"{what}: holds {_count(foreign)} fabkit did not write ({_names(foreign)}): "
            "give a new or empty folder (fabkit replaces only its own files)"
        )
    return present


def record(path: str | os.PathLike[str]) -> None:
    """List ``path`` (a file, or every file under a folder) in the claimed folder's manifest.

    Nothing happens outside a claimed folder (no command claimed one, or ``path`` lies
    elsewhere).
    """
    claim = _CLAIMED.get()
    if claim is None:
        return
    claimed, path = claim.folder, Path(path).resolve()
    if path != claimed and claimed not in path.parents:
        return
    if claim.earlier is not None:  # the first new file: the earlier run's files go now
        for name in claim.earlier:
            _remove(claimed, name)
        (claimed / MANIFEST).unlink(missing_ok=True)
        claim.earlier = None
    files = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    names = [p.relative_to(claimed).as_posix() for p in files if p.name != MANIFEST]
    names = [name for name in dict.fromkeys(names) if name not in claim.listed]
    claim.listed.update(names)
    lines = "".join(f"{name}\n" for name in names)
    with open(claimed / MANIFEST, "a", encoding="utf-8") as handle:
        handle.write(lines)


def _read_manifest(folder: Path, what: str) -> list[str]:
    """The relative paths a folder's manifest lists ([] without one)."""
    manifest = folder / MANIFEST
    if not manifest.is_file():
        return []
    if manifest.stat().st_size > MANIFEST_BYTES:
        raise FabkitError(f"{what}: {manifest} is larger than fabkit writes (not its manifest)")
    try:
        text = manifest.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise FabkitError(f"{what}: cannot read {manifest} ({exc})") from None
    return [line for line in text.splitlines() if line]


def _remove(folder: Path, name: str) -> None:
    """Delete ``folder/name`` (never outside ``folder``) and the sub-folders it leaves empty."""
    path = inside(folder, name)
    path.unlink(missing_ok=True)
    parent = path.parent
    while parent.resolve() != folder.resolve() and parent.is_dir() and not any(parent.iterdir()):
        parent.rmdir()
        parent = parent.parent


def _count(names: list[str]) -> str:
    return f"{len(names)} file{'s' if len(names) != 1 else ''}"


def _names(names: list[str]) -> str:
    shown = ", ".join(names[:SHOWN])
    return shown + (f" and {len(names) - SHOWN} more" if len(names) > SHOWN else "")
