"""Ray-casting backends: Embree (embreex, the fast path) and trimesh's pure-Python intersector
(only to cross-check Embree in tests). Both answer the same question for a triangle soup:
the first hit distance along each ray and the hit triangle.
"""
from __future__ import annotations

import threading
from typing import Protocol

import numpy as np

from sumo_scenarios.errors import InputError


class Caster(Protocol):
    """Casters are safe to call from several threads at once (World casts a sensor's channels on
    two)."""

    def first_hits(self, origins: np.ndarray, directions: np.ndarray,
                   far: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) origins and unit directions → ((N,) distance, inf where missed; (N,) triangle index, -1).

        ``far`` (N,): ignore hits beyond this distance (lets the caster stop early)."""

    def first_prims(self, origins: np.ndarray, directions: np.ndarray, far: np.ndarray,
                    rows: np.ndarray | None = None) -> np.ndarray:
        """Only the index of the first triangle hit within ``far`` (-1: none): (N,), or (K,) for
        the rays ``rows`` (K,) int64 alone."""


class EmbreeCaster:
    """First hits through Intel Embree; triangles: (F, 3, 3) float, any frame.

    Cast in packets of 16 rays through the Embree 4 library embreex ships
    (:mod:`asg.sensors.embree`), or, where that library is not found, one ray at a time through
    embreex's ``EmbreeScene.run``; both answer the same.

    ``robust``: Embree's robust traversal (RTC_SCENE_FLAG_ROBUST, embreex's default), which keeps
    rays from slipping through the shared edge of two triangles; without it casts are faster (the
    measured trade-off: docs/lidar.md)."""

    def __init__(self, triangles: np.ndarray, robust: bool = True, packets: bool = True):
        from .embree import PacketScene, packet_library

        self.n_triangles = len(triangles)
        self._packets = None
        self._scene = None
        if not self.n_triangles:
            return
        library = packet_library() if packets else None
        if library is not None:
            self._packets = PacketScene(library, triangles, robust)
            return
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        self._scene = rtcore_scene.EmbreeScene(robust=robust)
        TriangleMesh(self._scene, np.ascontiguousarray(triangles, dtype=np.float32))

    def first_hits(self, origins: np.ndarray, directions: np.ndarray,
                   far: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        n = len(origins)
        if n == 0 or self.n_triangles == 0:
            return np.full(n, np.inf), np.full(n, -1, dtype=np.int64)
        dists = np.full(n, 1e30, dtype=np.float32) if far is None else _far32(far)
        origins32 = np.ascontiguousarray(origins, dtype=np.float32)
        directions32 = np.ascontiguousarray(directions, dtype=np.float32)
        if self._packets is not None:
            prim32, t32 = self._packets.cast(origins32, directions32, dists, want_distance=True)
        else:
            out = self._scene.run(origins32, directions32, dists=dists, output=1)
            prim32, t32 = out["primID"], out["tfar"]
        prim = prim32.astype(np.int64)
        t = t32.astype(np.float64)
        t[prim < 0] = np.inf
        return t, prim

    def first_prims(self, origins: np.ndarray, directions: np.ndarray, far: np.ndarray,
                    rows: np.ndarray | None = None) -> np.ndarray:
        """Triangle ids only, no per-ray distances, normals or barycentrics to convert (the
        renderer gets the distance from the triangle's plane); ``rows``: see :class:`Caster`
        (the packets read those rays in place, no gathered copy)."""
        count = len(origins) if rows is None else len(rows)
        if count == 0 or self.n_triangles == 0:
            return np.full(count, -1, dtype=np.int32)
        if self._packets is not None:
            return self._packets.cast(np.ascontiguousarray(origins, dtype=np.float32),
                                      np.ascontiguousarray(directions, dtype=np.float32), _far32(far),
                                      want_distance=False, rows=rows)[0]
        if rows is not None:
            origins, directions, far = origins[rows], directions[rows], far[rows]
        return self._scene.run(np.ascontiguousarray(origins, dtype=np.float32),
                               np.ascontiguousarray(directions, dtype=np.float32), dists=_far32(far))


def _far32(far: np.ndarray) -> np.ndarray:
    """Far limits as Embree takes them: a new contiguous float32 array (embreex writes each
    ray's hit distance into it), at most 1e30 (inf: none)."""
    return np.minimum(far, 1e30).astype(np.float32)


class TrimeshCaster:
    """First hits through trimesh's pure-Python ray-triangle test (about 200x slower than Embree).

    One cast at a time: trimesh finds candidate triangles in an R-tree of libspatialindex (rtree),
    whose queries share the index's memory pool and are not safe to run concurrently
    (libspatialindex issue 189, rtree issue 53), and rtree's ctypes calls release the GIL. Two
    threads querying one index corrupted the heap, which crashed the process later, wherever
    memory was next freed (the test suite's intermittent segmentation fault: the index freed by
    the garbage collector; reproduced every time by two threads casting through one caster).
    """

    def __init__(self, triangles: np.ndarray):
        import trimesh
        from trimesh.ray.ray_triangle import RayMeshIntersector

        self.n_triangles = len(triangles)
        self._lock = threading.Lock()
        if self.n_triangles:
            tri = np.asarray(triangles, dtype=np.float64)
            mesh = trimesh.Trimesh(vertices=tri.reshape(-1, 3), faces=np.arange(len(tri) * 3).reshape(-1, 3), process=False)
            self._ray = RayMeshIntersector(mesh)

    def first_hits(self, origins: np.ndarray, directions: np.ndarray,
                   far: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        n = len(origins)
        t = np.full(n, np.inf)
        prim = np.full(n, -1, dtype=np.int64)
        if n == 0 or self.n_triangles == 0:
            return t, prim
        with self._lock:
            tri_idx, ray_idx, locations = self._ray.intersects_id(origins, directions, multiple_hits=True,
                                                                  return_locations=True)
        if len(ray_idx):
            dist = np.einsum("ij,ij->i", locations - origins[ray_idx], directions[ray_idx])
            order = np.lexsort((dist, ray_idx))
            ray_sorted = ray_idx[order]
            first = np.r_[True, ray_sorted[1:] != ray_sorted[:-1]]
            sel = order[first]
            t[ray_idx[sel]] = dist[sel]
            prim[ray_idx[sel]] = tri_idx[sel]
        if far is not None:
            beyond = t > far
            t[beyond] = np.inf
            prim[beyond] = -1
        return t, prim

    def first_prims(self, origins: np.ndarray, directions: np.ndarray, far: np.ndarray,
                    rows: np.ndarray | None = None) -> np.ndarray:
        if rows is not None:
            origins, directions, far = origins[rows], directions[rows], far[rows]
        return self.first_hits(origins, directions, far)[1]


def make_caster(backend: str, triangles: np.ndarray, embree_robust: bool = True) -> Caster:
    if backend == "embree":
        return EmbreeCaster(triangles, robust=embree_robust)
    if backend == "trimesh":
        return TrimeshCaster(triangles)
    raise InputError(f"unknown ray-casting backend '{backend}'; use embree or trimesh")
