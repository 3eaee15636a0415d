"""Real survey files and cached artifacts: damaged inputs, partial outputs, implausible coordinates.

* every reader of a file the workflow writes back (scene and template .npz, tiles, scene / detection /
  metrics / object / train JSON, object meshes, model checkpoints) and of the point-cloud formats
  (text, LAS/LAZ, PLY, NPZ) fails on a truncated or garbage file with an error naming the file (and
  the entry or line), and for the workflow's artifacts the fix: delete it and rerun the step;
* a step with several outputs writes all of them or none (`sonardet.io.atomic.atomic_outputs`), and
  `check_writable` refuses an output that cannot be written before the work starts;
* coordinates beyond any survey (1e30) are refused by the readers naming the file, line and value.
"""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path

import numpy as np
import pytest

from sonardet.io.annotations import read_detections, read_scene, write_detections
from sonardet.io.artifacts import FileReadError, read_json_file, read_npz
from sonardet.io.atomic import OutputError, atomic_outputs, atomic_write_text, check_writable
from sonardet.io.points import PointCloud, PointCloudError, iter_chunks, read_points, write_points
from sonardet.io.scenes import read_scene_points, write_scene
from sonardet.io.templates import read_templates

UTM = np.array([5.5e5, 4.18e6, 0.0])


# ------------------------------------------------------------------------------------ damaging files
def truncate(path: Path, keep: float = 0.5) -> Path:
    """Cut a file to a share of its bytes (an interrupted copy or write)."""
    data = path.read_bytes()
    path.write_bytes(data[: max(1, int(len(data) * keep))])
    return path


def garbage(path: Path, n: int = 300) -> Path:
    """Overwrite a file with bytes that are no format at all."""
    path.write_bytes(np.random.default_rng(0).integers(0, 256, n, dtype=np.uint8).tobytes())
    return path


