"""Hostile input files, made cheaply: zip bombs, lying headers, deep nesting, bad bytes.

Every maker writes one file and returns its path. Nothing here is large on disk: a "10 GB"
archive member only declares its size in the zip directory, a huge text file is sparse,
and a highly compressible stream repeats one flushed deflate block.
"""

from __future__ import annotations

import io
import json
import os
import struct
import zipfile
import zlib
from pathlib import Path

import numpy as np

GB = 1 << 30


def npy_bytes(array: np.ndarray, allow_pickle: bool = False) -> bytes:
    """``array`` as the bytes of an .npy file."""
    buffer = io.BytesIO()
    np.save(buffer, array, allow_pickle=allow_pickle)
    return buffer.getvalue()


def npy_header(shape: tuple[int, ...], descr: str = "<f8") -> bytes:
    """The header of an .npy file (format 1.0) declaring ``shape`` and ``descr``."""
    buffer = io.BytesIO()
    header = {"descr": descr, "fortran_order": False, "shape": shape}
    np.lib.format.write_array_header_1_0(buffer, header)
    return buffer.getvalue()


def write_npz(path: Path, members: dict[str, bytes], compress: bool = True) -> Path:
    """A zip of raw members (name -> bytes), as numpy writes one."""
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with zipfile.ZipFile(path, "w", method) as archive:
        for name, data in members.items():
            archive.writestr(name, data)
    return path


def arrays_of(path: Path) -> dict[str, np.ndarray]:
    """The arrays of a (valid) .npz file."""
    with np.load(path, allow_pickle=False) as data:
        return {key: data[key] for key in data.files}


def edited_npz(path: Path, source: Path, **changes: np.ndarray) -> Path:
    """``source`` with some arrays replaced (None removes one)."""
    arrays = {**arrays_of(source), **changes}
    members = {
        f"{k}.npy": npy_bytes(v, allow_pickle=True) for k, v in arrays.items() if v is not None
    }
    return write_npz(path, members)


def with_members(path: Path, source: Path, **extra: bytes) -> Path:
    """``source`` plus raw members named by the keywords' values' keys."""
    members = {f"{k}.npy": npy_bytes(v) for k, v in arrays_of(source).items()}
    members.update(extra)
    return write_npz(path, members)


def declared_size(path: Path, source: Path, key: str, size: int) -> Path:
    """``source`` whose member ``key`` declares ``size`` uncompressed bytes in the zip
    directory (zip64 when over 4 GB) while its stream stays small: a zip bomb's directory."""
    shape = (size // 8,)
    members = {f"{k}.npy": npy_bytes(v) for k, v in arrays_of(source).items()}
    members[f"{key}.npy"] = npy_header(shape) + bytes(64)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, data in members.items():
            archive.writestr(name, data)
        info = archive.getinfo(f"{key}.npy")
        info.file_size = size + len(npy_header(shape))
    return path


def declared_npz(
    path: Path, arrays: dict[str, tuple[tuple[int, ...], str]], **real: np.ndarray
) -> Path:
    """An .npz of ``real`` arrays and of members (key -> (shape, descr)) that each hold a
    header and 64 zero bytes while the zip directory declares the full size: consistent
    headers, no data."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as archive:
        for key, value in real.items():
            archive.writestr(f"{key}.npy", npy_bytes(value))
        for key, (shape, descr) in arrays.items():
            header = npy_header(shape, descr)
            archive.writestr(f"{key}.npy", header + bytes(64))
            size = int(np.prod(shape)) * np.dtype(descr).itemsize
            archive.getinfo(f"{key}.npy").file_size = len(header) + size
    return path


def compressible_stream(
    path: Path, source: Path, key: str, size: int, shape: tuple[int, ...]
) -> Path:
    """``source`` whose member ``key`` is a real deflate stream of ``size`` zero bytes after
    an .npy header declaring ``shape``: about size / 1000 bytes on disk (CRC not computed)."""
    header = npy_header(shape)
    block = 1 << 20
    compressor = zlib.compressobj(9, zlib.DEFLATED, -15)
    head = compressor.compress(header) + compressor.flush(zlib.Z_FULL_FLUSH)
    chunk = compressor.compress(bytes(block)) + compressor.flush(zlib.Z_FULL_FLUSH)
    stream = head + chunk * (size // block) + compressor.flush(zlib.Z_FINISH)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as archive:
        for name, array in arrays_of(source).items():
            if name != key:
                archive.writestr(f"{name}.npy", npy_bytes(array))
        archive.writestr(f"{key}.npy", stream)
        info = archive.getinfo(f"{key}.npy")
        info.compress_type = zipfile.ZIP_DEFLATED
        info.file_size = len(header) + (size // block) * block
    return path


def corrupt_deflate(path: Path, source: Path, key: str) -> Path:
    """``source`` with bytes in the middle of member ``key``'s deflate stream scrambled."""
    data = bytearray(source.read_bytes())
    with zipfile.ZipFile(source) as archive:
        info = archive.getinfo(f"{key}.npy")
    start = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra)
    middle = start + info.compress_size // 2
    for k in range(middle, min(middle + 16, start + info.compress_size)):
        data[k] ^= 0x5A
    path.write_bytes(bytes(data))
    return path


