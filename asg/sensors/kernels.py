"""Compiled (numba) per-ray bookkeeping around the Embree cast of a full render.

Embree finds the first triangle each ray hits; everything else a render does per ray (choosing
which rays can hit an object at all, turning triangle ids into distances, surface
classes and incidence, and rays into points) is a loop over tens of thousands of rays. In numpy
each step is a pass over temporary arrays, and together they cost more than the cast itself; here
each is one compiled loop (``cache=True``: compiled once per installation, then loaded).

Ray index i = channel * azimuth_steps + column, as in :meth:`LidarSpec.directions`.

numba is pinned (pyproject.toml): its LLVM aborted the process compiling a boolean-mask selection
(``a[mask]``) inside a kernel here, so the kernels select with explicit loops.
"""
from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True, nogil=True)
def candidate_rays(lo: np.ndarray, hi: np.ndarray, r_min_m: np.ndarray, el_top_rad: np.ndarray,
                   reach_m: np.ndarray, el_rad: np.ndarray, reachable: np.ndarray, azimuth_steps: int,
                   first_channel: int, channel_step: int) -> np.ndarray:
    """Indices (K,) int64, ascending, of the rays of channels first_channel, first_channel +
    channel_step, ... that may hit one of M objects.

    Object k spans azimuth columns lo[k]..hi[k] (taken modulo ``azimuth_steps``), starts r_min_m[k]
    from the sensor (horizontally) and its top is seen at elevation el_top_rad[k]. Channel c
    reaches reach_m[c] horizontally and points at el_rad[c]. Ray (c, column) is a candidate if some
    object spanning the column starts within the channel's reach and rises to its elevation, and
    ``reachable`` (C * A,) bool allows it.
    """
    channels = len(reach_m)
    a = azimuth_steps
    mask = np.zeros(channels * a, dtype=np.bool_)
    for k in range(len(lo)):
        for c in range(first_channel, channels, channel_step):
            if reach_m[c] >= r_min_m[k] and el_rad[c] <= el_top_rad[k] + 1e-9:
                base = c * a
                for col in range(lo[k], hi[k] + 1):
                    mask[base + col % a] = True
    count = 0
    for i in range(channels * a):
        if mask[i] and reachable[i]:
            count += 1
    out = np.empty(count, dtype=np.int64)
    j = 0
    for i in range(channels * a):
        if mask[i] and reachable[i]:
            out[j] = i
            j += 1
    return out


@nb.njit(cache=True, nogil=True)
def take_hits(cand: np.ndarray, prim: np.ndarray, origin: np.ndarray, dirs: np.ndarray, tri_v0: np.ndarray,
              normals: np.ndarray, surface_of_tri: np.ndarray,
              hit_t_m: np.ndarray, hit_surface: np.ndarray, hit_cos: np.ndarray) -> None:
    """Write the hits of the candidate rays ``cand`` (triangle ``prim``, -1 = none) into one
    sensor's per-ray arrays: distance from the sensor ``origin`` (3,) to the hit triangle's plane
    along the ray, surface class and |cos incidence|.

    ``dirs`` (N, 3) the sensor's unit ray directions, ``tri_v0`` (F, 3) a vertex and ``normals``
    (F, 3) the unit normal of each triangle, all float64 in the network frame.
    """
    for i in range(len(cand)):
        p = prim[i]
        if p < 0:
            continue
        j = cand[i]
        dn = 0.0
        num = 0.0
        for d in range(3):
            dn += dirs[j, d] * normals[p, d]
            num += (tri_v0[p, d] - origin[d]) * normals[p, d]
        if abs(dn) < 1e-12:
            continue  # grazing the triangle's plane: no well-defined return
        hit_t_m[j] = num / dn
        hit_surface[j] = surface_of_tri[p]
        hit_cos[j] = abs(dn)


@nb.njit(cache=True, nogil=True)
def hits_to_points(t_m: np.ndarray, surface: np.ndarray, cos_inc: np.ndarray, dirs_sensor: np.ndarray,
                   reflectivity: np.ndarray, range_m: float) -> np.ndarray:
    """Points (K, 4) float32 of the rays with a hit within range: x, y, z = direction (sensor frame)
    x distance, intensity = reflectivity[surface] x |cos incidence|."""
    n = 0
    for i in range(len(t_m)):
        if t_m[i] <= range_m:
            n += 1
    out = np.empty((n, 4), dtype=np.float32)
    k = 0
    for i in range(len(t_m)):
        t = t_m[i]
        if t <= range_m:
            for d in range(3):
                out[k, d] = np.float32(np.float64(dirs_sensor[i, d]) * t)
            out[k, 3] = np.float32(reflectivity[surface[i]] * cos_inc[i])
            k += 1
    return out


