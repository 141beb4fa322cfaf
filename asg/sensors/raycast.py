"""Ray-casting backends: Embree (embreex, the fast path) and trimesh's pure-Python intersector
(only to cross-check Embree in tests). Both answer the same question for a triangle soup:
the first hit distance along each ray and the hit triangle.
"""
from __future__ import annotations

from typing import Protocol

import numpy as np

from sumo_scenarios.errors import InputError


class Caster(Protocol):
    def first_hits(self, origins: np.ndarray, directions: np.ndarray,
                   far: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) origins and unit directions → ((N,) distance, inf where missed; (N,) triangle index, -1).

        ``far`` (N,): ignore hits beyond this distance (lets the caster stop early)."""

    def first_prims(self, origins: np.ndarray, directions: np.ndarray, far: np.ndarray) -> np.ndarray:
        """Only the (N,) index of the first triangle hit within ``far`` (-1: none)."""


class EmbreeCaster:
    """First hits through Intel Embree (embreex); triangles: (F, 3, 3) float, any frame.

    ``robust``: Embree's robust traversal (RTC_SCENE_FLAG_ROBUST, embreex's default), which keeps
    rays from slipping through the shared edge of two triangles; without it casts are faster (the
    measured trade-off: docs/lidar.md)."""

    def __init__(self, triangles: np.ndarray, robust: bool = True):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        self.n_triangles = len(triangles)
        self._scene = rtcore_scene.EmbreeScene(robust=robust)
        if self.n_triangles:
            TriangleMesh(self._scene, np.ascontiguousarray(triangles, dtype=np.float32))

    def first_hits(self, origins: np.ndarray, directions: np.ndarray,
                   far: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        n = len(origins)
        if n == 0 or self.n_triangles == 0:
            return np.full(n, np.inf), np.full(n, -1, dtype=np.int64)
        dists = None if far is None else np.ascontiguousarray(np.minimum(far, 1e30), dtype=np.float32)
        out = self._scene.run(np.ascontiguousarray(origins, dtype=np.float32),
                              np.ascontiguousarray(directions, dtype=np.float32), dists=dists, output=1)
        prim = out["primID"].astype(np.int64)
        t = out["tfar"].astype(np.float64)
        t[prim < 0] = np.inf
        return t, prim

    def first_prims(self, origins: np.ndarray, directions: np.ndarray, far: np.ndarray) -> np.ndarray:
        """Embree's plain intersect query: triangle ids only, no per-ray distances, normals or
        barycentrics to convert (the renderer gets the distance from the triangle's plane)."""
        if len(origins) == 0 or self.n_triangles == 0:
            return np.full(len(origins), -1, dtype=np.int32)
        if far.dtype != np.float32 or far.max() > 1e30:
            far = np.minimum(far, 1e30).astype(np.float32)
        return self._scene.run(np.ascontiguousarray(origins, dtype=np.float32),
                               np.ascontiguousarray(directions, dtype=np.float32), dists=np.ascontiguousarray(far))


class TrimeshCaster:
    """First hits through trimesh's pure-Python ray-triangle test (about 200x slower than Embree)."""

    def __init__(self, triangles: np.ndarray):
        import trimesh
        from trimesh.ray.ray_triangle import RayMeshIntersector

        self.n_triangles = len(triangles)
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
        tri_idx, ray_idx, locations = self._ray.intersects_id(origins, directions, multiple_hits=True, return_locations=True)
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

    def first_prims(self, origins: np.ndarray, directions: np.ndarray, far: np.ndarray) -> np.ndarray:
        return self.first_hits(origins, directions, far)[1]


def make_caster(backend: str, triangles: np.ndarray, embree_robust: bool = True) -> Caster:
    if backend == "embree":
        return EmbreeCaster(triangles, robust=embree_robust)
    if backend == "trimesh":
        return TrimeshCaster(triangles)
    raise InputError(f"unknown ray-casting backend '{backend}'; use embree or trimesh")
