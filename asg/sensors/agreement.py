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
    if not len(points):
        return float("nan")
    if not len(reference):
        return 0.0
    return float((nearest_m(points, reference) <= tol_m).mean())


def nearest_m(points: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(N,) distance (m) from each of ``points`` (N, >=3) to the nearest of ``reference`` (M >= 1,
    >=3). A point that stands in ``reference`` as it is (an unedited return: the same float32 x, y,
    z) is 0 without a search, so the tree is asked only for the points that differ."""
    from sklearn.neighbors import NearestNeighbors

    p, ref = (np.ascontiguousarray(c[:, :3], dtype=np.float32) for c in (points, reference))
    row = np.dtype((np.void, p.dtype.itemsize * 3))
    out = np.zeros(len(p))
    differ = np.flatnonzero(~np.isin(p.view(row).ravel(), ref.view(row).ravel()))
    if len(differ):
        tree = NearestNeighbors(n_neighbors=1).fit(ref.astype(np.float64))
        out[differ] = tree.kneighbors(p[differ].astype(np.float64))[0][:, 0]
    return out


#: a point this far from every point of the other frame counts as changed (m)
CHANGED_M = 0.05


def cloud_changes(before, after, tol_m: float = CHANGED_M) -> tuple[np.ndarray, np.ndarray]:
    """What a move changed in the scans of the sensing agents two cooperative frames share:
    (points of ``before`` that ``after`` lacks (K, 3), points of ``after`` new against ``before``
    (L, 3)), farther than ``tol_m`` from every point of the same agent's other cloud, both in the
    sensor frame of ``after``'s ego. For a recording: the removed and the inserted returns of its edit."""
    from .frame import transform_points

    ego = after.poses[after.ego_id]
    removed, added = [np.zeros((0, 3))], [np.zeros((0, 3))]
    for aid in (a for a in after.sensing_ids if a in before.sensing_ids):
        old, new = before.clouds[aid], after.clouds[aid]
        if not len(old) or not len(new):
            continue
        far_old, far_new = nearest_m(old, new) > tol_m, nearest_m(new, old) > tol_m
        removed.append(transform_points(before.clouds[aid][far_old], before.poses[aid], ego)[:, :3])
        added.append(transform_points(after.clouds[aid][far_new], after.poses[aid], ego)[:, :3])
    return np.concatenate(removed), np.concatenate(added)