@nb.njit(cache=True, nogil=True)
def outline_spans(outlines: np.ndarray, x_m: float, y_m: float, yaw_rad: float, azimuth_steps: int, range_m: float):
    """Azimuth column spans, in the frame of a sensor at (x_m, y_m) with yaw ``yaw_rad``, of ground
    outlines (M, K, 2) (network frame; shorter outlines padded by repeating their last vertex).

    Returns (lo, hi) column indices (M,) int64 (hi >= lo, to be taken modulo ``azimuth_steps``),
    the near and far distance (M,) of each outline (m), and (M,) bool: within range. The sensor
    must stand outside the outlines; an outline spanning more than half a turn gets every column.
    """
    m_count, k_count = outlines.shape[0], outlines.shape[1]
    a = azimuth_steps
    step = 2.0 * np.pi / a
    lo = np.empty(m_count, dtype=np.int64)
    hi = np.empty(m_count, dtype=np.int64)
    r_min = np.empty(m_count)
    r_max = np.empty(m_count)
    within = np.empty(m_count, dtype=np.bool_)
    for m in range(m_count):
        sx = 0.0
        sy = 0.0
        near2 = np.inf
        far2 = 0.0
        for k in range(k_count):
            x = outlines[m, k, 0] - x_m
            y = outlines[m, k, 1] - y_m
            sx += x
            sy += y
            nxt = (k + 1) % k_count
            ex = outlines[m, nxt, 0] - x_m - x
            ey = outlines[m, nxt, 1] - y_m - y
            tt = -(x * ex + y * ey) / max(ex * ex + ey * ey, 1e-12)
            tt = min(max(tt, 0.0), 1.0)
            px = x + tt * ex
            py = y + tt * ey
            near2 = min(near2, px * px + py * py)
            far2 = max(far2, x * x + y * y)
        centre = np.arctan2(sy / k_count, sx / k_count)
        d_min = np.inf
        d_max = -np.inf
        for k in range(k_count):
            ang = np.arctan2(outlines[m, k, 1] - y_m, outlines[m, k, 0] - x_m)
            delta = (ang - centre + np.pi) % (2.0 * np.pi) - np.pi
            d_min = min(d_min, delta)
            d_max = max(d_max, delta)
        base = centre - yaw_rad + np.pi
        lo_m = np.int64(np.floor((base + d_min) / step)) - 1
        hi_m = np.int64(np.ceil((base + d_max) / step)) + 1
        if hi_m - lo_m >= a - 1 or d_max - d_min > np.pi * 0.999:
            lo_m, hi_m = 0, a - 1
        lo[m] = lo_m
        hi[m] = hi_m
        r_min[m] = np.sqrt(near2)
        r_max[m] = np.sqrt(far2)
        within[m] = r_min[m] <= range_m
    return lo, hi, r_min, r_max, within


@nb.njit(cache=True, nogil=True)
def static_candidates(outlines: np.ndarray, tops_m: np.ndarray, skip: int, x_m: float, y_m: float, z_m: float,
                      yaw_rad: float, azimuth_steps: int, range_m: float, reach_m: np.ndarray, el_rad: np.ndarray,
                      reachable: np.ndarray, first_channel: int, channel_step: int) -> np.ndarray:
    """:func:`candidate_rays` for a sensor at (x_m, y_m, z_m) with yaw ``yaw_rad`` and objects
    given as ground outlines (M, K, 2) with top heights ``tops_m`` (M,), object ``skip`` (the
    sensor's own body; -1: none) left out. An object's top is seen at the elevation of its top
    edge at its near distance (top above the sensor) or far distance (below)."""
    lo, hi, r_min, r_max, keep = outline_spans(outlines, x_m, y_m, yaw_rad, azimuth_steps, range_m)
    if skip >= 0:
        keep[skip] = False
    el_top = np.empty(len(lo))
    n = 0
    for k in range(len(lo)):  # compact the kept objects in place (explicit loop: see the module notes)
        if keep[k]:
            dz = tops_m[k] - z_m
            el_top[n] = np.arctan2(dz, r_min[k] if dz > 0 else r_max[k])
            lo[n] = lo[k]
            hi[n] = hi[k]
            r_min[n] = r_min[k]
            n += 1
    return candidate_rays(lo[:n], hi[:n], r_min[:n], el_top[:n], reach_m, el_rad, reachable, azimuth_steps,
                          first_channel, channel_step)
