"""The occlusion heuristic of the perturbation search: who hides whom, from each viewpoint.

From a viewpoint (x, y), vehicle A occludes vehicle B if their azimuth intervals overlap and A is
nearer (distance from the viewpoint to the box centre). Extrinsic score of A = number of vehicles
it occludes; intrinsic score of B = 1 if anything occludes it. A vehicle's score is the sum of
both over all viewpoints (the sensing agents). Corners are taken once, in the network frame, from
the agents' own poses (the defect of applying the pose twice is avoided by construction).
"""
from __future__ import annotations

import math
from typing import Iterable, Sequence

import numpy as np

from ..scene import Agent


def azimuth_intervals(viewer_xy: tuple[float, float], agents: Sequence[Agent]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per agent: (centre azimuth, half-width, distance), rad / rad / m, from ``viewer_xy``."""
    if not agents:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    corners = np.stack([a.footprint_xy() for a in agents]) - np.asarray(viewer_xy)
    centre_xy = corners.mean(axis=1)
    centre = np.arctan2(centre_xy[:, 1], centre_xy[:, 0])
    ang = np.arctan2(corners[..., 1], corners[..., 0])
    delta = np.remainder(ang - centre[:, None] + math.pi, 2 * math.pi) - math.pi
    half = np.abs(delta).max(axis=1)
    return centre, half, np.hypot(centre_xy[:, 0], centre_xy[:, 1])


def occlusion_matrix(viewer_xy: tuple[float, float], agents: Sequence[Agent], range_m: float = 70.0) -> np.ndarray:
    """(M, M) bool, [i, j] = agent i occludes agent j from ``viewer_xy`` (both within range)."""
    centre, half, dist = azimuth_intervals(viewer_xy, agents)
    gap = np.abs(np.remainder(centre[:, None] - centre[None, :] + math.pi, 2 * math.pi) - math.pi)
    overlap = gap < (half[:, None] + half[None, :])
    in_range = dist <= range_m
    occ = overlap & (dist[:, None] < dist[None, :]) & in_range[:, None] & in_range[None, :]
    np.fill_diagonal(occ, False)
    return occ


def occlusion_scores(viewers: Iterable[Agent], vehicles: Sequence[Agent], range_m: float = 70.0,
                     exclude_ids: Iterable[str] = ()) -> dict[str, int]:
    """Intrinsic + extrinsic occlusion of each vehicle, summed over the viewpoints (the viewer
    agents' positions; a viewer is left out of its own viewpoint)."""
    excluded = set(exclude_ids)
    scores = {a.agent_id: 0 for a in vehicles}
    for viewer in viewers:
        seen = [a for a in vehicles if a.agent_id != viewer.agent_id]
        occ = occlusion_matrix((viewer.x_m, viewer.y_m), seen, range_m)
        extrinsic = occ.sum(axis=1)
        intrinsic = occ.any(axis=0).astype(int)
        for a, e, i in zip(seen, extrinsic, intrinsic):
            scores[a.agent_id] += int(e + i)
    return {k: v for k, v in scores.items() if k not in excluded}
