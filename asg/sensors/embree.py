"""Intel Embree 4 called directly: scenes built through ctypes, rays cast in packets of 16.

embreex (a dependency) ships Embree 4 as a shared library (``embreex.libs/libembree4-*.so.4``)
but its ``EmbreeScene.run`` casts one ray at a time (``rtcIntersect1`` in a loop). A LiDAR's
rays come in coherent fans (neighbouring azimuths of one channel), which Embree traverses
together when given as a packet: ``rtcIntersect16`` from a compiled loop casts the same rays
2.5x faster than embreex on the benchmark frame, hitting the same surfaces (measured:
docs/lidar.md). This module binds the few Embree calls that needs (device, scene, one
triangle geometry, commit, ``rtcIntersect16``); :func:`packet_library` returns None where
that library is not found (another platform's wheel layout, an Embree 2/3 build of embreex),
and the caster then falls back to embreex's own ``run``.

Ray/hit packet layout (``RTCRayHit16``, embree4/rtcore_ray.h, 64-byte aligned), in 32-bit
words: org_x, org_y, org_z, tnear, dir_x, dir_y, dir_z, time, tfar, mask, id, flags (16 words
each, words 0-191), then the hit: Ng_x, Ng_y, Ng_z, u, v, primID (word 272), geomID (word
288), instance ids (their count depends on Embree's build, 1 by default: the buffer has room for 22).
"""
from __future__ import annotations

import ctypes
import glob
import os
from pathlib import Path

import numba as nb
import numpy as np

#: 32-bit words of one packet buffer: RTCRayHit16 with room for up to 22 instance levels
_PACKET_WORDS = 1024
_TFAR, _MASK, _PRIM, _GEOM = 128, 144, 272, 288
_NO_HIT = 0xFFFFFFFF
# Embree 4 enums (embree4/rtcore_*.h)
_GEOMETRY_TRIANGLE = 0
_BUFFER_INDEX, _BUFFER_VERTEX = 0, 1
_FORMAT_UINT3, _FORMAT_FLOAT3 = 0x5003, 0x9003
_SCENE_FLAG_ROBUST = 1 << 2
#: RTC_RAY_QUERY_FLAG_COHERENT: the packets are fans of neighbouring rays, which Embree then
#: traverses as one frustum per direction octant (2.2x faster than without, measured: docs/lidar.md)
_QUERY_FLAGS = 1 << 16
#: direction components smaller than this are cast as +-this: Embree's reciprocal of a component
#: below 1e-18 loses its sign, and the coherent traversal, which splits a packet by the signs of
#: the directions, then culled such a ray (one of -5e-33, from a sensor yawed exactly -90 deg,
#: missed a wall). A tilt of at most 1e-6 rad: 70 um at 70 m.
_MIN_COMPONENT = 1e-6

_P, _S = ctypes.c_void_p, ctypes.c_size_t
#: rtcIntersect16(valid, scene, rayhit, args): pointers passed as integers (same ABI on x86-64)
INTERSECT16_TYPE = ctypes.CFUNCTYPE(None, _S, _S, _S, _S)


class _Library:
    """The bound Embree 4 library and this process's device."""

    def __init__(self, path: str):
        lib = ctypes.CDLL(path)
        signatures = {
            "rtcNewDevice": (_P, [ctypes.c_char_p]), "rtcNewScene": (_P, [_P]),
            "rtcSetSceneFlags": (None, [_P, ctypes.c_int]), "rtcNewGeometry": (_P, [_P, ctypes.c_int]),
            "rtcSetSharedGeometryBuffer": (None, [_P, ctypes.c_int, ctypes.c_uint, ctypes.c_int, _P, _S, _S, _S]),
            "rtcCommitGeometry": (None, [_P]), "rtcAttachGeometry": (ctypes.c_uint, [_P, _P]),
            "rtcReleaseGeometry": (None, [_P]), "rtcCommitScene": (None, [_P]),
            "rtcReleaseScene": (None, [_P]), "rtcGetDeviceError": (ctypes.c_int, [_P]),
        }
        for name, (restype, argtypes) in signatures.items():
            fn = getattr(lib, name)
            fn.restype, fn.argtypes = restype, argtypes
        self.lib = lib
        self.pid = os.getpid()
        self.device = lib.rtcNewDevice(None)
        if not self.device:
            raise RuntimeError(f"Embree: rtcNewDevice failed ({path})")
        self.intersect16 = INTERSECT16_TYPE(ctypes.cast(lib.rtcIntersect16, _P).value)

    def check(self, what: str) -> None:
        code = self.lib.rtcGetDeviceError(self.device)
        if code:
            raise RuntimeError(f"Embree: {what} failed (RTCError {code})")


_LIBRARY: _Library | None = None
_SEARCHED = False


def _library_path() -> str | None:
    """libembree4 as the embreex wheel installs it, or None."""
    try:
        import embreex
    except ImportError:
        return None
    root = Path(embreex.__file__).resolve().parent
    found = sorted(glob.glob(str(root.parent / "embreex.libs" / "libembree4*.so*")))
    return found[0] if found else None


def packet_library() -> _Library | None:
    """This process's Embree 4 device (made on first use, and again in a forked child: a device's
    threads do not survive a fork), or None when embreex's library is not where a Linux wheel
    puts it."""
    global _LIBRARY, _SEARCHED
    if _LIBRARY is not None and _LIBRARY.pid == os.getpid():
        return _LIBRARY
    if _SEARCHED and _LIBRARY is None:
        return None
    _SEARCHED = True
    path = _library_path()
    _LIBRARY = _Library(path) if path else None
    return _LIBRARY


