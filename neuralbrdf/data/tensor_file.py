"""Mitsuba's ``tensor_file`` container: named arrays in one little-endian binary file.

The format of Mitsuba 3's ``TensorFile`` (``src/core/tensor.cpp``) and of the RGL's reference
reader ``brdf-loader`` (``Tensor`` in ``powitacq.inl``), in which the RGL material database
(Dupuy & Jakob 2018) publishes its measured BRDFs (:mod:`neuralbrdf.data.rgl_bsdf`):

* the 12-byte magic ``tensor_file\\0``, the version bytes ``1, 0`` and a ``u32`` field count;
* per field: a ``u16`` name length and the name (UTF-8), a ``u16`` rank, a ``u8`` type code
  (:data:`DTYPES`: 1 ``u8`` … 10 ``f32``, 11 ``f64``), a ``u64`` byte offset and ``rank`` ``u64``
  sizes;
* each field's data at its offset, in C order (the writer aligns offsets to 8 bytes).

:func:`read_tensor_file` checks all of it against the file's size and the limits of
:mod:`neuralbrdf.limits` (field count, rank, name length) before it allocates anything, so memory
stays proportional to the file and a truncated, foreign or hostile file is one
:class:`~neuralbrdf.errors.InputError` naming the file, the first offending item and what was
expected; :func:`write_tensor_file` writes the same layout atomically.
"""

from __future__ import annotations

import struct
from os import PathLike
from pathlib import Path

import numpy as np

from neuralbrdf.atomic import atomic_path, note_input
from neuralbrdf.errors import InputError
from neuralbrdf.limits import (MAX_TENSOR_FIELDS, MAX_TENSOR_FILE_BYTES, MAX_TENSOR_NAME_BYTES, MAX_TENSOR_RANK,
                               check_file_size, file_problem)

MAGIC = b"tensor_file\0"
VERSION = (1, 0)
#: Type codes of the format (Mitsuba's ``Struct::Type`` as the files store it) -> NumPy dtypes.
DTYPES = {1: "u1", 2: "i1", 3: "<u2", 4: "<i2", 5: "<u4", 6: "<i4", 7: "<u8", 8: "<i8", 9: "<f2", 10: "<f4",
          11: "<f8"}
_CODES = {np.dtype(dtype): code for code, dtype in DTYPES.items()}
#: Bytes before the field table: magic, version, field count.
_PREAMBLE = len(MAGIC) + 2 + 4
_ALIGNMENT = 8


class _Header:
    """A cursor over the header bytes that names what it was reading when they ran out."""

    def __init__(self, data: bytes, path: Path) -> None:
        self.data, self.path, self.position = data, path, 0

    def take(self, fmt: str, what: str) -> tuple:
        size = struct.calcsize(fmt)
        if self.position + size > len(self.data):
            raise InputError(f"truncated tensor_file: the header ends inside {what} (byte {self.position} of "
                             f"{len(self.data)})", path=self.path)
        values = struct.unpack_from(fmt, self.data, self.position)
        self.position += size
        return values


