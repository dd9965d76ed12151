"""Reading ``.npz`` and ``.npy`` files without trusting them.

``np.load`` trusts a file: it allocates what an array header declares (a 64-byte file can
ask for 80 GB), inflates whatever the zip directory lists (a 10 MB zip can hold 10 GB of
zeros) and reads members of any name. Here everything is checked before an array is read:

1. the zip's end record: a central directory of at most ARCHIVE_MEMBERS entries;
2. every member: named ``<key>.npy`` (a plain key), stored or deflated, not encrypted,
   listed once, its declared size within ARCHIVE_BYTES (all members together too) and,
   above RATIO_FLOOR, compressed at most COMPRESSION_RATIO:1;
3. every array header (``np.lib.format``): real numbers (bool, int, float) or, for the
   keys the caller names as text, a unicode string; a shape whose bytes are exactly the
   bytes the member holds;
4. the caller's own check of the headers (shapes that fit together, grid sizes);

then each array is read with ``allow_pickle=False`` through zipfile's CRC check. Every
problem is one :class:`~fabkit.errors.FabkitError` line starting with the caller's
``where``.
"""

from __future__ import annotations

import contextlib
import math
import re
import struct
import warnings
import zipfile
import zlib
from collections.abc import Callable, Collection, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import numpy as np

from fabkit.errors import FabkitError
from fabkit.files.readfile import size_text
from fabkit.limits import (
    ARCHIVE_BYTES,
    ARCHIVE_MEMBERS,
    COMPRESSION_RATIO,
    EMBEDDED_TEXT_CHARS,
    MAGNITUDE,
    RATIO_FLOOR,
)

KEY = re.compile(r"[A-Za-z_][A-Za-z0-9_]{0,63}")
"""A member's key: the names fabkit and numpy's ``savez(key=...)`` use."""
NUMBER_KINDS = "biuf"
"""numpy dtype kinds of real numbers: bool, signed and unsigned integer, float."""
MAX_DIMENSIONS = 8
_END_RECORD = b"PK\x05\x06"
_ZIP64_LOCATOR = b"PK\x06\x07"
_ZIP64_END_RECORD = b"PK\x06\x06"
_CENTRAL_ENTRY_BYTES = 1024
"""Bytes one central directory entry may take (fixed part, name, extra field, comment)."""
_BAD_DATA = (zipfile.BadZipFile, zlib.error, EOFError, ValueError, OSError, NotImplementedError)
"""What zipfile and numpy raise on corrupt data (zipfile raises NotImplementedError for
encrypted or patched members, unknown methods and versions)."""


@dataclass(frozen=True)
class ArrayHeader:
    """What an .npy header declares: shape, dtype and the bytes of the data."""

    key: str
    shape: tuple[int, ...]
    dtype: np.dtype
    nbytes: int


Check = Callable[[Mapping[str, ArrayHeader]], None]


def read_npz(
    path: str | Path,
    where: str,
    *,
    text: Collection[str] = (),
    keys: Callable[[set[str]], None] | None = None,
    check: Check | None = None,
    limit: int = ARCHIVE_BYTES,
) -> dict[str, np.ndarray]:
    """Every array of the .npz file ``path``, checked as the module docstring says.

    ``text``: keys that hold a unicode string (at most EMBEDDED_TEXT_CHARS) instead of
    numbers; ``keys(found)`` refuses the set of keys, before any header is read;
    ``check(headers)`` refuses headers before any data is read; ``limit``: the most bytes
    all arrays may take. Errors start with ``where``.
    """
    with _open_zip(path, where) as archive:
        members = _members(archive, where, limit)
        if keys is not None:
            keys(set(members))
        headers = {key: _header(archive, info, key, text, where) for key, info in members.items()}
        if check is not None:
            check(headers)
        return {key: _array(archive, members[key], key, where) for key in members}


def npz_keys(path: str | Path, where: str) -> set[str]:
    """The keys of the .npz file ``path``, from its zip directory alone (nothing inflated)."""
    with _open_zip(path, where) as archive:
        return set(_members(archive, where, ARCHIVE_BYTES))


@contextlib.contextmanager
def _open_zip(path: str | Path, where: str) -> Iterator[zipfile.ZipFile]:
    """The zip at ``path`` (a regular file the caller found), its end record checked first.

    Only the end record, the central directory and the members asked for are ever read,
    so the file's own size does not matter.
    """
    try:
        with open(path, "rb") as handle:
            _check_end_record(handle, where)
            with zipfile.ZipFile(handle) as archive:
                yield archive
    except (zipfile.BadZipFile, ValueError, EOFError, NotImplementedError) as exc:
        raise FabkitError(f"{where}: not an .npz archive ({exc})") from None
    except OSError as exc:
        raise FabkitError(f"{where}: {exc.strerror or exc}") from None


