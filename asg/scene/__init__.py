"""Scenes: one frame of agents, buildings and lanes (``Scene``), built from traffic logs."""
from .agent import Agent, footprint_xy
from .scene import Scene, load_scene, save_scene

__all__ = ["Agent", "Scene", "footprint_xy", "load_scene", "save_scene"]
