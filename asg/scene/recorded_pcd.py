"""Recorded point clouds read as hostile input: PCD files (v0.7, ASCII or binary) with fields x, y, z
and an intensity, as OPV2V, V2XSet and V2V4Real store their scans.

OPV2V's scans are ASCII ``x y z rgb`` with the intensity in the red byte of the packed colour
(``rgb`` holds a float32 whose bits are 0x00RRGGBB); OpenCOOD reads them with Open3D and takes
``colors[:, 0]``, the red byte / 255, as the intensity: so does this reader. A plain ``intensity``
field is taken as it is. The header is read and checked before the data: a declared count above
MAX_CLOUD_POINTS, a size or type this reader does not take, a body shorter or longer than declared,
or a non-finite coordinate is one line (InputError), never a large allocation.
"""
from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from sumo_scenarios.errors import InputError

from .recording import MAX_CLOUD_POINTS, Handedness, RecordedView

#: the longest PCD header read (bytes) before its DATA line must have come
MAX_HEADER_BYTES = 4096
_NUMPY_TYPE = {("F", 4): "<f4", ("F", 8): "<f8", ("U", 4): "<u4", ("U", 1): "u1", ("I", 4): "<i4"}


def recorded_cloud(view: RecordedView, handed: Handedness) -> np.ndarray:
    """(N, 4) float32 x, y, z, intensity of a recorded view in its LiDAR's frame (x forward, y left:
    y mirrored from a left-handed file, a sign flip that keeps every value exact; the file's values
    themselves unless the view was written in a lowered frame, whose z is then lowered by
    ``origin_z_m`` in float32, the inverse of the export's raise to within one unit in the last
    place); InputError if the file is gone or is not the one imported (its sha256 or point count)."""
    cloud = read_recorded_pcd(Path(view.cloud), view.sha256)
    if len(cloud) != view.points:
        raise InputError(f"{view.cloud}: {len(cloud)} points where the scene recorded {view.points}; re-import it")
    cloud = in_scene_frame(cloud, handed)
    if view.origin_z_m:
        cloud[:, 2] -= np.float32(view.origin_z_m)
    return cloud


def in_scene_frame(cloud: np.ndarray, handed: Handedness) -> np.ndarray:
    """A cloud (N, 4) as its file holds it, in the scene's sensor frame (see :func:`recorded_cloud`)."""
    if handed is Handedness.RIGHT:
        return cloud
    out = cloud.copy()
    out[:, 1] = -out[:, 1]
    return out


def read_recorded_pcd(path: Path, sha256: str | None = None) -> np.ndarray:
    """(N, 4) float32 x, y, z, intensity in [0, 1] of a recorded scan, in the file's own frame;
    with ``sha256``, InputError unless the file's digest is that one."""
    cloud, digest = read_recorded_pcd_with_digest(path)
    if sha256 is not None and digest != sha256:
        raise InputError(f"{path}: not the scan the scene was imported from (its sha256 changed); re-import the recording")
    return cloud


def read_recorded_pcd_with_digest(path: Path) -> tuple[np.ndarray, str]:
    """(:func:`read_recorded_pcd`'s cloud, the sha256 of the file's bytes), the file read once."""
    path, most = Path(path), MAX_CLOUD_POINTS * 64 + MAX_HEADER_BYTES
    try:
        if path.exists() and not path.is_file():  # a device or a pipe (a scene file names any path)
            raise InputError(f"{path}: not a regular file; not a recorded scan")
        with path.open("rb") as fh:
            data = fh.read(most + 1)  # never more: a file may grow, or lie about its size
    except OSError as exc:
        raise InputError(f"{path}: cannot be read ({exc.strerror}); check the recording") from None
    if len(data) > most:
        raise InputError(f"{path}: larger than a scan of {MAX_CLOUD_POINTS} points can be; not a recorded scan")
    return _parsed(data, path), hashlib.sha256(data).hexdigest()


def _parsed(data: bytes, path: Path) -> np.ndarray:
    header, body = _header(data, path)
    fields = header["FIELDS"]
    if not {"x", "y", "z"} <= set(fields):
        raise InputError(f"{path}: fields {' '.join(fields)} lack x, y, z; not a LiDAR scan")
    n = header["POINTS"]
    if header["DATA"] == "ascii":
        values = _ascii_values(body, n, header, path)
    elif header["DATA"] == "binary":
        values = _binary_values(body, n, header, path)
    else:
        raise InputError(f"{path}: DATA {header['DATA']} is not read (ascii or binary); convert the scan")
    xyz = np.stack([values["x"], values["y"], values["z"]], axis=1).astype(np.float32)
    if not np.isfinite(xyz).all():
        raise InputError(f"{path}: holds a non-finite coordinate; not a usable scan")
    out = np.empty((n, 4), dtype=np.float32)
    out[:, :3] = xyz
    out[:, 3] = _intensity(values, fields, path)
    return out


