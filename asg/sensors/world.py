"""The 3D world of a scene and its LiDAR rendering.

A :class:`World` holds, in the network frame (x east, y north, z up, metres):
- the ground: the plane z = 0, intersected analytically (no triangles needed);
- a *static* Embree scene: buildings and every agent that will not move;
- *movable* agents (the ones a search may perturb): each is cast in its own local frame against a
  shared per-class template mesh (instancing by hand), so moving one never rebuilds anything.

A sensor never sees its own body: its rays start where they leave its own footprint prism.
Rendering casts only the rays that can hit something above the ground: a ray is a candidate if
some object spanning its azimuth column starts within the ray's horizontal reach (before the
ground or the range) and rises to the ray's elevation; each cast ray stops at its ground hit
(Embree's tfar); the rest are ground hits or misses. Candidate rays
of all sensors go to Embree in one batch split evenly over two threads (embreex releases the GIL).
Static results are cached per sensor, so a re-render after moving vehicles costs only the moved
vehicles' rays, independent of the number of buildings.
"""
from __future__ import annotations

import math
import zlib
from dataclasses import dataclass
from typing import Iterable, Mapping

import numpy as np

from sumo_scenarios.errors import InputError

from ..scene import Agent, Scene
from .lidar_spec import LidarSpec
from .meshes import REFLECTIVITY, SURFACES, agent_template, building_mesh
from .raycast import Caster, make_caster


@dataclass(frozen=True)
class SensorPose:
    """A LiDAR origin in the network frame and its yaw (x forward)."""

    x_m: float
    y_m: float
    z_m: float
    yaw_rad: float

    @property
    def origin(self) -> np.ndarray:
        return np.array([self.x_m, self.y_m, self.z_m])

    def rotation(self) -> np.ndarray:
        """(3, 3) sensor → network rotation."""
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def sensor_pose(agent: Agent, spec: LidarSpec) -> SensorPose:
    """Vehicle LiDAR on the roof (``vehicle_mount_above_roof_m`` above it); RSU LiDAR atop its pole."""
    if agent.kind == "rsu":
        return SensorPose(agent.x_m, agent.y_m, agent.z_m + agent.height_m, agent.yaw_rad)
    return SensorPose(agent.x_m, agent.y_m, agent.z_m + agent.height_m + spec.vehicle_mount_above_roof_m, agent.yaw_rad)


@dataclass
class _Hits:
    """Per-ray first hits of one sensor: distance (inf = none), surface class, |cos incidence|."""

    t: np.ndarray
    surface: np.ndarray
    cos_inc: np.ndarray

    def copy(self) -> "_Hits":
        return _Hits(self.t.copy(), self.surface.copy(), self.cos_inc.copy())

    def take(self, idx: np.ndarray, t: np.ndarray, surface: int | np.ndarray, cos_inc: np.ndarray) -> None:
        closer = t < self.t[idx]
        sel = idx[closer]
        self.t[sel] = t[closer]
        self.surface[sel] = surface if np.isscalar(surface) else surface[closer]
        self.cos_inc[sel] = cos_inc[closer]


@dataclass
class _SensorRays:
    """One sensor's rays, which depend only on its pose (network frame).

    ``t_start``: where each ray leaves the sensor's own footprint prism (a sensor never sees its
    own body); ``starts32``: the ray origins moved there.
    """

    pose: SensorPose
    dirs_w: np.ndarray
    dirs32: np.ndarray
    starts32: np.ndarray
    t_start: np.ndarray
    #: (N,) distance to the ground plane (inf: never, or under the own body)
    t_ground: np.ndarray
    #: (N,) where a static hit stops mattering: min(ground, range)
    t_limit: np.ndarray

    @staticmethod
    def make(agent: Agent, spec: LidarSpec, dirs_sensor: np.ndarray) -> "_SensorRays":
        pose = sensor_pose(agent, spec)
        dirs_w = dirs_sensor @ pose.rotation().T
        half_l, half_w = (0.2, 0.2) if agent.kind == "rsu" else (agent.length_m / 2, agent.width_m / 2)
        with np.errstate(divide="ignore"):
            # 2 cm past the footprint: a ray leaving it exactly on a face could hit the own body
            t_start = np.minimum(half_l / np.abs(dirs_sensor[:, 0]), half_w / np.abs(dirs_sensor[:, 1])) + 0.02
            dz = dirs_w[:, 2]
            t_ground = np.where(dz < -1e-9, pose.z_m / -np.minimum(dz, -1e-9), np.inf)
        t_ground[t_ground < t_start] = np.inf  # the ground under the own body is not visible
        starts = pose.origin + dirs_w * t_start[:, None]
        return _SensorRays(pose, dirs_w, dirs_w.astype(np.float32), starts.astype(np.float32), t_start,
                           t_ground, np.minimum(t_ground, spec.range_m))


