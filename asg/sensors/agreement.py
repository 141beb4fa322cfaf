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
