"""Shared fixtures."""

from __future__ import annotations

from pathlib import Path

import pytest

from sonardet.config import validate_config

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data" / "real"


@pytest.fixture(scope="session")
def default_config() -> dict:
    """The default config with every schema default filled in."""
    from sonardet.config import load_config

    return load_config(REPO / "config" / "config.yaml")


@pytest.fixture(scope="session")
def smoke_config() -> dict:
    from sonardet.config import load_config

    return load_config(REPO / "tests" / "config" / "smoke.yaml")


@pytest.fixture(scope="session")
def built_objects(default_config):
    """The four default class models (built once per session)."""
    from sonardet.objects import build_object

    return {c: build_object(c, default_config["objects"]) for c in default_config["classes"]}


__all__ = ["REPO", "SHARED_DATA", "validate_config"]