class _Template:
    """A template mesh with its caster, unit normals and surface class."""

    def __init__(self, mesh, backend: str):
        tri = mesh.vertices[mesh.faces]
        self.caster: Caster = make_caster(backend, tri)
        self.normals = np.asarray(mesh.face_normals, dtype=np.float64)
        self.surface = int(mesh.metadata.get("surface", SURFACES["vehicle"]))


class World:
    """A scene's world for LiDAR rendering; see the module docstring.

    ``movable_ids``: agents a search may move (never sensing agents). Every other agent is baked
    into the static scene and cannot move afterwards.
    """

    def __init__(self, scene: Scene, spec: LidarSpec, movable_ids: Iterable[str] = ()):
        spec.validate()
        self.scene = scene
        self.spec = spec
        self.movable_ids = frozenset(movable_ids)
        unknown = self.movable_ids - {a.agent_id for a in scene.agents}
        if unknown:
            raise InputError(f"scene {scene.scene_id}: no agent '{sorted(unknown)[0]}'")
        self._dirs_sensor = spec.directions()
        self._dirs_sensor32 = self._dirs_sensor.astype(np.float32)
        self._el = np.repeat(spec.elevations_rad(), spec.azimuth_steps)
        self._cos_el = np.cos(self._el)
        self._templates: dict[tuple, _Template] = {}
        self._build_static()
        self._base_cache: dict[str, _Hits] = {}
        self._ray_cache: dict[str, _SensorRays] = {}

    # ---- construction ----------------------------------------------------------------------
    def _template(self, a: Agent) -> _Template:
        key = (a.kind, a.type_id, round(a.length_m, 3), round(a.width_m, 3), round(a.height_m, 3))
        if key not in self._templates:
            self._templates[key] = _Template(agent_template(a.type_id, a.kind, a.length_m, a.width_m, a.height_m), self.spec.backend)
        return self._templates[key]

    def _build_static(self) -> None:
        tris, normals, surfaces, outlines, tops = [], [], [], [], []
        self._static_index: dict[str, int] = {}
        for b in self.scene.buildings:
            m = building_mesh(b)
            tris.append(m.vertices[m.faces])
            normals.append(m.face_normals)
            surfaces.append(np.full(len(m.faces), SURFACES["building"], dtype=np.int8))
            outlines.append(np.asarray(b.footprint_xy, dtype=float))
            tops.append(b.height_m)
        for a in self.scene.agents:
            if a.agent_id in self.movable_ids:
                continue
            mesh = agent_template(a.type_id, a.kind, a.length_m, a.width_m, a.height_m)
            rot, off = _pose_rt(a)
            tris.append(mesh.vertices[mesh.faces] @ rot.T + off)
            normals.append(mesh.face_normals @ rot.T)
            surfaces.append(np.full(len(mesh.faces), mesh.metadata["surface"], dtype=np.int8))
            self._static_index[a.agent_id] = len(outlines)
            outlines.append(a.footprint_xy())
            tops.append(a.z_m + a.height_m)
        self._static_tris = np.concatenate(tris) if tris else np.zeros((0, 3, 3))
        self._static_normals32 = (np.concatenate(normals) if normals else np.zeros((0, 3))).astype(np.float32)
        self._static_surface = np.concatenate(surfaces) if surfaces else np.zeros(0, dtype=np.int8)
        self._static = make_caster(self.spec.backend, self._static_tris)
        self._static_outlines = _pad_outlines(outlines)
        self._static_tops = np.asarray(tops, dtype=float)

    # ---- rendering ---------------------------------------------------------------------------
    def sensor_pose(self, agent_id: str) -> SensorPose:
        return sensor_pose(self.scene.agent(agent_id), self.spec)

    def render(self, sensor_id: str, moved: Mapping[str, Agent] | None = None, seed: int = 0) -> np.ndarray:
        """Points (N, 4) float32 of one sensor; see :meth:`render_many`."""
        return self.render_many([sensor_id], moved, seed)[sensor_id]

    def render_many(self, sensor_ids: Iterable[str], moved: Mapping[str, Agent] | None = None,
                    seed: int = 0) -> dict[str, np.ndarray]:
        """Points (N, 4) float32 per sensor: x, y, z in that sensor's frame, intensity in [0, 1].

        ``moved``: new poses of movable agents by id; the others stay as in the scene.
        Intensity = reflectivity of the surface class (ground 0.20, building 0.35, vehicle 0.60,
        pole 0.50) x |cos(incidence angle)|. Noise and drop-off (if the spec has them) are drawn
        from a generator seeded by (``seed``, sensor id).
        """
        sensor_ids = list(sensor_ids)
        moved = dict(moved or {})
        bad = set(moved) - self.movable_ids
        if bad:
            raise ValueError(f"agents {sorted(bad)} are baked into the static world; pass them as movable_ids")
        if self.movable_ids & set(sensor_ids):
            raise ValueError("a sensing agent cannot be movable")
        self._fill_base(sensor_ids)
        out = {}
        for sid in sensor_ids:
            hits = self._base_cache[sid]
            if self.movable_ids:
                hits = hits.copy()
                rays = self._rays(sid)
                for aid in sorted(self.movable_ids):
                    self._cast_instance(moved.get(aid) or self.scene.agent(aid), rays.pose, rays.dirs_w, hits)
            out[sid] = self._to_points(sid, hits, seed)
        return out

    def _rays(self, sensor_id: str) -> "_SensorRays":
        if sensor_id not in self._ray_cache:
            self._ray_cache[sensor_id] = _SensorRays.make(self.scene.agent(sensor_id), self.spec, self._dirs_sensor)
        return self._ray_cache[sensor_id]

    def prepare(self, sensor_ids: Iterable[str]) -> None:
        """Generate the rays of these sensors now (their poses are fixed for the World's life)."""
        for sid in sensor_ids:
            self._rays(sid)

    def _fill_base(self, sensor_ids: list[str]) -> None:
        """Cache ground + static hits for the sensors that have none yet: every sensor's candidate
        rays go to Embree in one batch, split evenly over two threads."""
        todo = [s for s in dict.fromkeys(sensor_ids) if s not in self._base_cache]
        if not todo:
            return
        rays = [self._rays(sid) for sid in todo]
        cands = [self._candidates(r.pose, r.t_limit, self._static_index.get(sid), r.t_start < r.t_limit)
                 for sid, r in zip(todo, rays)]
        starts = np.concatenate([np.take(r.starts32, c, axis=0) for r, c in zip(rays, cands)])
        dirs = np.concatenate([np.take(r.dirs32, c, axis=0) for r, c in zip(rays, cands)])
        far = np.concatenate([np.take(r.t_limit - r.t_start, c) for r, c in zip(rays, cands)])
        t_all, prim_all = _cast_split(self._static, starts, dirs, far)
        start = 0
        for sid, r, cand in zip(todo, rays, cands):
            end = start + len(cand)
            hits = _Hits(r.t_ground.copy(), np.full(len(r.t_ground), SURFACES["ground"], dtype=np.int8),
                         np.abs(r.dirs_w[:, 2]))
            t, prim = t_all[start:end], prim_all[start:end]
            ok = np.flatnonzero(prim >= 0)
            sel = cand[ok]
            pp = prim[ok]
            hits.t[sel] = t[ok] + r.t_start[sel]
            hits.surface[sel] = np.take(self._static_surface, pp)
            hits.cos_inc[sel] = np.abs(np.einsum("ij,ij->i", np.take(dirs[start:end], ok, axis=0),
                                                 np.take(self._static_normals32, pp, axis=0)))
            self._base_cache[sid] = hits
            start = end

    def _candidates(self, pose: SensorPose, t_now: np.ndarray, own: int | None, reachable: np.ndarray) -> np.ndarray:
        """Indices of rays that may hit a static object (but ``own``, the sensor's body) before ``t_now``.

        ``t_now`` (channels * azimuth_steps,) must depend on the channel only (ground or range
        limit), which makes each channel's horizontal reach R_c a constant. A ray (channel c,
        column) is a candidate if some object spanning that column starts within R_c and its top
        reaches at least the ray's elevation.
        """
        spec = self.spec
        A, C = spec.azimuth_steps, spec.channels
        if not len(self._static_outlines):
            return np.zeros(0, dtype=np.int64)
        lo, hi, r_min, r_max, ok = _spans(self._static_outlines, pose, A, spec.range_m)
        if own is not None:
            ok[own] = False
        if not ok.any():
            return np.zeros(0, dtype=np.int64)
        lo, hi, r_min, r_max, tops = lo[ok], hi[ok], r_min[ok], r_max[ok], self._static_tops[ok]
        dz = tops - pose.z_m
        el_top = np.arctan2(dz, np.where(dz > 0, r_min, r_max))
        reach = (t_now * self._cos_el).reshape(C, A).max(axis=1)  # (C,) horizontal reach per channel
        order = np.argsort(reach, kind="stable")
        rank = np.empty(C, dtype=np.int64)
        rank[order] = np.arange(C)
        first = np.searchsorted(reach[order], r_min, side="left")  # first rank that reaches each object
        live = first < C
        lo, hi, first, el_top = lo[live], hi[live], first[live], el_top[live]
        lengths = hi - lo + 1
        offsets = np.arange(lengths.sum()) - np.repeat(np.cumsum(lengths) - lengths, lengths)
        cols = (np.repeat(lo, lengths) + offsets) % A
        top = np.full((C, A), -np.inf)
        np.maximum.at(top, (np.repeat(first, lengths), cols), np.repeat(el_top, lengths))
        np.maximum.accumulate(top, axis=0, out=top)  # rank j: every object reached by rank <= j
        mask = self._el.reshape(C, A) <= top[rank] + 1e-9
        mask &= reachable.reshape(C, A)
        return np.flatnonzero(mask)

    def _cast_instance(self, agent: Agent, pose: SensorPose, dirs_w: np.ndarray, hits: _Hits) -> None:
        """Cast the rays that may reach ``agent`` in its local frame against its class template."""
        A = self.spec.azimuth_steps
        lo, hi, r_min, r_max, ok = _spans(agent.footprint_xy()[None], pose, A, self.spec.range_m)
        if not ok[0]:
            return
        cols = np.arange(lo[0], hi[0] + 1) % A
        idx = (np.arange(self.spec.channels)[:, None] * A + cols[None, :]).ravel()
        dz = agent.z_m + agent.height_m - pose.z_m
        el_top = math.atan2(dz, r_min[0] if dz > 0 else r_max[0])
        horiz = np.minimum(hits.t[idx], self.spec.range_m) * self._cos_el[idx]
        idx = idx[(horiz >= r_min[0]) & (self._el[idx] <= el_top + 1e-9)]
        if not len(idx):
            return
        tpl = self._template(agent)
        rot, off = _pose_rt(agent)
        o_local = (pose.origin - off) @ rot
        d_local = dirs_w[idx] @ rot
        t, prim = tpl.caster.first_hits(np.broadcast_to(o_local, (len(idx), 3)), d_local,
                                        np.minimum(hits.t[idx], self.spec.range_m))
        ok = prim >= 0
        cos_inc = np.abs(np.einsum("ij,ij->i", d_local[ok], tpl.normals[prim[ok]]))
        hits.take(idx[ok], t[ok], tpl.surface, cos_inc)

    def _to_points(self, sensor_id: str, hits: _Hits, seed: int) -> np.ndarray:
        spec = self.spec
        t = hits.t
        valid = t <= spec.range_m
        if spec.noise_std_m > 0 or spec.dropoff > 0:
            rng = np.random.default_rng([seed, zlib.crc32(sensor_id.encode())])
            noise = rng.normal(0.0, spec.noise_std_m, len(t)) if spec.noise_std_m > 0 else 0.0
            keep = rng.random(len(t)) >= spec.dropoff
            t = t + noise
            valid &= keep & (t > 0)
        idx = np.flatnonzero(valid)
        out = np.empty((len(idx), 4), dtype=np.float32)
        out[:, :3] = np.take(self._dirs_sensor32, idx, axis=0)
        out[:, :3] *= np.take(t, idx)[:, None]
        out[:, 3] = np.take(REFLECTIVITY, np.take(hits.surface, idx)) * np.take(hits.cos_inc, idx)
        return out

    # ---- exports -----------------------------------------------------------------------------
    def world_triangles(self, moved: Mapping[str, Agent] | None = None) -> np.ndarray:
        """(F, 3, 3) every triangle of the world in the network frame (buildings, all agents), plus
        a ground square under the scene: what an external ray caster needs to render the same world."""
        from .meshes import ground_mesh

        moved = moved or {}
        tris = [self._static_tris]
        for aid in sorted(self.movable_ids):
            a = moved.get(aid) or self.scene.agent(aid)
            mesh = agent_template(a.type_id, a.kind, a.length_m, a.width_m, a.height_m)
            rot, off = _pose_rt(a)
            tris.append(mesh.vertices[mesh.faces] @ rot.T + off)
        ego = self.scene.ego
        g = ground_mesh((ego.x_m, ego.y_m), 2 * self.spec.range_m + 200.0)
        tris.append(g.vertices[g.faces])
        return np.concatenate(tris)

    def rays_world(self, sensor_id: str) -> tuple[np.ndarray, np.ndarray]:
        """(origins (N, 3), directions (N, 3)) of one sweep of ``sensor_id`` in the network frame."""
        rays = self._rays(sensor_id)
        return np.broadcast_to(rays.pose.origin, rays.dirs_w.shape).copy(), rays.dirs_w.copy()