def read_npy(path: str | Path, where: str, check: Check | None = None) -> np.ndarray:
    """The array of the .npy file ``path``: real numbers, at most ARCHIVE_BYTES, its header
    checked (and ``check``-ed, as key "") before the data is read."""
    path = Path(path)
    with open(path, "rb") as handle:
        header = _read_header(handle, "", (), where)
        data_start = handle.tell()
        if check is not None:
            check({header.key: header})
        if header.nbytes > ARCHIVE_BYTES:
            raise FabkitError(
                f"{where}: its array would take {size_text(header.nbytes)} in memory, more "
                f"than the limit of {size_text(ARCHIVE_BYTES)}"
            )
        _check_bytes(header, handle.seek(0, 2) - data_start, where)
        try:
            handle.seek(0)
            return np.lib.format.read_array(handle, allow_pickle=False)
        except _BAD_DATA as exc:
            raise FabkitError(f"{where}: corrupt data ({exc})") from None


def _check_end_record(handle: BinaryIO, where: str) -> None:
    """Refuse a zip whose central directory (from its end record) holds more than
    ARCHIVE_MEMBERS entries or bytes for more, before zipfile reads it."""
    size = handle.seek(0, 2)
    tail_start = max(0, size - 22 - 65535)
    handle.seek(tail_start)
    tail = handle.read()
    at = tail.rfind(_END_RECORD)
    if at < 0 or len(tail) < at + 22:
        raise FabkitError(f"{where}: not an .npz archive (no zip end record)")
    entries, directory_bytes = struct.unpack_from("<xxxxxxxxxxHI", tail, at)
    locator = at - 20
    if locator >= 0 and tail[locator : locator + 4] == _ZIP64_LOCATOR:
        (offset,) = struct.unpack_from("<Q", tail, locator + 8)
        handle.seek(min(offset, size))
        record = handle.read(56)
        if len(record) == 56 and record[:4] == _ZIP64_END_RECORD:
            _, entries, directory_bytes = struct.unpack_from("<QQQ", record, 24)
    if entries > ARCHIVE_MEMBERS or directory_bytes > ARCHIVE_MEMBERS * _CENTRAL_ENTRY_BYTES:
        raise FabkitError(
            f"{where}: the archive lists {entries} members in {size_text(directory_bytes)}, "
            f"more than the limit of {ARCHIVE_MEMBERS} members"
        )
    handle.seek(0)


def _members(archive: zipfile.ZipFile, where: str, limit: int) -> dict[str, zipfile.ZipInfo]:
    """key -> member, every member checked from the zip directory alone."""
    members: dict[str, zipfile.ZipInfo] = {}
    total = 0
    for info in archive.infolist():
        name = info.filename
        key = name[:-4] if name.endswith(".npy") else ""
        if not KEY.fullmatch(key):
            raise FabkitError(
                f"{where}: member '{name[:80]}' is not an .npy array with a plain name "
                "(expected <key>.npy)"
            )
        if key in members:
            raise FabkitError(f"{where}: member '{name}' appears twice")
        if info.flag_bits & 0x1:
            raise FabkitError(f"{where}: member '{name}' is encrypted")
        if info.compress_type not in (zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED):
            raise FabkitError(
                f"{where}: member '{name}' uses compression method {info.compress_type}; "
                "numpy writes stored or deflated members only"
            )
        if info.file_size > limit:
            raise FabkitError(
                f"{where}: '{key}' would take {size_text(info.file_size)} in memory, more than "
                f"the limit of {size_text(limit)}"
            )
        ratio = info.file_size / max(info.compress_size, 1)
        if info.file_size > RATIO_FLOOR and ratio > COMPRESSION_RATIO:
            raise FabkitError(
                f"{where}: '{key}' is compressed {ratio:.0f}:1 ({size_text(info.file_size)}), "
                f"more than {COMPRESSION_RATIO}:1 for a member above "
                f"{size_text(RATIO_FLOOR)}: a zip bomb?"
            )
        total += info.file_size
        members[key] = info
    if total > limit:
        raise FabkitError(
            f"{where}: its arrays would take {size_text(total)} in memory, more than the limit "
            f"of {size_text(limit)}"
        )
    return members


