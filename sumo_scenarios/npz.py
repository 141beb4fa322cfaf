"""Reading an .npz archive as data, each member checked against what it holds before it is read.

``np.load`` trusts an archive: a member's .npy header may declare any shape (numpy allocates it
before reading a byte), and a compressed member may unpack to gigabytes from a few kilobytes.
asg's own archives (``np.savez``) store their members uncompressed, and a scene's detections
(``np.savez_compressed``) are small; :func:`load_npz` reads nothing a header or a member's size
does not account for, and never unpickles.
"""
from __future__ import annotations

import math
import zipfile
from pathlib import Path

import numpy as np

#: the .npy header versions numpy's writers use (3.0 differs only in its text encoding)
_HEADER_READERS = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}


def load_npz(path: Path, max_unpacked_bytes: int = 0) -> dict[str, np.ndarray]:
    """Every array of the archive ``path`` by name (without ``.npy``). A compressed member may
    unpack to at most ``max_unpacked_bytes`` (0: none may grow, as ``np.savez`` writes them); a
    stored member is bounded by the file itself. ValueError (naming the member) for a member that
    is not an array, holds Python objects, declares more or fewer bytes than it holds, or unpacks
    past the bound, or whose sizes in the archive's index are more than the file holds; OSError,
    EOFError or zipfile.BadZipFile for a file that is not a whole archive."""
    file_bytes = Path(path).stat().st_size
    with zipfile.ZipFile(path) as archive:
        return {info.filename[:-len(".npy")]: _read_member(archive, info, file_bytes, max_unpacked_bytes)
                for info in archive.infolist()}


def _read_member(archive: zipfile.ZipFile, info: zipfile.ZipInfo, file_bytes: int,
                 max_unpacked_bytes: int) -> np.ndarray:
    name = info.filename
    if info.is_dir() or not name.endswith(".npy"):
        raise ValueError(f"{name}: not an array")
    stored = info.compress_type == zipfile.ZIP_STORED
    if info.compress_size > file_bytes or (stored and info.file_size != info.compress_size):
        raise ValueError(f"{name}: the archive's index gives sizes the file does not hold")
    if not stored and info.file_size > max(info.compress_size, max_unpacked_bytes):
        raise ValueError(f"{name}: unpacks to {info.file_size} bytes from {info.compress_size}")
    with archive.open(info) as member:
        version = np.lib.format.read_magic(member)
        if version not in _HEADER_READERS:
            raise ValueError(f"{name}: .npy format {version[0]}.{version[1]}, which numpy's writers do not use")
        shape, fortran_order, dtype = _HEADER_READERS[version](member)
        if dtype.hasobject:
            raise ValueError(f"{name}: holds Python objects")
        held = info.file_size - member.tell()
        declared = math.prod(shape) * dtype.itemsize
        if declared != held:
            raise ValueError(f"{name}: declares {declared} bytes of data and holds {held}")
        data = bytearray(member.read(declared))  # writable, as np.load's arrays are
    if len(data) != declared:
        raise EOFError(f"{name}: ends after {len(data)} of {declared} bytes")
    return np.frombuffer(data, dtype=dtype).reshape(shape, order="F" if fortran_order else "C")