_POOL = None


def _cast_split(caster: Caster, origins: np.ndarray, directions: np.ndarray, far: np.ndarray):
    """``caster.first_hits`` with the rays split in two halves, one on a worker thread (embreex
    releases the GIL while it casts)."""
    global _POOL
    n = len(origins)
    if n < 2048:
        return caster.first_hits(origins, directions, far)
    from concurrent.futures import ThreadPoolExecutor

    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=1, thread_name_prefix="asg-lidar")
    h = n // 2
    other = _POOL.submit(caster.first_hits, origins[h:], directions[h:], far[h:])
    t0, p0 = caster.first_hits(origins[:h], directions[:h], far[:h])
    t1, p1 = other.result()
    return np.concatenate([t0, t1]), np.concatenate([p0, p1])


def _pose_rt(a: Agent) -> tuple[np.ndarray, np.ndarray]:
    c, s = math.cos(a.yaw_rad), math.sin(a.yaw_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]), np.array([a.x_m, a.y_m, a.z_m])


def _pad_outlines(outlines: list[np.ndarray]) -> np.ndarray:
    """Stack outlines of K_i vertices into (M, K, 2), repeating each one's last vertex."""
    if not outlines:
        return np.zeros((0, 3, 2))
    k = max(len(o) for o in outlines)
    return np.stack([np.vstack([o, np.repeat(o[-1:], k - len(o), axis=0)]) for o in outlines])


