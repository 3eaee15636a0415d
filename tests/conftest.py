"""Shared fixtures."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from sonardet.config import validate_config

REPO = Path(__file__).resolve().parents[1]


def _real_data_dir() -> Path | None:
    """Folder of the real R2Sonic survey line: $SONARDET_REAL_DATA, or ../shared/data/real beside the
    repository. In CI the data must be there (a silent skip would hide a broken checkout)."""
    for folder in (os.environ.get("SONARDET_REAL_DATA", ""), str(REPO.parent / "shared" / "data" / "real")):
        if folder and (Path(folder) / "r2sonic_sfbay.xyz.gz").is_file():
            return Path(folder)
    if os.environ.get("CI", "").lower() == "true":
        raise RuntimeError("CI: the real survey data ../shared/data/real/r2sonic_sfbay.xyz.gz is missing")
    return None


#: The real-data folder, or None when it is not available (tests using it are skipped locally).
REAL_DIR = _real_data_dir()
REAL_FILE = REAL_DIR / "r2sonic_sfbay.xyz.gz" if REAL_DIR else None
needs_real = pytest.mark.skipif(REAL_DIR is None, reason="real survey data not available")


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


__all__ = ["REAL_DIR", "REAL_FILE", "REPO", "needs_real", "validate_config"]
