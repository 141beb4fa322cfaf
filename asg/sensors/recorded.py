"""A recorded scene's renderer: the recorded clouds, edited where the scene's vehicles differ from the
recording, with each scan's own rays (as AdvCP edits OPV2V's shared scans).

:class:`RecordedWorld` stands behind the same interface as :class:`asg.sensors.world.World`
(``render_many``, ``render``, ``sensor_pose``, ``prepare``, ``scene``, ``spec``, ``movable_ids``);
the scene's source picks it (asg.sensors.renderers). With no vehicle changed, each sensing agent gets
its recorded points exactly (the file's float32 values, y mirrored from a left-handed recording), in
its LiDAR's frame: a view that asg's export wrote in a lowered frame (a high sensor's) is given back
in its LiDAR's frame, as the native scene had it (asg.scene.recorded_pcd.recorded_cloud).
A vehicle whose pose differs from the recording (moved, inserted, removed) is, in each sensing
agent's scan (its sensor frame: x forward, y left, z up, metres):

1. taken out: the points inside its recorded box (grown by REMOVE_MARGIN_M, and above the scan's
   fitted ground by more than the ground's tolerance) are its; their rays are cast again against
   what lies behind it (the ground plane fitted to the scan, the meshes of the other labelled
   vehicles at their current poses); a ray that hits nothing in range is dropped;
2. put in at its new pose: the rays of the scan within its azimuth window (the directions of the
   points, and where the scan recorded no return, the recorded LiDAR's beam directions) cast
   against its mesh (asg's template of its type and size); a return is replaced where the mesh is
   nearer, which also takes out the points in its new shadow.

Only rays within the azimuth window of a changed vehicle are cast again. Intensities of the new
returns follow the simulator's model (surface reflectivity x |cos incidence|). Where an edit is not
exact: an unlabelled object behind a removed vehicle (a wall, a pedestrian) is not known, so its
rays fall to the ground or are dropped; the inserted vehicle is asg's mesh, not the recorded car's
shape; sensor frames keep the recorded yaw only (roll and pitch are recorded but not applied).
"""
from __future__ import annotations

import functools
import math
from dataclasses import replace
from typing import Iterable, Mapping

import numpy as np

from sumo_scenarios.geometry import wrap_rad

from ..scene import Agent, Scene
from ..scene.agent import footprint_xy, in_any_box
from ..scene.recorded_pcd import recorded_cloud
from ..scene.recording import Handedness, RecordedView
from ..scene.scan_ground import GROUND_TOLERANCE_M, GroundPlane, ground_or_none
from .lidar_spec import LidarSpec
from .meshes import REFLECTIVITY, SURFACES, agent_template
from .raycast import make_caster
from .world import SensorPose

#: a removed vehicle's recorded box grown by this on every side before its points are taken (m)
REMOVE_MARGIN_M = 0.2
#: an azimuth window's margin beyond the footprint's corners (rad)
WINDOW_MARGIN_RAD = math.radians(0.5)