def read_tensor_file(path: str | PathLike[str]) -> dict[str, np.ndarray]:
    """The fields of a ``tensor_file`` by name, as read-only arrays of their stored dtype (module
    docstring); :class:`InputError` naming the file for anything that is not one."""
    path = Path(path)
    if path.is_dir():
        raise InputError("is a directory; expected a tensor_file such as NAME.bsdf", path=path)
    if not path.is_file():
        raise InputError(file_problem(path) or "no such file", path=path)
    size = check_file_size(path, MAX_TENSOR_FILE_BYTES, "tensor_file")
    note_input(path)
    data = path.read_bytes()
    if len(data) != size:
        raise InputError(f"changed while it was read ({size} bytes, then {len(data)})", path=path)
    header = _Header(data, path)
    (magic,) = header.take(f"{len(MAGIC)}s", "the magic bytes")
    if magic != MAGIC:
        raise InputError(f"not a Mitsuba tensor_file: it starts with {magic!r}, expected {MAGIC!r}", path=path)
    version = header.take("<BB", "the version")
    if version != VERSION:
        raise InputError(f"tensor_file version {version[0]}.{version[1]}; expected {VERSION[0]}.{VERSION[1]}",
                         path=path)
    (count,) = header.take("<I", "the field count")
    if count > MAX_TENSOR_FIELDS:
        raise InputError(f"tensor_file header claims {count} fields; at most {MAX_TENSOR_FIELDS} are read "
                         "(neuralbrdf.limits)", path=path)
    entries: dict[str, tuple[np.dtype, int, tuple[int, ...]]] = {}
    for index in range(count):
        (length,) = header.take("<H", f"the name of field {index + 1} of {count}")
        if length > MAX_TENSOR_NAME_BYTES:
            raise InputError(f"field {index + 1} of {count} has a name of {length} bytes; at most "
                             f"{MAX_TENSOR_NAME_BYTES} (neuralbrdf.limits)", path=path)
        (raw_name,) = header.take(f"{length}s", f"the name of field {index + 1} of {count}")
        try:
            name = raw_name.decode("utf-8")
        except UnicodeDecodeError:
            raise InputError(f"field {index + 1} of {count} has a name that is not UTF-8: {shown(repr(raw_name))}",
                             path=path) from None
        rank, code, offset = header.take("<HBQ", f"the description of field {shown(name)!r}")
        if rank > MAX_TENSOR_RANK:
            raise InputError(f"field {shown(name)!r} has rank {rank}; at most {MAX_TENSOR_RANK} (neuralbrdf.limits)",
                             path=path)
        shape = header.take(f"<{rank}Q", f"the shape of field {shown(name)!r}")
        if code not in DTYPES:
            raise InputError(f"field {shown(name)!r} has type code {code}; expected one of 1-11 (u8 ... f64)",
                             path=path)
        if name in entries:
            raise InputError(f"field {shown(name)!r} appears twice", path=path)
        entries[name] = (np.dtype(DTYPES[code]), offset, shape)
    fields = {}
    for name, (dtype, offset, shape) in entries.items():
        if max(shape, default=0) > len(data):
            raise InputError(f"truncated or corrupt tensor_file: field {shown(name)!r} claims a dimension of "
                             f"{max(shape)} in a file of {len(data)} bytes", path=path)
        count = int(np.prod(shape, dtype=object))
        if count * dtype.itemsize > len(data):
            raise InputError(f"truncated or corrupt tensor_file: field {shown(name)!r} {list(shape)} needs "
                             f"{float(count * dtype.itemsize):.3g} bytes, more than the file's {len(data)}", path=path)
        end = offset + count * dtype.itemsize
        if count and (offset < header.position or end > len(data)):
            where = "overlap the header" if offset < header.position else f"lie beyond its {len(data)} bytes"
            raise InputError(f"truncated or corrupt tensor_file: the data of field {shown(name)!r} {list(shape)} "
                             f"(bytes {offset}-{end}) would {where}", path=path)
        fields[name] = np.frombuffer(data, dtype=dtype, count=count, offset=offset if count else 0).reshape(shape)
    return fields


def shown(text: str, limit: int = 40) -> str:
    """``text`` shortened to ``limit`` characters for an error line (a name from a file may be long)."""
    return text if len(text) <= limit else text[: limit - 3] + "..."


def write_tensor_file(path: str | PathLike[str], fields: dict[str, np.ndarray]) -> None:
    """Write ``fields`` (name -> array of a :data:`DTYPES` dtype) as a ``tensor_file``, atomically."""
    arrays = {name: np.ascontiguousarray(np.asarray(value)) for name, value in fields.items()}
    for name, array in arrays.items():
        if array.dtype.newbyteorder("<") not in _CODES:
            raise ValueError(f"field {name!r}: dtype {array.dtype} has no tensor_file type code")
    table_size = sum(2 + len(name.encode()) + 2 + 1 + 8 + 8 * array.ndim for name, array in arrays.items())
    offset = _PREAMBLE + table_size
    table, blobs = [], []
    for name, array in arrays.items():
        start = -(-offset // _ALIGNMENT) * _ALIGNMENT
        blobs.append(b"\0" * (start - offset) + array.astype(array.dtype.newbyteorder("<")).tobytes())
        encoded = name.encode()
        code = _CODES[array.dtype.newbyteorder("<")]
        table.append(struct.pack(f"<H{len(encoded)}sHBQ{array.ndim}Q", len(encoded), encoded, array.ndim, code, start,
                                 *array.shape))
        offset = start + array.nbytes
    with atomic_path(path) as tmp:
        tmp.write_bytes(MAGIC + bytes(VERSION) + struct.pack("<I", len(arrays)) + b"".join(table) + b"".join(blobs))
