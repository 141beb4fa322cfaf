"""Binary PCD (v0.7) files of (N, 4) float32 x, y, z, intensity: readable by Open3D and PCL."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from sumo_scenarios.atomic import atomic_path
from sumo_scenarios.errors import InputError

from ..sensors.opv2v import pcd_intensity_levels

FIELDS = ("x", "y", "z", "intensity")


def write_pcd(path: str | Path, points: np.ndarray) -> None:
    """Write (N, 4) points as binary PCD, atomically."""
    pts = np.ascontiguousarray(points, dtype=np.float32).reshape(-1, 4)
    header = (
        "# .PCD v0.7 - Point Cloud Data file format\n"
        "VERSION 0.7\n"
        f"FIELDS {' '.join(FIELDS)}\n"
        "SIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
        f"WIDTH {len(pts)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\n"
        f"POINTS {len(pts)}\nDATA binary\n"
    )
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(header.encode("ascii"))
            fh.write(pts.tobytes())


def read_pcd(path: str | Path) -> np.ndarray:
    """Read a binary PCD with float32 x, y, z, intensity fields into (N, 4) float32."""
    data = Path(path).read_bytes()
    header = {}
    pos = 0
    while True:
        end = data.index(b"\n", pos)
        line = data[pos:end].decode("ascii").strip()
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, _, value = line.partition(" ")
        header[key] = value
        if key == "DATA":
            break
    if header.get("DATA") != "binary" or header.get("FIELDS", "").split() != list(FIELDS):
        raise InputError(f"{path}: only binary PCD with fields {' '.join(FIELDS)} is supported")
    n = int(header["POINTS"])
    return np.frombuffer(data[pos:pos + 16 * n], dtype=np.float32).reshape(n, 4).copy()


def write_pcd_rgb_intensity(path: str | Path, points: np.ndarray) -> None:
    """Write (N, 4) x, y, z, intensity as binary PCD with fields x y z rgb, the intensity (clipped to
    [0, 1]) in every colour channel: OpenCOOD's OPV2V loader reads intensity from Open3D's first
    colour channel and ignores an ``intensity`` field. Written atomically."""
    pts = np.asarray(points, dtype=np.float32).reshape(-1, 4)
    level = pcd_intensity_levels(pts[:, 3])
    packed = ((level << 16) | (level << 8) | level).view(np.float32)
    data = np.column_stack([pts[:, :3], packed]).astype(np.float32)
    header = (
        "# .PCD v0.7 - Point Cloud Data file format\n"
        "VERSION 0.7\nFIELDS x y z rgb\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n"
        f"WIDTH {len(data)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {len(data)}\nDATA binary\n"
    )
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(header.encode("ascii"))
            fh.write(np.ascontiguousarray(data).tobytes())