class RecordedWorld:
    """The renderer of a scene whose source is a recording; see the module docstring.

    ``movable_ids``: the agents a search may change (given for the interface; any vehicle whose pose
    differs from the recording is edited, movable or not)."""

    def __init__(self, scene: Scene, spec: LidarSpec, movable_ids: Iterable[str] = ()):
        self.scene = scene
        self.spec = spec
        self.movable_ids = frozenset(movable_ids)
        self.recording = scene.recording
        recorded = self.recording.lidar
        #: the recorded LiDAR as a spec: its beam pattern and range (the casting backend is ``spec``'s)
        self.lidar = replace(spec, name="recorded", channels=recorded.channels, fov_up_deg=recorded.upper_deg,
                             fov_down_deg=recorded.lower_deg, points_per_s=recorded.points_per_s,
                             rotation_hz=recorded.rotation_hz, range_m=recorded.range_m).validate()
        self._clouds: dict[str, np.ndarray] = {}
        self._beams: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._rays: dict[str, tuple] = {}
        self._windows: dict[tuple[str, str], tuple | None] = {}
        self._sorted: dict[tuple[str, bool], _Azimuths] = {}
        self._templates: dict[tuple, tuple] = {}
        self._taken: dict[tuple, tuple] = {}  # _taken_out's results
        self._recorded = {a.agent_id: a for a in self.recording.vehicles}

    # ---- the interface -------------------------------------------------------------------
    def lidar_protocol(self) -> dict:
        """The recorded LiDAR in CARLA's attribute names (an OPV2V scenario's data_protocol.yaml)."""
        return self.lidar.carla_protocol()

    def sensor_pose(self, agent_id: str) -> SensorPose:
        return SensorPose(*self.recording.views[agent_id].lidar_pose)

    def prepare(self, sensor_ids: Iterable[str]) -> None:
        for sid in sensor_ids:
            self._cloud(sid)

    def render(self, sensor_id: str, moved: Mapping[str, Agent | None] | None = None, seed: int = 0) -> np.ndarray:
        return self.render_many([sensor_id], moved, seed)[sensor_id]

    def render_many(self, sensor_ids: Iterable[str], moved: Mapping[str, Agent | None] | None = None,
                    seed: int = 0) -> dict[str, np.ndarray]:
        """Points (N, 4) float32 per sensor (x, y, z in its sensor frame, intensity): its recorded
        scan, edited for every vehicle whose pose differs from the recording. ``moved``: new poses
        by id (None: absent), over the scene's own; ``seed`` is unused (a recording has no noise)."""
        current = self.current_vehicles(moved)
        changed = self.changed(current)
        out = {}
        for sid in sensor_ids:
            cloud = self._cloud(sid)
            out[sid] = cloud.copy() if not changed else self._edited(sid, cloud, current, changed)
        return out

    # ---- which vehicles changed ------------------------------------------------------------
    def current_vehicles(self, moved: Mapping[str, Agent | None] | None = None) -> dict[str, Agent]:
        """{id: vehicle} as the frame has them: the scene's, with ``moved`` over them."""
        current = {a.agent_id: a for a in self.scene.vehicles}
        for aid, agent in (moved or {}).items():
            if agent is None:
                current.pop(aid, None)
            else:
                current[aid] = agent
        return current

    def changed(self, current: Mapping[str, Agent]) -> list[str]:
        """Ids of the vehicles whose pose differs from the recording: moved, inserted or removed."""
        ids = sorted(set(current) | set(self._recorded))
        return [i for i in ids if not _same_pose(current.get(i), self._recorded.get(i))]

    # ---- the edit -----------------------------------------------------------------------------
    def _edited(self, sid: str, cloud: np.ndarray, current: Mapping[str, Agent], changed: list[str]) -> np.ndarray:
        """``sid``'s scan with the ``changed`` vehicles taken out (at their recorded poses) and put in
        (at their ``current`` ones); its own body is never edited."""
        _, t, dirs, az = self._rays_of(sid)
        scan = _Scan(cloud, t.copy(), dirs, az)
        if any(i in self._recorded and i != sid for i in changed):
            idx, t_new, intensity, keep = self._taken_out(sid, current, changed)
            scan.t[idx], scan.intensity[idx], scan.keep[idx], scan.edited[idx] = t_new, intensity, keep, True
        added = [current[i] for i in changed if i in current and i != sid]
        if added:
            self._put_in(sid, scan, added)
        return scan.points()

    def _taken_out(self, sid: str, current: Mapping[str, Agent], changed: list[str]):
        """The rays of ``sid``'s scan that hit the recorded vehicles among ``changed`` (not ``sid``), cast again
        against what lies behind them: (indices (K,), distance (K,), intensity (K,) float32, still
        returning (K,) bool; a ray hitting nothing in range dropped). What lies behind is every
        vehicle the frame did not change, where the recording has it, so the result depends on
        ``sid`` and the recorded vehicles changed alone: cached by them (a search moves the same
        vehicles at every step)."""
        key = (sid, tuple(i for i in changed if i in self._recorded))
        if key not in self._taken:
            xyz, _, dirs, az = self._rays_of(sid)
            removed = [self._recorded[i] for i in key[1] if i != sid]
            idx = np.flatnonzero(self._points_of(sid, xyz, removed))
            behind = [a for i, a in current.items() if i not in changed and i != sid]
            t_new, surf, cos = self._background(sid, self.sensor_pose(sid), dirs[idx], az[idx], behind)
            self._taken[key] = (idx, t_new, (REFLECTIVITY[surf] * cos).astype(np.float32),
                                np.isfinite(t_new) & (t_new <= self._range_m()))
        return self._taken[key]

    def _put_in(self, sid: str, scan: "_Scan", added: list[Agent]) -> None:
        """Each of ``added`` cast against the rays in its azimuth window (the scan's, and the
        LiDAR's beams where it recorded no return), a return replaced where its mesh is nearer."""
        pose, n = self.sensor_pose(sid), len(scan.cloud)
        windows = [_window(pose, agent, self._range_m()) for agent in added]
        bdirs, baz = self._missing_beams(sid, windows)
        scan.extend(bdirs, baz)
        sorted_az = self._sorted_az(sid)
        for agent, window in zip(added, windows):
            idx = np.concatenate([sorted_az.within(window), n + _in_window(baz, window)])
            limit = np.where(scan.keep[idx], scan.t[idx], self._range_m())
            hit, t_hit, cos = self._cast(agent, pose, scan.dirs[idx], limit)
            sel = idx[hit]
            scan.t[sel], scan.intensity[sel] = t_hit[hit], REFLECTIVITY[SURFACES["vehicle"]] * cos[hit]
            scan.keep[sel] = scan.edited[sel] = True

    def _points_of(self, sid: str, xyz: np.ndarray, vehicles: list[Agent]) -> np.ndarray:
        """(N,) bool: the scan's points inside any of ``vehicles``' recorded boxes (grown by
        REMOVE_MARGIN_M) and above the scan's ground, in ``sid``'s sensor frame."""
        pose = self.sensor_pose(sid)
        inside = np.zeros(len(xyz), dtype=bool)
        sorted_az = self._sorted_az(sid)
        for a in vehicles:
            idx = sorted_az.within(_window(pose, a, self._range_m(), REMOVE_MARGIN_M))
            inside[idx] |= in_any_box(xyz[idx] @ pose.rotation().T + pose.origin, a.box7(), REMOVE_MARGIN_M)
        plane = self._plane(sid)
        if plane is not None:
            inside &= plane.height_m(xyz) > GROUND_TOLERANCE_M
        return inside

    def _background(self, sid: str, pose: SensorPose, dirs: np.ndarray, az: np.ndarray, behind: list[Agent]):
        """Distance (K,), surface class (K,) and |cos incidence| (K,) of rays (K, 3, sensor frame;
        ``az`` (K,) their azimuths) cast against the scan's ground plane and the ``behind``
        vehicles' meshes (inf: nothing)."""
        plane = self._plane(sid)
        t = plane.ray_distance(dirs) if plane is not None else np.full(len(dirs), np.inf)
        t = np.where(t <= self._range_m(), t, np.inf)
        surface = np.full(len(dirs), SURFACES["ground"], dtype=np.int64)
        cos = np.abs(dirs @ _plane_normal(plane)) if plane is not None else np.ones(len(dirs))
        for agent in self._facing(sid, az, behind):
            idx = _in_window(az, self._recorded_window(sid, agent))
            hit, t_hit, c_hit = self._cast(agent, pose, dirs[idx], np.minimum(t[idx], self._range_m()))
            sel = idx[hit]
            t[sel], surface[sel], cos[sel] = t_hit[hit], SURFACES["vehicle"], c_hit[hit]
        return t, surface, cos.astype(np.float32)

    def _cast(self, agent: Agent, pose: SensorPose, dirs: np.ndarray, limit: np.ndarray):
        """(hit (K,) bool, distance (K,), |cos incidence| (K,)) of rays (K, 3, sensor frame) from
        the LiDAR against ``agent``'s mesh, hits beyond ``limit`` (K,) ignored."""
        if not len(dirs):
            return np.zeros(0, bool), np.zeros(0), np.zeros(0)
        caster, normals = self._template(agent)
        c, s = math.cos(agent.yaw_rad), math.sin(agent.yaw_rad)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        d_world = dirs @ pose.rotation().T
        o_local = (pose.origin - (agent.x_m, agent.y_m, agent.z_m)) @ rot
        d_local = d_world @ rot
        t, prim = caster.first_hits(np.broadcast_to(o_local, d_local.shape), d_local, limit)
        hit = (prim >= 0) & (t < limit)
        cos = np.zeros(len(dirs))
        cos[hit] = np.abs(np.einsum("ij,ij->i", d_local[hit], normals[prim[hit]]))
        return hit, t, cos

    def _missing_beams(self, sid: str, windows: list) -> tuple[np.ndarray, np.ndarray]:
        """Unit directions (K, 3, sensor frame) and azimuths (K,) of the recorded LiDAR's beams
        within the azimuth ``windows`` (:func:`_window`'s) along which the scan recorded no return,
        in the beams' order."""
        beams, beam_az, empty = self._beam_pattern(sid)
        sorted_az = self._sorted_az(sid, beams=True)
        wanted = np.zeros(len(empty), dtype=bool)
        for window in windows:
            wanted[sorted_az.within(window)] = True
        idx = np.flatnonzero(wanted & empty)
        return beams[idx], beam_az[idx]

    def _rays_of(self, sid: str):
        """The scan's points as rays from its LiDAR (its frame's origin): (xyz (N, 3) float64,
        distance (N,), unit directions (N, 3), azimuth (N,) rad), all in its frame; cached."""
        if sid not in self._rays:
            xyz = self._cloud(sid)[:, :3].astype(np.float64)
            t = np.linalg.norm(xyz, axis=1)
            self._rays[sid] = (xyz, t, xyz / np.maximum(t, 1e-9)[:, None], np.arctan2(xyz[:, 1], xyz[:, 0]))
        return self._rays[sid]

    def _facing(self, sid: str, az: np.ndarray, vehicles: list[Agent]) -> list[Agent]:
        """Those of ``vehicles`` (at their recorded poses) whose azimuth window holds one of the
        azimuths ``az`` (K,): one (K, M) test instead of a window test per vehicle."""
        windows = [(a, self._recorded_window(sid, a)) for a in vehicles]
        windows = [(a, w) for a, w in windows if w is not None]
        if not windows or not len(az):
            return []
        table = np.array([w for _, w in windows])  # (M, 3): centre, low, high
        rel = (az[:, None] - table[None, :, 0] + math.pi) % (2 * math.pi) - math.pi
        hit = ((rel >= table[None, :, 1]) & (rel <= table[None, :, 2])).any(axis=0)
        return [a for (a, _), h in zip(windows, hit) if h]

    def _sorted_az(self, sid: str, beams: bool = False) -> "_Azimuths":
        """The scan's point azimuths (or its LiDAR's beams'), sorted for window lookups; cached."""
        key = (sid, beams)
        if key not in self._sorted:
            self._sorted[key] = _Azimuths(self._beam_pattern(sid)[1] if beams else self._rays_of(sid)[3])
        return self._sorted[key]

    def _recorded_window(self, sid: str, agent: Agent):
        """:func:`_window` of a vehicle at its recorded pose, cached per sensor."""
        key = (sid, agent.agent_id)
        if key not in self._windows:
            self._windows[key] = _window(self.sensor_pose(sid), agent, self._range_m())
        return self._windows[key]

    # ---- cached per sensor ---------------------------------------------------------------------
    def _cloud(self, sid: str) -> np.ndarray:
        if sid not in self._clouds:
            self._clouds[sid] = recorded_cloud(self.recording.views[sid], self.recording.handed)
        return self._clouds[sid]

    def _plane(self, sid: str) -> GroundPlane | None:
        """The ground of ``sid``'s scan (None: no road in view; removed rays hit only vehicles, or nothing)."""
        return _ground_of(self.recording.views[sid], self.recording.handed)

    def _beam_pattern(self, sid: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(beam directions (C * A, 3) of the recorded LiDAR, their azimuths (C * A,), (C * A,) bool:
        no recorded point in its cell), in the sensor frame."""
        if sid not in self._beams:
            lidar, steps = self.lidar, self.lidar.azimuth_steps
            el = lidar.elevations_rad()
            beams = lidar.directions()
            beam_az = np.tile(lidar.azimuths_rad(), lidar.channels)  # row-major (channel, azimuth), as directions()
            xyz = self._cloud(sid)[:, :3].astype(np.float64)
            r = np.linalg.norm(xyz, axis=1)
            ok = r > 1e-6
            p_el = np.arcsin(np.clip(xyz[ok, 2] / r[ok], -1, 1))
            p_az = np.arctan2(xyz[ok, 1], xyz[ok, 0])
            step_el = (el[0] - el[-1]) / max(lidar.channels - 1, 1) if lidar.channels > 1 else 1.0
            ch = np.clip(np.rint((el[0] - p_el) / step_el).astype(np.int64), 0, lidar.channels - 1)
            col = np.rint((p_az + math.pi) / (2 * math.pi / steps)).astype(np.int64) % steps
            empty = np.ones(lidar.channels * steps, dtype=bool)
            empty[ch * steps + col] = False
            self._beams[sid] = (beams, beam_az, empty)
        return self._beams[sid]

    def _template(self, agent: Agent):
        key = (agent.kind, agent.type_id, round(agent.length_m, 3), round(agent.width_m, 3), round(agent.height_m, 3))
        if key not in self._templates:
            mesh = agent_template(agent.type_id, agent.kind, agent.length_m, agent.width_m, agent.height_m)
            self._templates[key] = (make_caster(self.spec.backend, mesh.vertices[mesh.faces], self.spec.embree_robust),
                                    np.asarray(mesh.face_normals, dtype=np.float64))
        return self._templates[key]

    def _range_m(self) -> float:
        return float(self.lidar.range_m)


def _same_pose(a: Agent | None, b: Agent | None) -> bool:
    if a is None or b is None:
        return a is b
    return (abs(a.x_m - b.x_m) < 1e-6 and abs(a.y_m - b.y_m) < 1e-6 and abs(a.z_m - b.z_m) < 1e-6
            and abs(wrap_rad(a.yaw_rad - b.yaw_rad)) < 1e-9 and abs(a.length_m - b.length_m) < 1e-6
            and abs(a.width_m - b.width_m) < 1e-6 and abs(a.height_m - b.height_m) < 1e-6)


def _window(pose: SensorPose, agent: Agent, range_m: float, margin_m: float = 0.0) -> tuple[float, float, float] | None:
    """``agent``'s azimuth window seen from ``pose`` in its sensor frame: (centre, low, high) rad,
    low and high relative to the centre; None if it is out of range or the sensor stands in its
    footprint (grown by ``margin_m``)."""
    corners = footprint_xy(agent.x_m, agent.y_m, agent.yaw_rad, agent.length_m + 2 * margin_m,
                           agent.width_m + 2 * margin_m) - (pose.x_m, pose.y_m)
    centre = corners.mean(axis=0)
    if math.hypot(*centre) > range_m + agent.length_m or _inside(np.zeros(2), corners):
        return None
    az_c = math.atan2(centre[1], centre[0])
    rel = np.arctan2(corners[:, 1], corners[:, 0]) - az_c
    rel = (rel + math.pi) % (2 * math.pi) - math.pi
    return az_c - pose.yaw_rad, float(rel.min()) - WINDOW_MARGIN_RAD, float(rel.max()) + WINDOW_MARGIN_RAD


class _Scan:
    """One scan under edit, per ray: distance ``t``, unit direction ``dirs`` and azimuth ``az`` (view
    frame, from the LiDAR), ``intensity``, whether it still returns (``keep``) and was changed
    (``edited``); rays past the recorded cloud's rows are the LiDAR's beams that recorded nothing."""

    def __init__(self, cloud: np.ndarray, t: np.ndarray, dirs: np.ndarray, az: np.ndarray):
        self.cloud, self.t, self.dirs, self.az = cloud, t, dirs, az
        self.intensity = cloud[:, 3].copy()
        self.keep = np.ones(len(cloud), dtype=bool)
        self.edited = np.zeros(len(cloud), dtype=bool)

    def extend(self, dirs: np.ndarray, az: np.ndarray) -> None:
        """Add rays (K, 3) with azimuths (K,) that return nothing yet."""
        k = len(dirs)
        self.dirs, self.az = np.concatenate([self.dirs, dirs]), np.concatenate([self.az, az])
        self.t = np.concatenate([self.t, np.full(k, np.inf)])
        self.intensity = np.concatenate([self.intensity, np.zeros(k, np.float32)])
        self.keep = np.concatenate([self.keep, np.zeros(k, bool)])
        self.edited = np.concatenate([self.edited, np.ones(k, bool)])

    def points(self) -> np.ndarray:
        """(M, 4) float32: the recorded rows as recorded unless edited, edited ones from the LiDAR
        along their rays, dropped ones out, the beams that now return appended."""
        n = len(self.cloud)
        out = np.concatenate([self.cloud, np.zeros((len(self.t) - n, 4), np.float32)]) if len(self.t) > n \
            else self.cloud.copy()
        rows = np.flatnonzero(self.edited & self.keep)
        out[rows, :3] = self.dirs[rows] * self.t[rows, None]
        out[rows, 3] = self.intensity[rows]
        return out if self.keep.all() else out[self.keep]


class _Azimuths:
    """Azimuths (N,) rad in [-pi, pi] sorted once, so that a window's rays are two binary searches."""

    def __init__(self, az: np.ndarray):
        self.order = np.argsort(az, kind="stable")
        self.sorted = az[self.order]

    def within(self, window: tuple[float, float, float] | None) -> np.ndarray:
        """Indices (into the unsorted azimuths) within ``window`` (see :func:`_window`)."""
        if window is None:
            return np.zeros(0, dtype=np.int64)
        centre, lo, hi = window
        a = (centre + lo + math.pi) % (2 * math.pi) - math.pi
        b = a + (hi - lo)
        spans = [(a, b)] if b <= math.pi else [(a, math.pi), (-math.pi, b - 2 * math.pi)]
        parts = [self.order[np.searchsorted(self.sorted, s, "left"):np.searchsorted(self.sorted, e, "right")]
                 for s, e in spans]
        return np.sort(np.concatenate(parts))


def _in_window(az: np.ndarray, window: tuple[float, float, float] | None) -> np.ndarray:
    """Indices of azimuths ``az`` (N,) rad within ``window`` (see :func:`_window`)."""
    if window is None:
        return np.zeros(0, dtype=np.int64)
    centre, lo, hi = window
    rel = (az - centre + math.pi) % (2 * math.pi) - math.pi
    return np.flatnonzero((rel >= lo) & (rel <= hi))


@functools.lru_cache(maxsize=256)
def _ground_of(view: RecordedView, handed: Handedness) -> GroundPlane | None:
    """The ground fitted to a recorded view's cloud in its LiDAR's frame (None: no road in view),
    kept across worlds: a scene's search builds several, and the fit is seeded (the same plane)."""
    return ground_or_none(recorded_cloud(view, handed))


def _plane_normal(plane: GroundPlane) -> np.ndarray:
    n = np.array([-plane.a, -plane.b, 1.0])
    return n / np.linalg.norm(n)


def _inside(point: np.ndarray, corners: np.ndarray) -> bool:
    """Is ``point`` (2,) inside the convex polygon ``corners`` (K, 2), counter-clockwise?"""
    a, b = corners, np.roll(corners, -1, axis=0)
    return bool((((b[:, 0] - a[:, 0]) * (point[1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (point[0] - a[:, 0])) >= 0).all())