def _spans(outlines: np.ndarray, pose: SensorPose, A: int, range_m: float):
    """Azimuth column spans (sensor frame) of ground outlines (M, K, 2), vectorised.

    Returns (lo, hi) column indices (hi >= lo, to be taken modulo A), the near and far distance
    (m) of each outline, and a mask of the outlines within range. The sensor must stand outside
    the outlines (its own body is excluded by the caller); an outline spanning more than half a
    turn gets every column.
    """
    rel = outlines - np.array([pose.x_m, pose.y_m])
    x, y = rel[..., 0], rel[..., 1]
    ex = np.roll(x, -1, axis=1) - x
    ey = np.roll(y, -1, axis=1) - y
    tt = np.clip(-(x * ex + y * ey) / np.maximum(ex * ex + ey * ey, 1e-12), 0.0, 1.0)
    px, py = x + tt * ex, y + tt * ey
    r_min = np.sqrt(np.min(px * px + py * py, axis=1))
    r_max = np.sqrt(np.max(x * x + y * y, axis=1))
    ang = np.arctan2(y, x)
    centre = np.arctan2(y.mean(axis=1), x.mean(axis=1))
    delta = np.remainder(ang - centre[:, None] + math.pi, 2 * math.pi) - math.pi
    base = centre - pose.yaw_rad + math.pi
    step = 2 * math.pi / A
    lo = np.floor((base + delta.min(axis=1)) / step).astype(np.int64) - 1
    hi = np.ceil((base + delta.max(axis=1)) / step).astype(np.int64) + 1
    full = (hi - lo >= A - 1) | (delta.max(axis=1) - delta.min(axis=1) > math.pi * 0.999)
    lo = np.where(full, 0, lo)
    hi = np.where(full, A - 1, hi)
    return lo, hi, r_min, r_max, r_min <= range_m
