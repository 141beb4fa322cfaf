"""asg: adversarial scene generation for cooperative V2X LiDAR perception (V2XP-ASG on SUMO)."""

__version__ = "0.1.0"
