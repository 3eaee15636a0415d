"""TEMPORARY shim until the io layer lands: template scans reader."""

from ..sim.templates import load_templates as read_templates  # noqa: F401
