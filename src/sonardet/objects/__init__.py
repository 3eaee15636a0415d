"""Object classes (registry of specs), their procedural meshes and the on-disk object files."""

from . import classes
from .catalog import ObjectInfo, canonical_box, mesh_file_check, metadata, object_info, read_object, write_object
from .classes import ClassSpec, build_object, footprint_radius_m
from .meshes import SYMMETRY_CONTINUOUS, ObjectModel

__all__ = [
    "SYMMETRY_CONTINUOUS",
    "ClassSpec",
    "ObjectInfo",
    "ObjectModel",
    "build_object",
    "canonical_box",
    "classes",
    "footprint_radius_m",
    "read_object",
    "mesh_file_check",
    "metadata",
    "object_info",
    "write_object",
]
