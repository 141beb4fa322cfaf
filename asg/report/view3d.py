"""The report's interactive 3D view of a scene: the fused LiDAR cloud with boxes (plotly, WebGL).

plotly.js is written into the page once (``plotly_script``), each view as a ``<div>`` with its own
call (``scene_view_html``); the page needs no network. Points and boxes are in the ego's sensor
frame (x forward, y left, z up, metres), the frame the detections are in.
"""
from __future__ import annotations

import numpy as np
from matplotlib.colors import to_hex

from ..scene import footprint_xy
from ..sensors.frame import CooperativeFrame
from ..io.figures import points_above_ground

#: most points drawn per view (a uniform, seeded subsample above that): the page stays a few MB
MAX_POINTS = 12000
#: the 12 edges of a box, as pairs of indices into its 8 corners (4 bottom, then 4 top)
_EDGES = ((0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7))


def plotly_script() -> str:
    """plotly.js as one inline ``<script>`` (about 5 MB), to put in the page once."""
    from plotly.offline import get_plotlyjs

    return f"<script>{get_plotlyjs()}</script>"


def box_edges(boxes: np.ndarray) -> np.ndarray:
    """(M, 7) boxes (centre x, y, z, length, width, height, yaw) -> (M * 12 * 3, 3) polyline vertices:
    each edge's two ends then a NaN row that breaks the line."""
    out = []
    for x, y, z, l, w, h, yaw in np.asarray(boxes, dtype=float).reshape(-1, 7):
        fp = footprint_xy(x, y, yaw, l, w)
        corners = np.vstack([np.column_stack([fp, np.full(4, z - h / 2)]), np.column_stack([fp, np.full(4, z + h / 2)])])
        for a, b in _EDGES:
            out += [corners[a], corners[b], [np.nan] * 3]
    return np.asarray(out, dtype=float).reshape(-1, 3)


def scene_view_html(frame: CooperativeFrame, detections: np.ndarray, div_id: str, agent_colours: tuple[str, ...],
                    gt_colour: str, det_colour: str, seed: int = 0) -> str:
    """A ``<div>`` with the 3D view: each sensing agent's points above the ground in its colour
    (at most ``MAX_POINTS`` in all), ground truth and detections (K, 7) as wireframes. Colours are
    any matplotlib colour; ``div_id`` must be a safe HTML id (the caller makes it)."""
    import plotly.graph_objects as go

    clouds = points_above_ground(frame)
    total = sum(len(pts) for _, pts, _ in clouds)
    keep = min(1.0, MAX_POINTS / max(total, 1))
    rng = np.random.default_rng(seed)
    fig = go.Figure()
    for k, (aid, pts, _) in enumerate(clouds):
        pts = pts[rng.random(len(pts)) < keep] if keep < 1.0 else pts
        xyz = pts[:, :3].astype(np.float32)
        fig.add_trace(go.Scatter3d(x=xyz[:, 0], y=xyz[:, 1], z=xyz[:, 2], mode="markers", name=f"{aid} points",
                                   marker={"size": 1.5, "color": to_hex(agent_colours[k % len(agent_colours)])}))
    for boxes, colour, name in ((frame.ego_boxes, gt_colour, "ground truth"), (detections, det_colour, "detections")):
        if len(boxes):
            e = box_edges(boxes)
            fig.add_trace(go.Scatter3d(x=e[:, 0], y=e[:, 1], z=e[:, 2], mode="lines", name=name,
                                       line={"color": to_hex(colour), "width": 3}))
    fig.update_layout(height=560, margin={"l": 0, "r": 0, "t": 0, "b": 0}, legend={"x": 0, "y": 1},
                      scene={"aspectmode": "data", "xaxis_title": "x (m)", "yaxis_title": "y (m)", "zaxis_title": "z (m)"})
    return fig.to_html(full_html=False, include_plotlyjs=False, div_id=div_id, config={"displaylogo": False})
