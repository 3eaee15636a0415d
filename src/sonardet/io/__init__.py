"""Readers and writers: point clouds, annotations, detections; atomic writes; local origins."""