class PacketScene:
    """One Embree scene of a triangle soup (F, 3, 3), any frame; cast with :meth:`cast`."""

    def __init__(self, library: _Library, triangles: np.ndarray, robust: bool):
        self._library = library
        lib = library.lib
        # the vertex buffer is read with 16-byte loads: one spare vertex after the last
        self._vertices = np.zeros((len(triangles) * 3 + 1, 3), dtype=np.float32)
        self._vertices[:-1] = np.asarray(triangles, dtype=np.float32).reshape(-1, 3)
        self._indices = np.arange(len(triangles) * 3, dtype=np.uint32).reshape(-1, 3)
        self._scene = lib.rtcNewScene(library.device)
        if robust:
            lib.rtcSetSceneFlags(self._scene, _SCENE_FLAG_ROBUST)
        geometry = lib.rtcNewGeometry(library.device, _GEOMETRY_TRIANGLE)
        lib.rtcSetSharedGeometryBuffer(geometry, _BUFFER_VERTEX, 0, _FORMAT_FLOAT3, self._vertices.ctypes.data,
                                       0, 12, len(triangles) * 3)
        lib.rtcSetSharedGeometryBuffer(geometry, _BUFFER_INDEX, 0, _FORMAT_UINT3, self._indices.ctypes.data,
                                       0, 12, len(triangles))
        lib.rtcCommitGeometry(geometry)
        lib.rtcAttachGeometry(self._scene, geometry)
        lib.rtcReleaseGeometry(geometry)
        lib.rtcCommitScene(self._scene)
        library.check("building a scene")

    def cast(self, origins: np.ndarray, directions: np.ndarray, far: np.ndarray, want_distance: bool,
             rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
        """(N, 3) float32 origins and unit directions, (N,) float32 far limits; ``rows`` (K,) int64:
        cast only these rays (default all) → ((K,) int32 triangle hit first, -1: none; (K,) float32
        its distance (tfar) or None)."""
        rows = np.arange(len(far)) if rows is None else rows
        prim = np.empty(len(rows), dtype=np.int32)
        t = np.empty(len(rows) if want_distance else 0, dtype=np.float32)
        cast_packets(self._library.intersect16, self._scene, rows, origins, directions, far, prim, t)
        return prim, (t if want_distance else None)

    def __del__(self):
        try:
            if self._scene and self._library.pid == os.getpid():
                self._library.lib.rtcReleaseScene(self._scene)
        except Exception:  # a half-made scene, or the interpreter shutting down
            pass


@nb.njit(cache=True, nogil=True)
def cast_packets(intersect16, scene: int, rows: np.ndarray, origins: np.ndarray, directions: np.ndarray,
                 far: np.ndarray, prim_out: np.ndarray, t_out: np.ndarray) -> None:
    """Cast rays ``rows`` (K,) int64 of ``origins``, ``directions`` (N, 3) float32 and ``far`` (N,)
    float32, in packets of 16 consecutive rows, through ``intersect16`` (rtcIntersect16) on
    ``scene``; writes row k's first triangle hit (or -1) to ``prim_out[k]`` (K,) int32 and, if
    ``t_out`` has K entries, its distance to ``t_out[k]`` float32."""
    # one 64-byte aligned block: the packet, then the valid mask, then the query arguments
    buf = np.zeros(_PACKET_WORDS + 16 + 16 + 16, dtype=np.float32)
    start = (64 - buf.ctypes.data % 64) % 64 // 4
    ray = buf[start:start + _PACKET_WORDS]
    word = ray.view(np.uint32)
    valid = buf[start + _PACKET_WORDS:start + _PACKET_WORDS + 16].view(np.int32)
    args = buf[start + _PACKET_WORDS + 16:start + _PACKET_WORDS + 32].view(np.uint32)
    args[0] = _QUERY_FLAGS
    args[1] = 0xFFFFFFFF  # every feature
    n = len(rows)
    with_t = len(t_out) == n
    for first in range(0, n, 16):
        m = min(16, n - first)
        for k in range(16):
            if k < m:
                i = rows[first + k]
                ray[k], ray[16 + k], ray[32 + k], ray[48 + k] = origins[i, 0], origins[i, 1], origins[i, 2], 0.0
                for axis in range(3):
                    d = directions[i, axis]
                    if abs(d) < _MIN_COMPONENT:
                        d = _MIN_COMPONENT if d >= 0.0 else -_MIN_COMPONENT
                    ray[64 + 16 * axis + k] = d
                ray[112 + k], ray[_TFAR + k] = 0.0, far[i]
                word[_MASK + k], word[_MASK + 16 + k], word[_MASK + 32 + k] = _NO_HIT, 0, 0
                word[_PRIM + k], word[_GEOM + k] = _NO_HIT, _NO_HIT
                valid[k] = -1
            else:
                valid[k] = 0
        intersect16(valid.ctypes.data, scene, ray.ctypes.data, args.ctypes.data)
        for k in range(m):
            hit = word[_GEOM + k] != _NO_HIT
            prim_out[first + k] = np.int32(word[_PRIM + k]) if hit else -1
            if with_t:
                t_out[first + k] = ray[_TFAR + k]