def _header(data: bytes, path: Path) -> tuple[dict, bytes]:
    """The checked header (FIELDS, SIZE, TYPE, COUNT as lists; POINTS an int; DATA) and the body."""
    end = data.find(b"DATA", 0, MAX_HEADER_BYTES)
    line_end = data.find(b"\n", end)
    if end < 0 or line_end < 0:
        raise InputError(f"{path}: no PCD header (no DATA line in its first {MAX_HEADER_BYTES} bytes)")
    try:
        lines = data[:line_end].decode("ascii").splitlines()
    except UnicodeDecodeError:
        raise InputError(f"{path}: its PCD header is not ASCII text") from None
    header: dict = {}
    for line in lines:
        key, _, value = line.strip().partition(" ")
        if key and not key.startswith("#"):
            header[key] = value.split()
    try:
        fields, sizes, types = header["FIELDS"], [int(v) for v in header["SIZE"]], header["TYPE"]
        counts = [int(v) for v in header.get("COUNT", ["1"] * len(fields))]
        points = int(header["POINTS"][0])
        data_kind = header["DATA"][0]
    except (KeyError, IndexError, ValueError):
        raise InputError(f"{path}: a PCD header needs FIELDS, SIZE, TYPE, POINTS and DATA") from None
    if not len(fields) == len(sizes) == len(types) == len(counts) or len(set(fields)) != len(fields):
        raise InputError(f"{path}: FIELDS, SIZE, TYPE and COUNT disagree in length (or a field repeats)")
    if any(c != 1 for c in counts):
        raise InputError(f"{path}: a field of COUNT other than 1 is not read")
    if any((t, s) not in _NUMPY_TYPE for t, s in zip(types, sizes)):
        raise InputError(f"{path}: field types {' '.join(f'{t}{s}' for t, s in zip(types, sizes))} are not read "
                         "(F4, F8, U1, U4, I4)")
    if not 0 <= points <= MAX_CLOUD_POINTS:
        raise InputError(f"{path}: declares {points} points (at most {MAX_CLOUD_POINTS}); not a recorded scan")
    width = int(header.get("WIDTH", [points])[0]) * int(header.get("HEIGHT", ["1"])[0])
    if width != points:
        raise InputError(f"{path}: WIDTH x HEIGHT ({width}) is not POINTS ({points})")
    return ({"FIELDS": fields, "SIZE": sizes, "TYPE": types, "POINTS": points, "DATA": data_kind},
            data[line_end + 1:])


def _ascii_values(body: bytes, n: int, header: dict, path: Path) -> dict[str, np.ndarray]:
    fields = header["FIELDS"]
    try:
        flat = np.array(body.split(), dtype=np.float64)
    except ValueError:
        raise InputError(f"{path}: a value of its ASCII body is not a number") from None
    if len(flat) != n * len(fields):
        raise InputError(f"{path}: {len(flat)} values where POINTS {n} x {len(fields)} fields declare {n * len(fields)}")
    table = flat.reshape(n, len(fields))
    out = {}
    for i, (name, kind, size) in enumerate(zip(fields, header["TYPE"], header["SIZE"])):
        if name == "rgb" and kind == "F":  # its bits matter: decoded in float64 arithmetic, see _float32_bits
            out[name] = _float32_bits(table[:, i], path)
        else:
            out[name] = table[:, i].astype(_NUMPY_TYPE[kind, size]) if kind != "F" else table[:, i].astype(
                np.float32 if size == 4 else np.float64)
    return out


def _float32_bits(value: np.ndarray, path: Path) -> np.ndarray:
    """(N,) uint32 bits of the float32 numbers written as text in ``value`` (N,) float64: a packed
    colour below r = 128 is a subnormal float32, which a cast would flush to zero where a library
    set the CPU's flush-to-zero mode (torch's threads do): the bits are computed in float64."""
    if not (np.isfinite(value).all() and (value >= 0).all() and (value < 2.0 ** -103).all()):
        raise InputError(f"{path}: an rgb value is not a packed colour (0x00RRGGBB as a float)")
    tiny = value < 2.0 ** -126
    bits = np.empty(len(value), dtype=np.uint32)
    bits[tiny] = np.rint(value[tiny] * 2.0 ** 149).astype(np.uint32)
    mant, exp = np.frexp(value[~tiny])  # value = mant * 2**exp, mant in [0.5, 1)
    bits[~tiny] = (((exp - 1 + 127).astype(np.uint32) << 23)
                   | np.rint((2.0 * mant - 1.0) * 2.0 ** 23).astype(np.uint32))
    return bits


def _binary_values(body: bytes, n: int, header: dict, path: Path) -> dict[str, np.ndarray]:
    dtype = np.dtype([(name, _NUMPY_TYPE[kind, size])
                      for name, kind, size in zip(header["FIELDS"], header["TYPE"], header["SIZE"])])
    if len(body) != n * dtype.itemsize:
        raise InputError(f"{path}: {len(body)} bytes of data where POINTS {n} declare {n * dtype.itemsize}")
    table = np.frombuffer(body, dtype=dtype, count=n)
    return {name: table[name] for name in header["FIELDS"]}


def _intensity(values: dict[str, np.ndarray], fields: list[str], path: Path) -> np.ndarray:
    """(N,) float32 intensity in [0, 1]: the red byte of a packed ``rgb`` / 255 (as OpenCOOD reads
    OPV2V), else an ``intensity`` field clipped to [0, 1], else zeros."""
    if "rgb" in fields:
        rgb = values["rgb"]
        packed = np.ascontiguousarray(rgb).view(np.uint32) if rgb.dtype == np.float32 else rgb.astype(np.uint32)
        return (((packed >> 16) & 0xFF).astype(np.float32) / np.float32(255.0)).astype(np.float32)
    if "intensity" in fields:
        level = values["intensity"].astype(np.float32)
        if not np.isfinite(level).all():
            raise InputError(f"{path}: holds a non-finite intensity")
        return np.clip(level, 0.0, 1.0)
    return np.zeros(len(values["x"]), dtype=np.float32)
