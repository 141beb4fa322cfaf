"""Bird's-eye pictures of a cooperative frame (matplotlib, written atomically as PNG)."""
from __future__ import annotations

from pathlib import Path
from typing import Iterable

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from sumo_scenarios.atomic import atomic_path  # noqa: E402

from ..scene import Scene, footprint_xy  # noqa: E402
from ..sensors.frame import CooperativeFrame, transform_points  # noqa: E402

AGENT_COLOURS = ("tab:red", "tab:blue", "tab:green", "tab:purple", "tab:orange")


def points_above_ground(frame: CooperativeFrame, above_m: float = 0.2) -> list[tuple[str, np.ndarray, int]]:
    """Per sensing agent (in ``frame.sensing_ids`` order): its id, its points in the ego's sensor
    frame (K, 4) without ground returns (lower than ``above_m`` over the ego's ground), and how many
    points it had in all."""
    ego_pose = frame.poses[frame.ego_id]
    out = []
    for aid in frame.sensing_ids:
        pts = transform_points(frame.clouds[aid], frame.poses[aid], ego_pose)
        out.append((aid, pts[pts[:, 2] > -ego_pose.z_m + above_m], len(pts)))
    return out


def bev_figure(scene: Scene, frame: CooperativeFrame, out_path: str | Path, title: str = "",
               marked_ids: Iterable[str] = (), extent_m: float = 60.0,
               changes: tuple[np.ndarray, np.ndarray] | None = None) -> None:
    """Points of every sensing agent in the ego frame (coloured by agent), ground-truth boxes,
    buildings, agent markers; ``marked_ids`` (perturbed vehicles) circled, as in the paper's Fig. 3.
    ``changes``: (removed (K, 3), added (L, 3)) points in the ego's sensor frame, drawn over the
    rest (asg.sensors.agreement.cloud_changes: a recording's edit told apart)."""
    ego_pose = frame.poses[frame.ego_id]
    fig, ax = plt.subplots(figsize=(8, 8), dpi=110)
    c, s = np.cos(ego_pose.yaw_rad), np.sin(ego_pose.yaw_rad)

    def to_ego(xy: np.ndarray) -> np.ndarray:
        d = xy - np.array([ego_pose.x_m, ego_pose.y_m])
        return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=1)

    for b in scene.buildings:
        xy = to_ego(np.asarray(b.footprint_xy))
        ax.fill(xy[:, 0], xy[:, 1], color="0.85", zorder=0)
    for k, (aid, pts, total) in enumerate(points_above_ground(frame)):
        ax.scatter(pts[:, 0], pts[:, 1], s=0.3, color=AGENT_COLOURS[k % len(AGENT_COLOURS)],
                   label=f"{aid} ({total} pts)", zorder=2)
        p = frame.poses[aid]
        m = to_ego(np.array([[p.x_m, p.y_m]]))[0]
        ax.plot(m[0], m[1], marker="^", markersize=10, color=AGENT_COLOURS[k % len(AGENT_COLOURS)], mec="k", zorder=5)
    if changes is not None:
        for pts, colour, marker, label in ((changes[0], "0.35", "x", "removed"), (changes[1], "magenta", ".", "added")):
            pts = pts[pts[:, 2] > -ego_pose.z_m + 0.2]
            ax.scatter(pts[:, 0], pts[:, 1], s=6, color=colour, marker=marker, lw=0.6, zorder=6,
                       label=f"{label} by the move ({len(pts)} pts above ground)")
    marked = set(marked_ids)
    for box, gid in zip(frame.ego_boxes, frame.gt_ids):
        fp = footprint_xy(box[0], box[1], box[6], box[3], box[4])
        loop = np.vstack([fp, fp[:1]])
        ax.plot(loop[:, 0], loop[:, 1], color="k", lw=0.8, zorder=3)
        if gid in marked:
            ax.add_patch(plt.Circle((box[0], box[1]), 3.2, fill=False, color="tab:blue", lw=2, zorder=4))
    ax.set_xlim(-extent_m, extent_m)
    ax.set_ylim(-extent_m, extent_m)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m, ego frame)")
    ax.set_ylabel("y (m)")
    ax.set_title(title or frame.scene_id, fontsize=9)
    ax.legend(loc="upper right", fontsize=7, markerscale=10)
    with atomic_path(out_path) as tmp:
        fig.savefig(tmp, format="png", bbox_inches="tight")
    plt.close(fig)
