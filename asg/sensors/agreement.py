"""How far two point clouds agree: the share of one's points within a distance of the other's, the
yardstick of a recorded scan's edit against the simulator's rendering of the same move
(docs/recordings.md).

The nearest neighbours come from scikit-learn's tree, not SciPy's ``cKDTree``: with the CPU's
flush-to-zero mode on (asg.perception sets it for torch's threads when it loads), ``cKDTree.query``
crashed the process (a segmentation fault, SciPy 1.16 on x86-64) on ordinary scans.
"""
from __future__ import annotations

import numpy as np


def share_within(points: np.ndarray, reference: np.ndarray, tol_m: float) -> float:
    """The share of ``points`` (N, >=3) within ``tol_m`` of a point of ``reference`` (M, >=3), one
    frame for both (nan for no points, 0 against none)."""
    from sklearn.neighbors import NearestNeighbors

    if not len(points):
        return float("nan")
    if not len(reference):
        return 0.0
    tree = NearestNeighbors(n_neighbors=1).fit(np.asarray(reference[:, :3], dtype=np.float64))
    distance, _ = tree.kneighbors(np.asarray(points[:, :3], dtype=np.float64))
    return float((distance[:, 0] <= tol_m).mean())


#: a point this far from every point of the other frame counts as changed (m)
CHANGED_M = 0.05


def cloud_changes(before, after, tol_m: float = CHANGED_M) -> tuple[np.ndarray, np.ndarray]:
    """What a move changed in the scans of the sensing agents two cooperative frames share:
    (points of ``before`` that ``after`` lacks (K, 3), points of ``after`` new against ``before``
    (L, 3)), farther than ``tol_m`` from every point of the same agent's other cloud, both in the
    sensor frame of ``after``'s ego. For a recording: the removed and the inserted returns of its edit."""
    from sklearn.neighbors import NearestNeighbors

    from .frame import transform_points

    ego = after.poses[after.ego_id]
    removed, added = [np.zeros((0, 3))], [np.zeros((0, 3))]
    for aid in (a for a in after.sensing_ids if a in before.sensing_ids):
        old, new = before.clouds[aid][:, :3].astype(np.float64), after.clouds[aid][:, :3].astype(np.float64)
        if not len(old) or not len(new):
            continue
        far_old = NearestNeighbors(n_neighbors=1).fit(new).kneighbors(old)[0][:, 0] > tol_m
        far_new = NearestNeighbors(n_neighbors=1).fit(old).kneighbors(new)[0][:, 0] > tol_m
        removed.append(transform_points(before.clouds[aid][far_old], before.poses[aid], ego)[:, :3])
        added.append(transform_points(after.clouds[aid][far_new], after.poses[aid], ego)[:, :3])
    return np.concatenate(removed), np.concatenate(added)