def lying_npy(path: Path, shape: tuple[int, ...], descr: str = "<f8") -> Path:
    """An .npy file whose header declares ``shape`` but which holds only 64 data bytes."""
    path.write_bytes(npy_header(shape, descr) + bytes(64))
    return path


def sparse(path: Path, size: int, head: bytes = b"") -> Path:
    """A file of ``size`` bytes taking no disk space (``head``, then zeros)."""
    with open(path, "wb") as handle:
        handle.write(head)
        handle.truncate(size)
    return path


def deep_toml(kind: str, depth: int, key: str = "a") -> str:
    """TOML text nested ``depth`` deep: "array", "inline" table, "dotted" key or "header"."""
    if kind == "array":
        return f"{key} = " + "[" * depth + "]" * depth + "\n"
    if kind == "inline":
        return f"{key} = " + "{b = " * depth + "1" + "}" * depth + "\n"
    if kind == "dotted":
        return key + ".a" * depth + " = 1\n"
    return "[" + ".".join([key] * depth) + "]\n"


def deep_json(depth: int) -> str:
    """A JSON array nested ``depth`` deep."""
    return "[" * depth + "]" * depth


def png_header(path: Path, width: int, height: int, bit_depth: int = 8) -> Path:
    """A PNG that declares width x height greyscale pixels but holds one tiny IDAT: the
    header of a decompression bomb."""

    def chunk(kind: bytes, body: bytes) -> bytes:
        crc = zlib.crc32(kind + body) & 0xFFFFFFFF
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", crc)

    ihdr = struct.pack(">IIBBBBB", width, height, bit_depth, 0, 0, 0, 0)
    idat = zlib.compress(bytes(1024))
    data = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b"")
    path.write_bytes(data)
    return path


def png_bomb(path: Path, side: int) -> Path:
    """A real, valid PNG of side x side black 1-bit pixels (small on disk)."""
    row = b"\x00" + bytes((side + 7) // 8)
    compressor = zlib.compressobj(9)
    body = b"".join(compressor.compress(row) for _ in range(side)) + compressor.flush()

    def chunk(kind: bytes, data: bytes) -> bytes:
        crc = zlib.crc32(kind + data) & 0xFFFFFFFF
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", crc)

    ihdr = struct.pack(">IIBBBBB", side, side, 1, 0, 0, 0, 0)
    data = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", body) + chunk(b"IEND", b"")
    path.write_bytes(data)
    return path


def stl_declaring(path: Path, faces: int, written: int = 2) -> Path:
    """A binary STL whose header declares ``faces`` triangles but holds ``written``."""
    triangle = struct.pack("<12fH", 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0)
    path.write_bytes(bytes(80) + struct.pack("<I", faces) + triangle * written)
    return path


def ply_declaring(path: Path, vertices: int, faces: int) -> Path:
    """An ASCII PLY whose header declares huge element counts over a tiny body."""
    header = (
        "ply\nformat ascii 1.0\n"
        f"element vertex {vertices}\nproperty float x\nproperty float y\nproperty float z\n"
        f"element face {faces}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    path.write_text(header + "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")
    return path


def ascii_stl(path: Path, triangles: np.ndarray) -> Path:
    """An ASCII STL of triangles (T, 3, 3), written with repr() so 1e300 and nan survive."""
    lines = ["solid s"]
    for triangle in triangles:
        lines += ["facet normal 0 0 1", "outer loop"]
        lines += [f"vertex {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in triangle]
        lines += ["endloop", "endfacet"]
    path.write_text("\n".join([*lines, "endsolid s", ""]))
    return path


def grid_stl(path: Path, side: int = 12, z: float = 0.0) -> Path:
    """A valid ASCII STL of a flat side x side lattice at height z (a mesh height map)."""
    xs = np.linspace(-2.0, 2.0, side)
    triangles = []
    for i in range(side - 1):
        for j in range(side - 1):
            a, b, c, d = (
                (xs[i], xs[j], z),
                (xs[i + 1], xs[j], z),
                (xs[i + 1], xs[j + 1], z),
                (xs[i], xs[j + 1], z),
            )
            triangles += [(a, b, c), (a, c, d)]
    return ascii_stl(path, np.array(triangles))


def spec_json_of(design: Path) -> dict:
    """The spec embedded in a design file, as a table."""
    return json.loads(str(arrays_of(design)["spec"]))


def with_spec(path: Path, design: Path, table: object) -> Path:
    """``design`` with another embedded spec (any JSON value, or raw text)."""
    text = table if isinstance(table, str) else json.dumps(table)
    return edited_npz(path, design, spec=np.array(text))


def symlink(path: Path, target: Path) -> Path:
    """``path`` -> ``target``."""
    os.symlink(target, path)
    return path
