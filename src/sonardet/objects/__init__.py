"""Procedural meshes of the reef element classes and their metadata."""

from .catalog import ObjectInfo, canonical_box, metadata, read_object, write_object
from .meshes import KNOWN_CLASSES, SYMMETRY_CONTINUOUS, ObjectModel, build_object

__all__ = [
    "KNOWN_CLASSES",
    "SYMMETRY_CONTINUOUS",
    "ObjectInfo",
    "ObjectModel",
    "build_object",
    "canonical_box",
    "metadata",
    "read_object",
    "write_object",
]
