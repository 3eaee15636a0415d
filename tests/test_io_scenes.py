"""The scene file pair (sonardet.io.scenes): the writer validates what it writes, the bytes are those of
`numpy.savez` + `json.dumps(meta, indent=1)`, and reading a scene imports no simulator library."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest
from conftest import REPO

from sonardet.io.annotations import AnnotationError
from sonardet.io.scenes import SOUNDING_FIELDS, read_scene, read_scene_points, write_scene


def _scene(n: int = 50, seed: int = 0) -> dict:
    """A small scene as a mapping: soundings in the scene frame (m) and a valid scene document."""
    rng = np.random.default_rng(seed)
    xyz = np.c_[rng.uniform(0, 10, (n, 2)), rng.normal(-11.0, 0.05, n)]
    label = np.full(n, -1, np.int32)
    label[:10] = 0
    meta = {"schema_version": 1, "scene": "s0001", "seed": 3, "config_hash": "abc", "extent": [0, 10, 0, 10],
            "objects": [{"id": 0, "cls": "reef_cone", "pose": {"t": [1.0, 2.0, -11.0], "q": [1.0, 0.0, 0.0, 0.0]},
                         "box": [1.0, 2.0, -10.5, 1.2, 1.2, 1.0, 0.0], "n_points": 10, "visible": True}],
            "stats": {"n_points": n}}
    return {"xyz": xyz, "ping": np.arange(n, dtype=np.int32), "beam": (np.arange(n) % 7).astype(np.int16),
            "line": np.zeros(n, np.int16), "label": label, "meta": meta}


def test_round_trip_and_bytes_are_numpy_savez_and_json_dumps(tmp_path):
    scene = _scene()
    write_scene(scene, tmp_path / "s0001.npz", tmp_path / "s0001.json")
    buf = io.BytesIO()
    np.savez(buf, **{k: scene[k] for k in ("xyz", *SOUNDING_FIELDS)})
    assert (tmp_path / "s0001.npz").read_bytes() == buf.getvalue()
    assert (tmp_path / "s0001.json").read_text() == json.dumps(scene["meta"], indent=1)
    pts = read_scene_points(tmp_path / "s0001.npz")
    assert list(pts) == ["xyz", *SOUNDING_FIELDS]
    for k in pts:
        assert pts[k].dtype == scene[k].dtype and np.array_equal(pts[k], scene[k])
    assert read_scene(tmp_path / "s0001.json")["objects"][0]["n_points"] == 10


def test_a_scene_object_is_written_like_its_mapping(tmp_path):
    scene = _scene()
    write_scene(scene, tmp_path / "a.npz", tmp_path / "a.json")
    write_scene(SimpleNamespace(**scene), tmp_path / "b.npz", tmp_path / "b.json")
    assert (tmp_path / "a.npz").read_bytes() == (tmp_path / "b.npz").read_bytes()
    assert (tmp_path / "a.json").read_bytes() == (tmp_path / "b.json").read_bytes()


@pytest.mark.parametrize("field, value, match", [
    ("xyz", np.zeros((5, 2)), r"'xyz' must be an \(N,3\) array"),
    ("xyz", np.zeros((50, 3), np.float32), "'xyz' must be float64"),
    ("xyz", np.where(np.arange(150).reshape(50, 3) == 64, np.nan, 0.0), "NaN/Inf at row 21"),
    ("label", np.zeros(49, np.int32), "'label' must be a 1-D array of 50 entries"),
    ("beam", np.zeros((50, 1), np.int16), "'beam' must be a 1-D array of 50 entries"),
    ("ping", np.zeros(50), "'ping' must hold integers, found float64"),
])
def test_writer_refuses_bad_soundings_and_writes_nothing(tmp_path, field, value, match):
    scene = {**_scene(), field: value}
    with pytest.raises(ValueError, match=match) as err:
        write_scene(scene, tmp_path / "s.npz", tmp_path / "s.json")
    assert str(tmp_path / "s.npz") in str(err.value)
    assert not list(tmp_path.iterdir())


def test_writer_validates_the_document_before_writing(tmp_path):
    scene = _scene()
    scene["meta"] = {**scene["meta"], "objects": [{**scene["meta"]["objects"][0], "box": [0, 0, 0]}]}
    with pytest.raises(AnnotationError, match=r"s.json: objects\[0\].box"):
        write_scene(scene, tmp_path / "s.npz", tmp_path / "s.json")
    del scene["meta"]
    with pytest.raises(ValueError, match="lacks \\['meta'\\]"):
        write_scene(scene, tmp_path / "s.npz", tmp_path / "s.json")
    assert not list(tmp_path.iterdir())


def test_reader_names_the_file(tmp_path):
    p = tmp_path / "bad.npz"
    np.savez(p, xyz=np.zeros((4, 3), np.float32))
    with pytest.raises(ValueError, match=f"{p}: 'xyz' must be float64"):
        read_scene_points(p)
    np.savez(p, xyz=np.zeros((4, 3)), label=np.zeros(3, np.int32))
    with pytest.raises(ValueError, match="'label' has 3 entries for 4 points"):
        read_scene_points(p)


def test_reading_a_scene_imports_no_simulator_library(tmp_path):
    """Reading a scene needs numpy only: not MuJoCo, Open3D, trimesh (the simulator's) nor pandas."""
    write_scene(_scene(), tmp_path / "s0001.npz", tmp_path / "s0001.json")
    code = (
        "import sys\n"
        "from sonardet.io.scenes import read_scene, read_scene_points\n"
        f"pts = read_scene_points({str(tmp_path / 's0001.npz')!r})\n"
        f"doc = read_scene({str(tmp_path / 's0001.json')!r})\n"
        "assert len(pts['xyz']) == 50 and doc['scene'] == 's0001'\n"
        "heavy = [m for m in ('mujoco', 'open3d', 'trimesh', 'pandas') if m in sys.modules]\n"
        "assert 'mujoco' not in sys.modules and 'open3d' not in sys.modules, heavy\n"
        "assert not heavy, heavy\n"
    )
    env = {**os.environ, "PYTHONPATH": str(REPO / "src")}
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert res.returncode == 0, res.stderr
