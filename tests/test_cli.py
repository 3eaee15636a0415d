"""The `sonardet` command line."""

import subprocess
import sys

import numpy as np
import pytest

from sonardet.cli import main
from sonardet.io.points import read_points


@pytest.fixture
def scene_npz(tmp_path):
    rng = np.random.default_rng(0)
    n = 500
    p = tmp_path / "s0000.npz"
    np.savez(p, xyz=rng.uniform([0, 0, -12], [40, 40, -10], (n, 3)), ping=np.arange(n, dtype=np.int32),
             beam=(np.arange(n) % 256).astype(np.int16), line=np.zeros(n, np.int16),
             label=np.where(np.arange(n) < 50, 0, -1).astype(np.int32))
    return p


@pytest.mark.parametrize("suffix", [".las", ".ply", ".xyz"])
def test_export_scene_round_trip(scene_npz, tmp_path, suffix):
    out = tmp_path / f"scene{suffix}"
    assert main(["export-scene", str(scene_npz), str(out)]) == 0
    back = read_points(out)
    src = np.load(scene_npz)["xyz"]
    tol = 1e-3 if suffix == ".las" else 1e-9
    assert np.allclose(back.xyz, src, atol=tol)
    assert np.array_equal(np.asarray(back.attributes["label"]).astype(int), np.load(scene_npz)["label"])


def test_export_scene_bad_input_is_a_clear_error(tmp_path, capsys):
    bad = tmp_path / "bad.npz"
    np.savez(bad, xyz=np.full((3, 3), np.nan))
    assert main(["export-scene", str(bad), str(tmp_path / "o.las")]) == 2
    assert "bad.npz" in capsys.readouterr().err


def test_console_script_installed():
    proc = subprocess.run([sys.executable, "-m", "sonardet.cli", "--help"], capture_output=True, text=True)
    assert proc.returncode == 0 and "export-scene" in proc.stdout
