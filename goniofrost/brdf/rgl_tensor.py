r"""Read and write the RGL tensor file format (``.bsdf``) of Mitsuba 3 and pbrt-v4.

The layout of Mitsuba 3's ``tensor_io.py``, little-endian: ``b"tensor_file\0"``, version (1, 0),
field count; per field its name, rank, dtype code (``DTYPE_CODES``), data offset and shape; then
the data, each field 8-byte aligned, C order. Writing is atomic and deterministic.
"""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from goniofrost.core.atomic_file import write_buffers_atomic
from goniofrost.core.errors import GoniofrostError

MAGIC = b"tensor_file\x00"
VERSION = (1, 0)
ALIGN = 8  # mi.tensor_io.write's default alignment of every field's data
# Mitsuba's Struct::Type codes (struct.h before struct-jit, unchanged in struct-jit): 0 is Invalid.
DTYPE_CODES = {
    np.dtype("u1"): 1, np.dtype("i1"): 2, np.dtype("<u2"): 3, np.dtype("<i2"): 4,
    np.dtype("<u4"): 5, np.dtype("<i4"): 6, np.dtype("<u8"): 7, np.dtype("<i8"): 8,
    np.dtype("<f2"): 9, np.dtype("<f4"): 10, np.dtype("<f8"): 11,
}
CODE_DTYPES = {code: dtype for dtype, code in DTYPE_CODES.items()}


class TensorFileError(GoniofrostError, ValueError):
    """A file is not a readable RGL tensor file, or fields cannot be written as one."""


def encode(fields: dict) -> bytes:
    """The bytes of a tensor file holding ``fields`` (name -> numpy array or str), in order."""
    return b"".join(bytes(buffer) for buffer in encode_buffers(fields))


def encode_buffers(fields: dict) -> list:
    """The file as a list of bytes-like pieces (header, zero padding, each array's memory), in order.

    Written in turn without joining them: a 100 MB spectral file is not copied three times.
    """
    arrays = {name: _as_field(name, value) for name, value in fields.items()}
    header = bytearray(MAGIC + struct.pack("<BBI", *VERSION, len(arrays)))
    header_size = len(header) + sum(_entry_size(name, a) for name, a in arrays.items())
    offsets, position = [], header_size
    for array in arrays.values():
        position = _aligned(position)
        offsets.append(position)
        position += array.nbytes
    for (name, array), offset in zip(arrays.items(), offsets):
        label = name.encode("utf-8")
        header += struct.pack("<H", len(label)) + label
        header += struct.pack("<HBQ", array.ndim, DTYPE_CODES[array.dtype], offset)
        header += struct.pack(f"<{array.ndim}Q", *array.shape)
    buffers, end = [bytes(header)], len(header)
    for array, offset in zip(arrays.values(), offsets):
        buffers.append(bytes(offset - end))  # zero padding up to the aligned offset
        buffers.append(memoryview(array).cast("B"))
        end = offset + array.nbytes
    return buffers


def write_tensor_file(path, fields: dict) -> None:
    """Write ``fields`` (name -> array or str) as a tensor file, atomically."""
    write_buffers_atomic(path, encode_buffers(fields))


def read_tensor_file(path) -> dict[str, np.ndarray]:
    """Read every field of a tensor file into numpy arrays (name -> array, in file order).

    Raises TensorFileError naming the file and what is wrong (truncated, bad header, unknown
    dtype, a field that runs past the end of the file).
    """
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise TensorFileError(f"{path}: no such file") from None
    return decode(raw, str(path))


def decode(raw: bytes, source: str = "tensor file") -> dict[str, np.ndarray]:
    """The fields of a tensor file's bytes (see ``read_tensor_file``)."""
    if len(raw) < len(MAGIC) + 6:
        raise TensorFileError(f"{source}: truncated tensor file: {len(raw)} bytes, expected at least 18")
    if raw[:12] != MAGIC:
        raise TensorFileError(f"{source}: not a tensor file: header {raw[:12]!r}, expected {MAGIC!r}")
    version = tuple(raw[12:14])
    if version != VERSION:
        raise TensorFileError(f"{source}: tensor file version {version}, expected {VERSION}")
    (count,) = struct.unpack_from("<I", raw, 14)
    position, fields = 18, {}
    for _ in range(count):
        name, dtype, offset, shape, position = _read_entry(raw, position, source)
        size = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
        if offset + size > len(raw):
            raise TensorFileError(f"{source}: field {name!r} needs bytes {offset}..{offset + size}, "
                                  f"the file has {len(raw)}")
        fields[name] = np.frombuffer(raw, dtype=dtype, count=size // dtype.itemsize, offset=offset).reshape(shape).copy()
    return fields


def _read_entry(raw: bytes, position: int, source: str):
    try:
        (length,) = struct.unpack_from("<H", raw, position)
        name = raw[position + 2:position + 2 + length].decode("utf-8")
        position += 2 + length
        ndim, code, offset = struct.unpack_from("<HBQ", raw, position)
        position += 11
        shape = struct.unpack_from(f"<{ndim}Q", raw, position)
    except (struct.error, UnicodeDecodeError) as exc:
        raise TensorFileError(f"{source}: truncated or corrupt field table at byte {position}: {exc}") from None
    if code not in CODE_DTYPES:
        raise TensorFileError(f"{source}: field {name!r}: dtype code {code}, expected one of 1..11")
    return name, CODE_DTYPES[code], offset, shape, position + 8 * ndim


def _as_field(name: str, value) -> np.ndarray:
    if isinstance(value, str):
        return np.frombuffer(value.encode("utf-8"), dtype=np.uint8)
    array = np.ascontiguousarray(value)
    dtype = array.dtype.newbyteorder("<") if array.dtype.itemsize > 1 else array.dtype
    if dtype not in DTYPE_CODES:
        raise TensorFileError(f"field {name!r}: dtype {array.dtype} cannot be stored in a tensor file, "
                              f"expected one of {sorted(str(d) for d in DTYPE_CODES)}")
    return np.ascontiguousarray(array, dtype=dtype)


def _entry_size(name: str, array: np.ndarray) -> int:
    return 2 + len(name.encode("utf-8")) + 2 + 1 + 8 + 8 * array.ndim


def _aligned(position: int) -> int:
    return (position + ALIGN - 1) // ALIGN * ALIGN
