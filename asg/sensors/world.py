"""The 3D world of a scene and its LiDAR rendering.

A :class:`World` holds, in the network frame (x east, y north, z up, metres):
- the ground: the plane z = 0, intersected analytically (no triangles needed);
- the *static* triangles: buildings and every agent that will not move; each sensor casts against
  its own Embree scene of the static triangles it can hit first (:class:`_StaticView`);
- *movable* agents (the ones a search may perturb): each is cast in its own local frame against a
  shared per-class template mesh (instancing by hand), so moving one never rebuilds anything.

A sensor never sees its own body: its rays start where they leave its own footprint prism.
Rendering casts only the rays that can hit something above the ground: a ray is a candidate if
some object spanning its azimuth column starts within the ray's horizontal reach (before the
ground or the range) and rises to the ray's elevation; each cast ray stops at its ground hit
(Embree's tfar); the rest are ground hits or misses. Candidate rays
are cast in two tasks, even and odd channels, on two threads (the packet cast releases the GIL);
Embree returns only the hit triangle, and the distance is that triangle's plane along the ray. The
per-ray work around the cast runs in compiled loops (:mod:`asg.sensors.kernels`).
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
from .kernels import hits_to_points, outline_spans, static_candidates, take_hits
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
    #: (N,) float32 length of each ray from its start to t_limit (Embree's far limit)
    far32: np.ndarray
    #: (C,) horizontal reach of each channel (m): the furthest a ray of it can hit an object
    reach_m: np.ndarray
    #: (N,) bool: rays that leave the own body before t_limit
    reachable: np.ndarray
    #: (N,) |cos| of each ray's incidence on the ground: |z| of its direction
    cos_ground: np.ndarray

    def ground_hits(self) -> "_Hits":
        """Hits of the ground alone: the start of every render."""
        return _Hits(self.t_ground.copy(), np.full(len(self.t_ground), SURFACES["ground"], dtype=np.int8),
                     self.cos_ground.copy())

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
        t_limit = np.minimum(t_ground, spec.range_m)
        cos_el = np.cos(spec.elevations_rad())[:, None]  # (C, 1)
        reach_m = (t_limit.reshape(spec.channels, spec.azimuth_steps) * cos_el).max(axis=1)
        return _SensorRays(pose, dirs_w, dirs_w.astype(np.float32), starts.astype(np.float32), t_start,
                           t_ground, t_limit, np.minimum(t_limit - t_start, 1e30).astype(np.float32), reach_m,
                           t_start < t_limit, np.abs(dirs_w[:, 2]))


@dataclass
class _StaticView:
    """The static triangles one sensor can hit first, with their own caster: the ones facing it
    (every static mesh is closed and the sensor outside it, so a face turned away is never a
    first hit: its mesh's near side is in front of it) and within range horizontally, the
    sensor's own body left out. About a quarter of the world's triangles on a town frame, which
    makes each cast about a quarter cheaper; built once per sensor, as its rays are.

    ``v0`` (F', 3) a vertex and ``normals`` (F', 3) the unit normal of each kept triangle (float64,
    network frame), ``surface`` (F',) its surface class.
    """

    caster: Caster
    v0: np.ndarray
    normals: np.ndarray
    surface: np.ndarray


class _Template:
    """A template mesh with its caster, unit normals and surface class."""

    def __init__(self, mesh, spec: LidarSpec):
        tri = mesh.vertices[mesh.faces]
        self.caster: Caster = make_caster(spec.backend, tri, spec.embree_robust)
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
        self._el_channel = spec.elevations_rad()
        self._el = np.repeat(self._el_channel, spec.azimuth_steps)
        self._cos_el = np.cos(self._el)
        self._templates: dict[tuple, _Template] = {}
        self._build_static()
        self._base_cache: dict[str, _Hits] = {}
        self._ray_cache: dict[str, _SensorRays] = {}
        self._view_cache: dict[str, _StaticView] = {}

    # ---- construction ----------------------------------------------------------------------
    def _template(self, a: Agent) -> _Template:
        key = (a.kind, a.type_id, round(a.length_m, 3), round(a.width_m, 3), round(a.height_m, 3))
        if key not in self._templates:
            self._templates[key] = _Template(agent_template(a.type_id, a.kind, a.length_m, a.width_m, a.height_m), self.spec)
        return self._templates[key]

    def _build_static(self) -> None:
        tris, normals, surfaces, outlines, tops, owners = [], [], [], [], [], []
        self._static_index: dict[str, int] = {}
        for b in self.scene.buildings:
            m = building_mesh(b)
            owners.append(np.full(len(m.faces), len(outlines)))
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
            owners.append(np.full(len(mesh.faces), len(outlines)))
            tris.append(mesh.vertices[mesh.faces] @ rot.T + off)
            normals.append(mesh.face_normals @ rot.T)
            surfaces.append(np.full(len(mesh.faces), mesh.metadata["surface"], dtype=np.int8))
            self._static_index[a.agent_id] = len(outlines)
            outlines.append(a.footprint_xy())
            tops.append(a.z_m + a.height_m)
        self._static_tris = np.concatenate(tris) if tris else np.zeros((0, 3, 3))
        self._static_v0 = np.ascontiguousarray(self._static_tris[:, 0], dtype=np.float64)
        self._static_normals = np.ascontiguousarray(np.concatenate(normals) if normals else np.zeros((0, 3)), dtype=np.float64)
        self._static_surface = np.concatenate(surfaces) if surfaces else np.zeros(0, dtype=np.int8)
        #: (F,) the outline index (building or agent) each static triangle belongs to
        self._static_owner = np.concatenate(owners) if owners else np.zeros(0, dtype=np.int64)
        self._static_outlines = np.ascontiguousarray(_pad_outlines(outlines), dtype=np.float64)
        self._static_tops = np.asarray(tops, dtype=float)

    # ---- rendering ---------------------------------------------------------------------------
    def lidar_protocol(self) -> dict:
        """The LiDAR the clouds are cast with, in CARLA's attribute names (an OPV2V scenario's
        data_protocol.yaml)."""
        return self.spec.carla_protocol()

    def sensor_pose(self, agent_id: str) -> SensorPose:
        return sensor_pose(self.scene.agent(agent_id), self.spec)

    def render(self, sensor_id: str, moved: Mapping[str, Agent] | None = None, seed: int = 0) -> np.ndarray:
        """Points (N, 4) float32 of one sensor; see :meth:`render_many`."""
        return self.render_many([sensor_id], moved, seed)[sensor_id]

    def render_many(self, sensor_ids: Iterable[str], moved: Mapping[str, Agent] | None = None,
                    seed: int = 0) -> dict[str, np.ndarray]:
        """Points (N, 4) float32 per sensor: x, y, z in that sensor's frame, intensity in [0, 1].

        ``moved``: new poses of movable agents by id (None: the agent is absent); the others stay
        as in the scene.
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
                    agent = moved[aid] if aid in moved else self.scene.agent(aid)
                    if agent is not None:  # None: absent (an inserted vehicle a search left out)
                        self._cast_instance(agent, rays.pose, rays.dirs_w, hits)
            out[sid] = self._to_points(sid, hits, seed)
        return out

    def _rays(self, sensor_id: str) -> "_SensorRays":
        if sensor_id not in self._ray_cache:
            self._ray_cache[sensor_id] = _SensorRays.make(self.scene.agent(sensor_id), self.spec, self._dirs_sensor)
        return self._ray_cache[sensor_id]

    def _static_view(self, sensor_id: str) -> _StaticView:
        if sensor_id not in self._view_cache:
            origin = self._rays(sensor_id).pose.origin
            tris = self._static_tris
            facing = np.einsum("ij,ij->i", self._static_v0 - origin, self._static_normals) < 0.0
            near = xy_distance_to_triangles(tris, origin[:2]) <= self.spec.range_m + 1.0
            own = self._static_index.get(sensor_id, -1)
            keep = np.flatnonzero(facing & near & (self._static_owner != own))
            self._view_cache[sensor_id] = _StaticView(
                make_caster(self.spec.backend, tris[keep], self.spec.embree_robust), np.ascontiguousarray(self._static_v0[keep]),
                np.ascontiguousarray(self._static_normals[keep]), np.ascontiguousarray(self._static_surface[keep]))
        return self._view_cache[sensor_id]

    def prepare(self, sensor_ids: Iterable[str]) -> None:
        """Generate the rays and static views of these sensors now (their poses are fixed for the
        World's life)."""
        for sid in sensor_ids:
            self._static_view(sid)

    def _fill_base(self, sensor_ids: list[str]) -> None:
        """Cache ground + static hits for the sensors that have none yet. The work (candidates,
        Embree cast, hits) is split in two tasks, the even and the odd channels of every sensor
        (about equal work), one on a worker thread: the compiled kernels and the cast release the
        GIL."""
        todo = [s for s in dict.fromkeys(sensor_ids) if s not in self._base_cache]
        if not todo:
            return
        hits = {sid: self._rays(sid).ground_hits() for sid in todo}
        for sid in todo:
            self._static_view(sid)

        def channels_from(first: int) -> None:
            for sid in todo:
                self._cast_static(sid, first, 2, hits[sid])

        _run_on_two_threads([lambda: channels_from(0), lambda: channels_from(1)])
        self._base_cache.update(hits)

    def _cast_static(self, sensor_id: str, first_channel: int, channel_step: int, hits: _Hits) -> None:
        """Static hits of one sensor's channels first_channel, first_channel + channel_step, ...,
        written into ``hits`` (rows of other channels untouched)."""
        rays = self._rays(sensor_id)
        cand = self._candidates(rays, self._static_index.get(sensor_id), first_channel, channel_step)
        if not len(cand):
            return
        view = self._view_cache[sensor_id]
        prim = view.caster.first_prims(rays.starts32, rays.dirs32, rays.far32, rows=cand)
        take_hits(cand, prim, rays.pose.origin, rays.dirs_w, view.v0, view.normals, view.surface,
                  hits.t, hits.surface, hits.cos_inc)

    def _candidates(self, rays: "_SensorRays", own: int | None, first_channel: int = 0,
                    channel_step: int = 1) -> np.ndarray:
        """Indices of ``rays`` (of channels first_channel, + channel_step, ...) that may hit a static
        object (but ``own``, the sensor's body) before their limit (ground or range); see
        :func:`kernels.static_candidates`. The limit depends on the channel only, which makes
        each channel's horizontal reach a constant."""
        if not len(self._static_outlines):
            return np.zeros(0, dtype=np.int64)
        p = rays.pose
        return static_candidates(self._static_outlines, self._static_tops, -1 if own is None else own, p.x_m, p.y_m,
                                 p.z_m, p.yaw_rad, self.spec.azimuth_steps, float(self.spec.range_m), rays.reach_m,
                                 self._el_channel, rays.reachable, first_channel, channel_step)

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
        if spec.noise_std_m <= 0 and spec.dropoff <= 0:
            return hits_to_points(hits.t, hits.surface, hits.cos_inc, self._dirs_sensor32, REFLECTIVITY,
                                  float(spec.range_m))
        t = hits.t
        valid = t <= spec.range_m
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
#: threads a cast may use: 2 (the calling thread and one worker thread) or 1 (one task after the
#: other, for a process that shares the machine with other workers); the points are the same
_CAST_THREADS = 2


def set_cast_threads(threads: int) -> None:
    """Let a render use ``threads`` threads (1, or 2 and more: two)."""
    global _CAST_THREADS
    _CAST_THREADS = 1 if threads <= 1 else 2


def _run_on_two_threads(tasks: list) -> None:
    """Run the callables, the first on the calling thread and the others on a worker thread (or
    all on the calling thread when casts may use one thread); the first exception propagates,
    after every task has stopped."""
    global _POOL
    if _CAST_THREADS == 1:
        for task in tasks:
            task()
        return
    if _POOL is None:
        from concurrent.futures import ThreadPoolExecutor

        _POOL = ThreadPoolExecutor(max_workers=1, thread_name_prefix="asg-lidar")
    others = [_POOL.submit(t) for t in tasks[1:]]
    try:
        tasks[0]()
    finally:
        for future in others:
            future.result()


def xy_distance_to_triangles(tris: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """(F,) horizontal distance (m) from the point ``xy`` (2,) to each triangle (F, 3, 3) seen from
    above: 0 inside its outline, else the distance to its nearest edge (walls seen from above
    are segments, which the edge distance covers)."""
    a = tris[:, :, :2] - xy  # (F, 3, 2) the vertices relative to the point
    b = np.roll(a, -1, axis=1)
    edge = b - a
    length2 = np.maximum(np.einsum("fkd,fkd->fk", edge, edge), 1e-18)
    u = np.clip(-np.einsum("fkd,fkd->fk", a, edge) / length2, 0.0, 1.0)
    closest = a + u[..., None] * edge
    dist = np.sqrt(np.einsum("fkd,fkd->fk", closest, closest).min(axis=1))
    cross = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]  # (F, 3): the point's side of each edge
    inside = (cross > 0).all(axis=1) | (cross < 0).all(axis=1)
    return np.where(inside, 0.0, dist)


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
    """Azimuth column spans of ground outlines (M, K, 2) seen from ``pose``; see
    :func:`kernels.outline_spans`."""
    return outline_spans(np.ascontiguousarray(outlines, dtype=np.float64), pose.x_m, pose.y_m, pose.yaw_rad, A, range_m)
