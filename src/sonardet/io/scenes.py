"""TEMPORARY shim until the io layer lands: scene soundings reader."""

from ..sim.scene import load_scene_points as read_scene_points  # noqa: F401
