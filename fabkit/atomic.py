"""Write files so that an interrupted or failed job never leaves a half-written output."""

from __future__ import annotations

import contextlib
import os
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