def corrupt_member(path: Path, member: str) -> Path:
    """Flip bytes inside one entry's data of a zip (.npz) archive; its CRC no longer matches."""
    with zipfile.ZipFile(path) as z:
        info = z.getinfo(member)
    data = bytearray(path.read_bytes())
    start = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra)
    for k in range(start + info.compress_size // 2, start + info.compress_size // 2 + 8):
        data[k] ^= 0xFF
    path.write_bytes(bytes(data))
    return path


def scene(tmp_path: Path, sid: str = "s0001") -> tuple[Path, Path]:
    """A small valid scene file pair (soundings + annotations)."""
    rng = np.random.default_rng(1)
    n = 500
    meta = {"schema_version": 1, "scene": sid, "seed": 1, "config_hash": "x", "extent": [0, 10, 0, 10],
            "objects": [{"id": 0, "cls": "reef_cone", "pose": {"t": [5, 5, -11.5], "q": [1, 0, 0, 0]},
                         "box": [5, 5, -10.8, 2, 2, 1.37, 0], "n_points": 40, "visible": True}]}
    parts = {"xyz": rng.uniform([0, 0, -12], [10, 10, -10], (n, 3)), "ping": np.arange(n), "beam": np.arange(n),
             "line": np.zeros(n, np.int64), "label": np.full(n, -1), "meta": meta}
    write_scene(parts, tmp_path / f"{sid}.npz", tmp_path / f"{sid}.json")
    return tmp_path / f"{sid}.npz", tmp_path / f"{sid}.json"


def assert_names_file(exc_info, path: Path, rebuild: bool = True):
    msg = str(exc_info.value)
    assert str(path) in msg, msg
    if rebuild:
        assert "delete it" in msg and "rerun" in msg, msg


# -------------------------------------------------------------------------------- cached artifacts
@pytest.mark.parametrize("damage", ["truncate", "garbage", "member"])
def test_scene_soundings_damaged(tmp_path, damage):
    npz, _ = scene(tmp_path)
    if damage == "truncate":
        truncate(npz)
    elif damage == "garbage":
        garbage(npz)
    else:
        corrupt_member(npz, "xyz.npy")
    with pytest.raises(FileReadError) as exc:
        read_scene_points(npz)
    assert_names_file(exc, npz)
    if damage == "member":
        assert "entry 'xyz'" in str(exc.value)


@pytest.mark.parametrize("damage", ["truncate", "garbage", "not_utf8", "empty"])
def test_scene_and_detection_json_damaged(tmp_path, damage):
    _, js = scene(tmp_path)
    det = tmp_path / "det" / "s0001.json"
    write_detections(det, "s0001", "m", [{"cls": "reef_cone", "box": [5, 5, -11, 2, 2, 1.4, 0], "score": 0.9}])
    for path, reader in ((js, read_scene), (det, read_detections)):
        if damage == "truncate":
            truncate(path)
        elif damage == "garbage":
            garbage(path)
        elif damage == "not_utf8":
            path.write_bytes(path.read_bytes().replace(b'"s0001"', b'"s\xff0001"', 1))
        else:
            path.write_bytes(b"")
        with pytest.raises(ValueError) as exc:
            reader(path)
        assert_names_file(exc, path)
        assert damage == "empty" or "line " in str(exc.value)  # where in the file


def test_non_utf8_detections_name_line_and_byte(tmp_path):
    det = tmp_path / "s0002.json"
    write_detections(det, "s0002", "m", [])
    det.write_bytes(det.read_bytes().replace(b'"m"', b'"\xe9"'))
    with pytest.raises(FileReadError, match=r"s0002\.json: line \d+ \(byte \d+\): not UTF-8 text"):
        read_detections(det)


@pytest.mark.parametrize("damage", ["truncate", "garbage", "member"])
def test_templates_damaged(tmp_path, damage):
    from sonardet.io.templates import TemplateViews, write_templates

    tv = TemplateViews("reef_cone", np.zeros((10, 3)), np.zeros(10, np.int64), np.zeros(10, np.int64),
                       np.zeros(10, np.int64), np.zeros(1), np.array(["x"]), np.zeros(1), np.zeros((1, 3)),
                       np.array([[1.0, 0, 0, 0]]), {"altitude_m": 11.5})
    path = tmp_path / "reef_cone.npz"
    write_templates(path, tv)
    assert read_templates(path).cls == "reef_cone"
    {"truncate": truncate, "garbage": garbage, "member": lambda p: corrupt_member(p, "xyz.npy")}[damage](path)
    with pytest.raises(FileReadError) as exc:
        read_templates(path)
    assert_names_file(exc, path)


@pytest.mark.parametrize("damage", ["truncate", "garbage"])
def test_tiles_and_tile_index_damaged(tmp_path, damage):
    from sonardet.survey import read_tile_index, read_tile_points, split_survey

    rng = np.random.default_rng(2)
    src = tmp_path / "s.xyz"
    write_points(src, PointCloud(rng.uniform([0, 0, -12], [30, 20, -11], (3000, 3)) + UTM))
    doc = split_survey(src, tmp_path / "tiles", tmp_path / "index.json", survey="s", tile_m=12.0)
    tile = tmp_path / doc["tiles"][0]["file"]
    index = tmp_path / "index.json"
    hurt = truncate if damage == "truncate" else garbage
    hurt(tile)
    hurt(index)
    with pytest.raises(PointCloudError) as exc:
        read_tile_points(tile)
    assert_names_file(exc, tile)
    with pytest.raises(ValueError) as exc:
        read_tile_index(index)
    assert str(index) in str(exc.value) and "survey_tiles" in str(exc.value)


@pytest.mark.parametrize("damage", ["truncate", "garbage"])
def test_metrics_train_json_and_pr_curves_damaged(tmp_path, damage):
    from sonardet.report.inputs import read_json, read_metrics, read_pr_curves

    hurt = truncate if damage == "truncate" else garbage
    metrics, train = tmp_path / "metrics.json", tmp_path / "train.json"
    atomic_write_text(metrics, json.dumps({"classes": [], "mAP": {}, "per_class": {}}, indent=1))
    atomic_write_text(train, json.dumps({"train_time_s": 1.0, "steps": 2}, indent=1))
    pr = tmp_path / "pr_curves.npz"
    np.savez(pr, classes=np.array(["a"]), thresholds_m=np.zeros(1), recall=np.zeros(101), precision=np.zeros((1, 1, 101)))
    for path, reader in ((metrics, read_metrics), (train, read_json), (pr, read_pr_curves)):
        hurt(path)
        with pytest.raises(FileReadError) as exc:
            reader(path)
        assert_names_file(exc, path)


@pytest.mark.parametrize("damage", ["truncate", "garbage"])
def test_model_checkpoint_damaged(tmp_path, damage):
    torch = pytest.importorskip("torch")
    from sonardet.detect.sasa import TrainedSASA

    path = tmp_path / "model.pt"
    torch.save({"format": "sonardet-sasa", "weights": torch.zeros(1000)}, path)
    (truncate if damage == "truncate" else garbage)(path)
    with pytest.raises(FileReadError) as exc:
        TrainedSASA.load(path)
    assert_names_file(exc, path)


def test_read_npz_names_a_missing_entry_and_json_names_the_line(tmp_path):
    p = tmp_path / "a.npz"
    np.savez(p, a=np.zeros(3))
    with pytest.raises(FileReadError, match=r"a\.npz: no entry 'xyz'"):
        read_npz(p, "scene soundings file", required=("xyz",))
    j = tmp_path / "a.json"
    j.write_text('{\n "a": 1,\n "b": \n')
    with pytest.raises(FileReadError, match=r"a\.json: line 4, column 1: not valid JSON"):
        read_json_file(j, "metrics file")
    with pytest.raises(FileNotFoundError, match="nope.json"):
        read_json_file(tmp_path / "nope.json", "metrics file")


# ---------------------------------------------------------------------------- point-cloud formats
@pytest.mark.parametrize("suffix", [".xyz", ".xyz.gz", ".csv", ".las", ".laz", ".ply", ".npz"])
@pytest.mark.parametrize("damage", ["truncate", "garbage"])
def test_point_cloud_formats_damaged(tmp_path, suffix, damage):
    rng = np.random.default_rng(3)
    path = tmp_path / f"survey{suffix}"
    write_points(path, PointCloud(rng.uniform([0, 0, -12], [30, 20, -11], (5000, 3)) + UTM,
                                  {"intensity": rng.integers(0, 255, 5000).astype(np.uint16)}))
    (truncate if damage == "truncate" else garbage)(path, *(() if damage == "truncate" else (4000,)))
    for read in (read_points, lambda p: [c for c in iter_chunks(p, chunk_points=1000)]):
        try:
            read(path)
        except (PointCloudError, FileReadError) as exc:
            assert str(path) in str(exc), str(exc)
        else:  # a text file cut at a line end is a shorter valid file, nothing to refuse
            assert suffix in (".xyz", ".csv") and damage == "truncate"


@pytest.mark.filterwarnings("ignore:invalid value encountered in cast:RuntimeWarning")  # laspy writing 1e30
@pytest.mark.parametrize("suffix", [".xyz", ".csv", ".las", ".npz", ".ply"])
def test_implausible_coordinates_are_refused_naming_file_line_and_value(tmp_path, suffix):
    """A sentinel (1e30) in an easting: refused by the reader, naming the file, where and the value,
    whole or chunked; the tiling never sees it."""
    xyz = np.random.default_rng(4).uniform([0, 0, -12], [30, 20, -11], (200, 3)) + UTM
    path = tmp_path / f"bad{suffix}"
    if suffix in (".xyz", ".csv"):
        write_points(path, PointCloud(xyz))
        lines = path.read_text().splitlines()
        k = len(lines) - 200 + 57  # data line of point 57
        cells = lines[k].split("," if suffix == ".csv" else " ")
        cells[0] = "1e30"
        lines[k] = ("," if suffix == ".csv" else " ").join(cells)
        path.write_text("\n".join(lines) + "\n")
        where = f"line {k + 1} (point 57)"
    else:
        ok = PointCloud(xyz)
        write_points(path, ok)
        if suffix == ".las":  # LAS stores scaled integers: an offset of 1e30 is the sentinel's way in
            import laspy

            las = laspy.read(path)
            las.header.offsets = np.array([1e30, las.header.offsets[1], las.header.offsets[2]])
            las.write(path)
            where = "point 0"
        else:
            bad = xyz.copy()
            bad[57, 0] = 1e30
            object.__setattr__(ok, "xyz", bad)  # bypass the object's own check to write the file
            from sonardet.io.points import format_module

            format_module(path).write(path, ok)
            where = "point 57"
    for read in (read_points, lambda p: list(iter_chunks(p, chunk_points=50))):
        with pytest.raises(PointCloudError) as exc:
            read(path)
        msg = str(exc.value)
        assert str(path) in msg and "implausible coordinates" in msg and "1e+30" in msg, msg
        assert where in msg, msg


# --------------------------------------------------------------------------------- all or none
def test_atomic_outputs_writes_all_or_none(tmp_path):
    a, b = tmp_path / "x" / "s0001.json", tmp_path / "y" / "s0001.csv"
    a.parent.mkdir()
    a.write_text("old")
    with pytest.raises(RuntimeError, match="boom"):
        with atomic_outputs([a, b]) as (ta, tb):
            assert ta.name == a.name and tb.name == b.name and ta.parent != a.parent
            write_detections(ta, "s0001", "m", [])  # a writer that checks the file name works on the staged one
            raise RuntimeError("boom")
    assert a.read_text() == "old" and not b.exists()
    assert sorted(os.listdir(a.parent)) == ["s0001.json"] and not any(b.parent.iterdir())
    with atomic_outputs([a, b]) as (ta, tb):
        write_detections(ta, "s0001", "m", [])
        tb.write_text("csv")
    assert read_detections(a)["scene"] == "s0001" and b.read_text() == "csv"
    assert sorted(os.listdir(a.parent)) == ["s0001.json"]  # no staging folder left


def test_atomic_outputs_refuses_a_missing_output_and_names_the_target(tmp_path):
    a, b = tmp_path / "a.json", tmp_path / "b.csv"
    with pytest.raises(OutputError, match=r"b\.csv: the step finished without writing this output"):
        with atomic_outputs([a, b]) as (ta, _):
            ta.write_text("{}")
    assert not a.exists() and not b.exists()
    with pytest.raises(OSError) as exc:
        with atomic_outputs([a, b]) as (_, tb):
            raise PermissionError(13, "Permission denied", str(tb))
    assert str(b) in str(exc.value) and ".staging" not in str(exc.value)
    with pytest.raises(ValueError, match="twice"):
        with atomic_outputs([a, a]):
            pass


def test_check_writable_names_the_paths_that_cannot_be_written(tmp_path):
    (tmp_path / "afile").write_text("x")
    (tmp_path / "adir").mkdir()
    good = tmp_path / "new" / "deep" / "out.json"
    check_writable([good, None, tmp_path / "out.csv"])
    with pytest.raises(OutputError) as exc:
        check_writable([good, tmp_path / "afile" / "out.csv", tmp_path / "adir"])
    msg = str(exc.value)
    assert f"{tmp_path / 'afile' / 'out.csv'}: cannot be written" in msg and "is not a directory" in msg
    assert f"{tmp_path / 'adir'}: cannot be written (is a directory)" in msg and str(good) not in msg


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root may write read-only files")
def test_check_writable_refuses_read_only_files_and_folders(tmp_path):
    ro_dir = tmp_path / "ro"
    ro_dir.mkdir()
    (tmp_path / "ro.csv").write_text("x")
    os.chmod(tmp_path / "ro.csv", 0o444)
    os.chmod(ro_dir, 0o555)
    try:
        with pytest.raises(OutputError) as exc:
            check_writable([tmp_path / "ro.csv", ro_dir / "out.json"])
        assert "read-only" in str(exc.value) and "not writable" in str(exc.value)
    finally:
        os.chmod(ro_dir, 0o755)


def test_write_scene_writes_both_files_or_neither(tmp_path, monkeypatch):
    npz, js = scene(tmp_path)
    before = npz.read_bytes(), js.read_bytes()
    import sonardet.io.scenes as scenes_module

    def fail(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(scenes_module, "atomic_write_text", fail)  # the JSON fails after the soundings
    with pytest.raises(OSError):
        scene(tmp_path)
    assert (npz.read_bytes(), js.read_bytes()) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s0001.json", "s0001.npz"]


def test_csv_tables_read_back_name_the_file(tmp_path):
    from sonardet.report.inputs import read_csv_file

    path = garbage(tmp_path / "loss.csv")
    with pytest.raises(FileReadError) as exc:
        read_csv_file(path, "loss curve (loss.csv)")
    assert_names_file(exc, path)
    with pytest.raises(FileNotFoundError, match="loss.csv"):
        read_csv_file(tmp_path / "x" / "loss.csv", "loss curve")