def _header(
    archive: zipfile.ZipFile, info: zipfile.ZipInfo, key: str, text: Collection[str], where: str
) -> ArrayHeader:
    """The checked header of one member; its bytes must be the member's bytes."""
    try:
        with archive.open(info) as member:
            header = _read_header(member, key, text, where)
            held = info.file_size - member.tell()
    except _BAD_DATA as exc:
        raise FabkitError(f"{where}: corrupt data in '{key}' ({exc})") from None
    _check_bytes(header, held, where)
    return header


def _read_header(handle: BinaryIO, key: str, text: Collection[str], where: str) -> ArrayHeader:
    """Read and check an .npy header at the handle's position (left just after it)."""
    try:
        version = np.lib.format.read_magic(handle)
        with warnings.catch_warnings():  # a bad escape in the text warns before it fails
            warnings.simplefilter("ignore")  # (DeprecationWarning, SyntaxWarning on 3.12)
            if version == (1, 0):
                shape, _, dtype = np.lib.format.read_array_header_1_0(handle)
            elif version == (2, 0):
                shape, _, dtype = np.lib.format.read_array_header_2_0(handle)
            else:
                raise ValueError("an .npy format version fabkit does not read")
    # numpy parses the header text with tokenize and ast.literal_eval, which raise many
    # exception types on garbage (ValueError, SyntaxError, tokenize.TokenError,
    # RecursionError, ...); all mean a bad header. Their messages quote the file's bytes,
    # so say what is wrong without them.
    except Exception:  # noqa: BLE001
        what = f"{_name(key)} is not an .npy array" if key else "not an .npy file"
        raise FabkitError(f"{where}: {what} (bad or missing header)") from None
    _check_dtype(key, dtype, key in text, where)
    if len(shape) > MAX_DIMENSIONS:
        raise FabkitError(f"{where}: {_name(key)} has {len(shape)} dimensions")
    nbytes = math.prod(shape) * dtype.itemsize
    if key in text and shape != ():
        raise FabkitError(f"{where}: {_name(key)} must be one string, not a {len(shape)}-d array")
    if key in text and dtype.itemsize // 4 > EMBEDDED_TEXT_CHARS:
        raise FabkitError(
            f"{where}: {_name(key)} holds {dtype.itemsize // 4} characters, more than the limit of "
            f"{EMBEDDED_TEXT_CHARS}"
        )
    return ArrayHeader(key, tuple(shape), dtype, nbytes)


def _check_dtype(key: str, dtype: np.dtype, is_text: bool, where: str) -> None:
    """Real numbers (or a unicode string for a text key); never objects, records, complex."""
    plain = dtype.names is None and dtype.subdtype is None and not dtype.hasobject
    wanted = "U" if is_text else NUMBER_KINDS
    if not plain or dtype.kind not in wanted:
        expected = "text" if is_text else "real numbers (bool, int or float)"
        raise FabkitError(
            f"{where}: {_name(key)} holds {_dtype_name(dtype)} values; expected {expected}"
        )


def _dtype_name(dtype: np.dtype) -> str:
    if dtype.hasobject:
        return "object"
    return "record" if dtype.names is not None else str(dtype)


def _check_bytes(header: ArrayHeader, held: int, where: str) -> None:
    """The header's shape must account for exactly the bytes the member holds."""
    if header.nbytes != held:
        raise FabkitError(
            f"{where}: {_name(header.key)} declares a {_shape_text(header.shape)} {header.dtype} "
            f"array ({size_text(header.nbytes)}) but holds {size_text(held)}"
        )


def _name(key: str) -> str:
    """How an error names an array: ``'alpha'``, or "the array" of an .npy file."""
    return f"'{key}'" if key else "the array"


def _shape_text(shape: tuple[int, ...]) -> str:
    return " x ".join(str(n) for n in shape) if shape else "0-d"


def _array(archive: zipfile.ZipFile, info: zipfile.ZipInfo, key: str, where: str) -> np.ndarray:
    """Read one member (its CRC is checked when its last byte is read)."""
    try:
        with archive.open(info) as member:
            array = np.lib.format.read_array(member, allow_pickle=False)
            member.read(1)
    except _BAD_DATA as exc:
        raise FabkitError(f"{where}: corrupt data in '{key}' ({exc})") from None
    return array


def check_magnitude(values: np.ndarray, key: str, where: str | Path | None = None) -> None:
    """Refuse finite values beyond +-MAGNITUDE (NaN is let through): no sheet, toolpath or
    surface is described by such numbers, and they overflow what is computed from them."""
    with np.errstate(invalid="ignore"):
        largest = float(np.nanmax(np.abs(values), initial=0.0))
    if largest > MAGNITUDE:
        raise FabkitError(
            f"{where}: '{key}' has values up to {largest:.3g}, beyond the plausible +-{MAGNITUDE:g}"
        )
