"""The 3D world and the LiDAR simulator (the only part of asg that imports trimesh)."""
from .frame import CooperativeFrame, count_points_in_boxes, render_frame, simulate_frame
from .lidar_spec import LidarSpec, load_lidar_spec
from .occlusion import occlusion_matrix, occlusion_scores
from .renderers import world_for
from .world import World, sensor_pose

__all__ = ["CooperativeFrame", "LidarSpec", "World", "count_points_in_boxes", "load_lidar_spec",
           "occlusion_matrix", "occlusion_scores", "render_frame", "sensor_pose", "simulate_frame", "world_for"]
