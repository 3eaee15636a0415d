"""SASA detector: shapes, losses, learning, checkpoints, box coder, determinism (tiny models, CPU).

Scenes are synthesized here in a few milliseconds: a noisy, gently sloping seabed plane plus the
visible surfaces (top and four sides) of a few class-sized boxes, written in the scene contract
(npz + json), so the tests do not depend on the simulator or on results/.
"""

from __future__ import annotations

import json
import math
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from sonardet.detect.sasa import (ConfigMismatchError, SASADetector, TrainedSASA, detect_points, infer, infer_models,
                                  resolve_params, train)
from sonardet.detect.sasa.box_coder import PointBinResidualCoder
from sonardet.detect.sasa.data import PaddingWarning, augment, collate, prepare_scene, sample_points
from sonardet.detect.sasa.losses import assign_points, box_corners, points_in_boxes
from sonardet.detect.sasa.trainer import _make_batch, evaluate_scenes, ground_truth
from sonardet.geometry import box_corners as np_box_corners
from sonardet.geometry import points_in_box

pytestmark = pytest.mark.usefixtures("one_torch_thread")

SIZES = {  # l, w, h (m) of the four classes, as in the default objects
    "reef_ring": (2.7, 2.7, 0.8),
    "reef_cone": (2.0, 2.0, 1.4),
    "tetrapod_b": (2.3, 2.5, 2.1),
    "tetrapod_s": (1.6, 1.7, 1.5),
}
CLASSES = list(SIZES)

#: A tiny network for tests: 1024 input points, 64 / 32 / 16 SA centres (8 candidates per scene).
TINY = {
    "n_points": 1024,
    "sa_npoints": [128, 64, 32],
    "sa_radii_m": [[0.4, 0.8], [0.8, 1.6], [1.6, 2.4]],
    "sa_nsamples": [[8, 8], [8, 8], [8, 8]],
    "sa_mlps": [[[8, 16], [8, 16]], [[16, 32], [16, 32]], [[32, 32], [32, 32]]],
    "sa_aggregation": [16, 32, 32],
    "sa_confidence_mlps": [[16], [16]],
    "vote_mlp": [16],
    "vote_radii_m": [1.0, 2.0],
    "vote_nsamples": [8, 8],
    "vote_mlps": [[32, 32], [32, 32]],
    "head_shared_fc": [32],
    "head_cls_fc": [32],
    "head_reg_fc": [32],
    "batch_size": 2,
    "epochs": 1,
    "lr": 0.01,
    "progress": False,
    "num_threads": None,
}


def _box_surface(box, density, rng):
    """Points (n, 3) on the top and the four sides of a box [x,y,z,l,w,h,yaw] (m), ~density /m^2."""
    x, y, z, l, w, h, yaw = box
    faces = []
    n_top = max(1, int(density * l * w))
    faces.append(np.c_[rng.uniform(-l / 2, l / 2, n_top), rng.uniform(-w / 2, w / 2, n_top), np.full(n_top, h / 2)])
    for ax, (a, b) in ((0, (l, w)), (1, (w, l))):
        n = max(1, int(density * b * h))
        for sgn in (-1, 1):
            u = np.full(n, sgn * a / 2)
            v = rng.uniform(-b / 2, b / 2, n)
            zz = rng.uniform(-h / 2, h / 2, n)
            faces.append(np.c_[u, v, zz] if ax == 0 else np.c_[v, u, zz])
    p = np.vstack(faces)
    c, s = math.cos(yaw), math.sin(yaw)
    return np.c_[x + c * p[:, 0] - s * p[:, 1], y + s * p[:, 0] + c * p[:, 1], z + p[:, 2]]


def make_scene(tmp_path, sid, seed, classes, extent=14.0, density=40.0, origin=(500000.0, 4000000.0, -11.5)):
    """Write a synthetic scene {sid}.npz/.json (far-from-zero origin, like UTM) and return the npz path."""
    rng = np.random.default_rng(seed)
    n_ground = int(density * extent * extent)
    gxy = rng.uniform(0, extent, (n_ground, 2))
    gz = 0.02 * gxy[:, 0] + rng.normal(0, 0.02, n_ground)
    pts, labels, objects = [np.c_[gxy, gz]], [np.full(n_ground, -1)], []
    slots = [(3.5, 3.5), (10.5, 3.5), (3.5, 10.5), (10.5, 10.5), (7.0, 7.0)]
    for i, cls in enumerate(classes):
        l, w, h = SIZES[cls]
        cx, cy = slots[i]
        cx, cy = cx + rng.uniform(-0.5, 0.5), cy + rng.uniform(-0.5, 0.5)
        yaw = 0.0 if cls.startswith("reef") else float(rng.uniform(-math.pi / 3, math.pi / 3))
        ground = 0.02 * cx
        box = [cx, cy, ground + h / 2, l, w, h, yaw]
        p = _box_surface(box, density, rng)
        pts.append(p)
        labels.append(np.full(len(p), i))
        b = [float(v) for v in box]
        b[0] += origin[0]
        b[1] += origin[1]
        b[2] += origin[2]
        objects.append({"id": i, "cls": cls, "pose": {"t": b[:3], "q": [1.0, 0.0, 0.0, 0.0]}, "box": b,
                        "n_points": int(len(p)), "visible": True})
    xyz = np.vstack(pts) + np.asarray(origin)
    npz = tmp_path / f"{sid}.npz"
    np.savez(npz, xyz=xyz.astype(np.float64), label=np.concatenate(labels).astype(np.int64))
    doc = {"schema_version": 1, "scene": sid, "seed": seed, "config_hash": "test", "extent": [0, extent, 0, extent],
           "objects": objects}
    (tmp_path / f"{sid}.json").write_text(json.dumps(doc))
    return npz


def _batch(tmp_path, params, classes_per_scene=(("reef_ring", "tetrapod_b"), ("reef_cone", "tetrapod_s")), aug=False):
    paths = [make_scene(tmp_path, f"b{i}", i, list(c)) for i, c in enumerate(classes_per_scene)]
    scenes = [prepare_scene(p, params) for p in paths]
    return _make_batch(scenes, params, np.random.default_rng(0), "cpu", aug), scenes


def test_forward_backward_shapes(tmp_path):
    p = resolve_params(TINY)
    batch, _ = _batch(tmp_path, p)
    torch.manual_seed(0)
    model = SASADetector(p)
    out = model(batch)
    bb, head = out["backbone"], out["head"]
    assert [x.shape for x in bb["xyz"]] == [(2, 128, 3), (2, 64, 3), (2, 32, 3)]
    assert bb["logits"][0].shape == (2, 128) and bb["logits"][1].shape == (2, 64) and bb["logits"][2] is None
    assert bb["features"][2].shape == (2, 32, 32)
    assert head["votes"].shape == (2, 16, 3) and head["candidates"].shape == (2, 16, 3)
    assert head["cls_logits"].shape == (2, 16, 4)
    assert head["box_codes"].shape == (2, 16, 6 + 2 * p["angle_bins"])
    off = (head["votes"] - head["candidates"]).abs()
    assert torch.all(off <= torch.tensor(p["vote_range_m"]) + 1e-6)
    loss, parts = model.loss(out, batch)
    assert loss.ndim == 0 and torch.isfinite(loss)
    loss.backward()
    grads = [q.grad for q in model.parameters() if q.requires_grad]
    assert all(g is not None and torch.isfinite(g).all() for g in grads)
    # the segmentation branches and the vote layer get gradient
    assert model.backbone.layers[0].confidence[-1].weight.grad.abs().sum() > 0
    assert model.head.vote_layer[-1].weight.grad.abs().sum() > 0
    preds = model.eval().predict(model(batch))
    assert len(preds) == 2 and preds[0]["boxes"].shape[1] == 7


def test_batch_without_objects_trains_without_nan(tmp_path):
    """Hard case: scenes with no objects at all (every target negative, no positives for box losses)."""
    p = resolve_params({**TINY, "ground_filter": False})
    batch, _ = _batch(tmp_path, p, classes_per_scene=((), ()))
    assert (batch["gt_cls"] < 0).all()
    torch.manual_seed(0)
    model = SASADetector(p)
    opt = torch.optim.Adam(model.parameters(), 1e-2)
    for _ in range(3):
        loss, parts = model.loss(model(batch), batch)
        assert torch.isfinite(loss), parts
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert parts["n_pos"] == 0 and parts["reg"] == 0.0
    assert all(torch.isfinite(q).all() for q in model.parameters())


def test_overfits_two_small_scenes(tmp_path):
    """A real learning test: a tiny model fits two small scenes (4 classes) to high AP in 200 steps."""
    paths = [make_scene(tmp_path, "o0", 10, ["reef_ring", "reef_cone", "tetrapod_b", "tetrapod_s"]),
             make_scene(tmp_path, "o1", 11, ["tetrapod_s", "tetrapod_b", "reef_cone", "reef_ring"])]
    params = {**TINY, "epochs": 200, "lr": 0.01, "batch_size": 2, "aug_rotation_rad": 0.0, "aug_flip_x": False,
              "aug_flip_y": False, "aug_object_prob": 0.0, "aug_scale": [1.0, 1.0], "score_thresh": 0.05,
              "n_points": 1024, "sa_npoints": [256, 128, 64]}
    summary = train(paths, [], params, tmp_path / "run", resume=False)
    assert summary["steps"] == 200
    dets, timing = infer(tmp_path / "run" / "model.pt", paths, {**params})
    assert timing["n_scenes"] == 2 and timing["s_per_scene"] > 0 and timing["device"] == "cpu"
    m = evaluate_scenes(dets, paths, resolve_params(params), dist_thresholds_m=(0.5, 1.0))
    assert m["mAP"]["1.0"] >= 0.9, m["mAP"]
    assert m["mAP"]["0.5"] >= 0.75, m["mAP"]
    # A development evaluation during training: labels read once, the headline distance alone; the
    # same headline mAP (each distance is matched on its own).
    once = evaluate_scenes(dets, [], resolve_params(params), dist_thresholds_m=(0.5,), gt=ground_truth(paths, CLASSES))
    assert once["mAP_headline"] == m["mAP_headline"] == m["mAP"]["0.5"] and list(once["mAP"]) == ["0.5"]
    # the written artifacts
    run = tmp_path / "run"
    lines = (run / "loss.csv").read_text().splitlines()
    assert len(lines) == 201 and lines[0].startswith("epoch,")
    info = json.loads((run / "train.json").read_text())
    assert info["steps"] == 200 and info["train_time_s"] > 0 and info["peak_rss_mb"] > 0
    # the allocator setting of the training (sonardet.allocator), in force on glibc
    assert info["freed_memory_kept"] is (sys.platform.startswith("linux") and info["params"]["retain_freed_memory"])


def test_padding_warns(tmp_path):
    p = resolve_params({**TINY, "n_points": 4096})
    npz = make_scene(tmp_path, "pad", 3, ["reef_ring"], extent=8.0, density=10.0)
    scene = prepare_scene(npz, p)
    assert len(scene.xyz) < 4096
    with pytest.warns(PaddingWarning, match="pad"):
        idx = sample_points(len(scene.xyz), 4096, np.random.default_rng(0), scene.scene_id)
    assert idx.shape == (4096,)
    assert set(np.unique(idx)) == set(range(len(scene.xyz)))  # every point kept at least once
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sample_points(5000, 4096, np.random.default_rng(0))  # enough points: no warning


def test_checkpoint_from_other_config_is_refused(tmp_path):
    paths = [make_scene(tmp_path, "c0", 0, ["reef_ring", "tetrapod_s"])]
    params = {**TINY, "epochs": 2, "batch_size": 1, "val_every_epochs": 1}
    s = train(paths, paths, params, tmp_path / "run", resume=False)
    assert s["val"] is not None and "val_mAP" in (tmp_path / "run" / "loss.csv").read_text()
    with pytest.raises(ConfigMismatchError, match="n_points: checkpoint 1024 vs now 2048"):
        train(paths, [], {**params, "n_points": 2048}, tmp_path / "run", resume=True)
    with pytest.raises(ConfigMismatchError, match="lr: checkpoint 0.01 vs now 0.02"):
        train(paths, [], {**params, "lr": 0.02}, tmp_path / "run", resume=True)
    other = [make_scene(tmp_path, "c1", 1, ["reef_cone"])]
    with pytest.raises(ConfigMismatchError, match="train_scenes"):
        train(other, [], params, tmp_path / "run", resume=True)
    # inference may change inference keys (training-only keys are ignored), not network/input keys
    dets, _ = infer(tmp_path / "run" / "model.pt", paths, {**params, "score_thresh": 0.0, "epochs": 9})
    # an in-memory cloud (a user's survey) gives the same detections as the scene file
    xyz = np.load(paths[0])["xyz"]
    same = detect_points(tmp_path / "run" / "model.pt", xyz, {"score_thresh": 0.0}, scene_id="c0")
    assert len(same) == len(dets["c0"]) > 0
    assert np.allclose([d["box"] for d in same], [d["box"] for d in dets["c0"]])
    assert all(abs(d["box"][0] - 500000.0) < 50 for d in same)  # scene frame (UTM-like), not local
    # a model loaded once and called per cloud gives the same, call after call
    sasa = TrainedSASA.load(tmp_path / "run" / "model.pt", {"score_thresh": 0.0})
    for _ in range(2):
        again, stats = sasa(xyz, "c0")
        assert again == same and stats["n_detections"] == len(same) and stats["n_points"] == len(xyz)
    assert sasa.detect_file(paths[0]) == ("c0", dets["c0"])
    # clouds with nothing to fit: no error, finite boxes; an empty one is "nothing to detect"
    rng = np.random.default_rng(1)
    for cloud in (np.array([[1.0, 2.0, -11.0]]), np.tile([[1.0, 2.0, -11.0]], (300, 1)),
                  np.column_stack([np.linspace(0, 30, 2000), np.zeros(2000), np.full(2000, -11.0)]),
                  np.column_stack([rng.uniform(0, 1, (8, 2)), np.full(8, -11.0)])):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", PaddingWarning)
            got, stats = sasa(cloud, "d")
        assert stats["n_points"] == len(cloud) and all(np.all(np.isfinite(d["box"])) for d in got)
    with pytest.warns(UserWarning, match="nothing to detect"):
        assert sasa(np.zeros((0, 3)), "e")[0] == []
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        sasa(np.zeros((4, 2)), "bad")
    with pytest.raises(ConfigMismatchError, match="sa_npoints"):
        infer(tmp_path / "run" / "model.pt", paths, {**params, "sa_npoints": [64, 32, 16]})
    # a finished checkpoint with the same settings resumes to the end without new steps
    s = train(paths, [], {**params, "num_threads": 1}, tmp_path / "run", resume=True)  # runtime keys may change
    assert s["steps"] == 2


def test_models_sharing_a_run_get_their_own_detections(tmp_path, monkeypatch):
    """`infer_models` (one job for every SASA model on a dataset): each model's detections equal
    `infer`'s of it alone; each scene is read and prepared once for the models that prepare alike, and
    once more for a model that prepares otherwise."""
    from sonardet.detect.sasa import trainer

    paths = [make_scene(tmp_path, "m0", 4, ["reef_ring", "tetrapod_s"]),
             make_scene(tmp_path, "m1", 5, ["reef_cone", "tetrapod_b"])]
    params = {**TINY, "epochs": 1, "batch_size": 1}
    train(paths, [], params, tmp_path / "a", resume=False)
    train(paths, [], {**params, "seed": 7}, tmp_path / "b", resume=False)
    alone = [infer(tmp_path / r / "model.pt", paths, {"score_thresh": 0.0}) for r in "ab"]
    assert all(len(dets[sid]) > 0 for dets, _ in alone for sid in ("m0", "m1"))
    assert alone[0][0] != alone[1][0]  # two different models
    models = [TrainedSASA.load(tmp_path / r / "model.pt", {"score_thresh": 0.0}) for r in "ab"]
    lower = TrainedSASA(models[0].model, {**models[0].params, "ground_height_m": 0.05})
    prepared = []
    real = trainer.prepare_scene
    monkeypatch.setattr(trainer, "prepare_scene", lambda p, *a, **k: prepared.append(Path(p).stem) or real(p, *a, **k))
    shared = infer_models(models + [lower], paths)
    assert [dets for dets, _ in shared[:2]] == [dets for dets, _ in alone]
    assert prepared == ["m0", "m0", "m1", "m1"]  # once for the two models, once for the other ground filter
    assert all(t["n_scenes"] == 2 and t["s_per_scene"] > 0 and t["device"] == "cpu" for _, t in shared)
    assert infer_models([], paths) == []


def test_resume_continues_identically(tmp_path, monkeypatch):
    """An interrupted run resumed from its checkpoint ends with the same weights as an uninterrupted one."""
    import importlib

    tr = importlib.import_module("sonardet.detect.sasa.trainer")  # the module (the package exports train())

    paths = [make_scene(tmp_path, f"r{i}", i, ["reef_cone", "tetrapod_b"]) for i in range(2)]
    params = {**TINY, "epochs": 2, "batch_size": 2}
    a = train(paths, [], params, tmp_path / "a", resume=False)
    real = tr.atomic_write_text
    calls = []

    def interrupt_in_epoch_2(path, text):
        calls.append(path)
        if str(path).endswith("loss.csv") and len(calls) == 2:
            raise KeyboardInterrupt  # after epoch 2's step, before its checkpoint
        real(path, text)

    monkeypatch.setattr(tr, "atomic_write_text", interrupt_in_epoch_2)
    with pytest.raises(KeyboardInterrupt):
        train(paths, [], params, tmp_path / "b", resume=False)
    monkeypatch.setattr(tr, "atomic_write_text", real)
    assert torch.load(tmp_path / "b" / "checkpoint.pt", weights_only=False)["epoch"] == 1
    b = train(paths, [], params, tmp_path / "b", resume=True)
    sa = torch.load(tmp_path / "a" / "model.pt", weights_only=False)["state_dict"]
    sb = torch.load(tmp_path / "b" / "model.pt", weights_only=False)["state_dict"]
    assert all(torch.equal(sa[k], sb[k]) for k in sa)
    assert a["steps"] == b["steps"] == 2


def test_box_coder_round_trip():
    coder = PointBinResidualCoder(12, [0, 0, 3, 3])
    g = torch.Generator().manual_seed(0)
    n = 64
    labels = torch.randint(0, 4, (n,), generator=g)
    yaw = (torch.rand(n, generator=g) * 2 - 1) * math.pi / 3  # tetrapod convention [-pi/3, pi/3)
    yaw = torch.where(labels < 2, torch.zeros_like(yaw), yaw)
    boxes = torch.cat([torch.randn(n, 3, generator=g) * 5, 0.5 + 2 * torch.rand(n, 3, generator=g), yaw[:, None]], 1)
    anchors = boxes[:, :3] + torch.randn(n, 3, generator=g) * 0.5
    reg, bin_id, res, amask = coder.encode(boxes, anchors, labels)
    assert torch.all(res >= -0.5) and torch.all(res < 0.5)
    assert torch.equal(amask, labels >= 2)
    codes = torch.zeros(n, coder.code_size)
    codes[:, :6] = reg
    codes[torch.arange(n), 6 + bin_id] = 10.0
    codes[torch.arange(n), 6 + 12 + bin_id] = res
    dec = coder.decode(codes, anchors, labels)
    assert torch.allclose(dec[:, :6], boxes[:, :6], atol=1e-4)
    assert torch.allclose(dec[:, 6], boxes[:, 6], atol=1e-5)
    # the folded angle: a tetrapod turned by 120 deg is the same box and decodes to the same yaw
    turned = boxes.clone()
    turned[:, 6] += 2 * math.pi / 3
    reg2, b2, r2, _ = coder.encode(turned, anchors, labels)
    codes2 = torch.zeros(n, coder.code_size)
    codes2[:, :6] = reg2
    codes2[torch.arange(n), 6 + b2] = 10.0
    codes2[torch.arange(n), 6 + 12 + b2] = r2
    dec2 = coder.decode(codes2, anchors, labels)
    period = 2 * math.pi / 3
    d = torch.remainder(dec2[:, 6] - boxes[:, 6] + period / 2, period) - period / 2
    assert torch.all(d.abs() < 1e-4)
    assert torch.all(dec2[labels >= 2, 6].abs() <= math.pi / 3 + 1e-5)


def test_corner_order_matches_geometry():
    box = [1.0, -2.0, 0.5, 2.3, 1.5, 1.0, 0.4]
    a = box_corners(torch.tensor(box, dtype=torch.float64)).numpy()
    assert np.allclose(a, np_box_corners(box))


def _points_in_boxes_stacked(points, boxes, valid, extra_m=0.0):
    """The loss's former formulation: every point in every box's frame as one (B, M, K, 3) tensor."""
    d = points[:, :, None, :] - boxes[:, None, :, :3]
    c, s = torch.cos(boxes[:, None, :, 6]), torch.sin(boxes[:, None, :, 6])
    loc = torch.stack([d[..., 0] * c + d[..., 1] * s, -d[..., 0] * s + d[..., 1] * c, d[..., 2]], dim=-1)
    half = 0.5 * (boxes[:, None, :, 3:6] + extra_m)
    return (loc.abs() <= half + 1e-5).all(dim=-1) & valid[:, None, :]


def test_points_in_boxes_agrees_with_the_stacked_form_and_geometry():
    gen = torch.Generator().manual_seed(3)
    boxes = torch.cat([torch.rand(2, 6, 3, generator=gen) * 8 - 4, 0.5 + torch.rand(2, 6, 3, generator=gen) * 2,
                       torch.rand(2, 6, 1, generator=gen) * 2 * math.pi], dim=-1)
    valid = torch.ones(2, 6, dtype=torch.bool)
    valid[1, 4:] = False  # padded boxes contain nothing
    pts = torch.rand(2, 3000, 3, generator=gen) * 10 - 5
    # points on and just off the faces of box (0, 0), where rounding decides
    x, y, z, l, w, h, yaw = boxes[0, 0].tolist()
    u = torch.tensor([0.5 * l, -0.5 * l, 0.5 * l + 1e-5, 0.0, 0.0, 0.0])
    v = torch.tensor([0.0, 0.0, 0.0, 0.5 * w, -0.5 * w - 2e-5, 0.0])
    hz = torch.tensor([0.0, 0.0, 0.0, 0.0, 0.0, 0.5 * h])
    face = torch.stack([x + u * math.cos(yaw) - v * math.sin(yaw), y + u * math.sin(yaw) + v * math.cos(yaw),
                        z + hz], dim=-1)
    pts[0, :len(face)] = face
    for extra in (0.0, 0.4):
        got = points_in_boxes(pts, boxes, valid, extra)
        assert torch.equal(got, _points_in_boxes_stacked(pts, boxes, valid, extra))
        for b in range(2):
            for k in range(6):
                mask = got[b, :, k].numpy()
                if not valid[b, k]:
                    assert not mask.any()
                    continue
                ref = points_in_box(pts[b].double().numpy(), boxes[b, k].double().numpy(), 0.5 * extra)
                assert ref.any() and (~ref).any()
                assert (mask != ref).sum() <= 3  # float32 and float64 differ only on the faces
    idx, inside = assign_points(pts, boxes, valid, 0.4)
    assert torch.equal(inside, _points_in_boxes_stacked(pts, boxes, valid, 0.4))
    d2 = ((pts[:, :, None, :] - boxes[:, None, :, :3]) ** 2).sum(-1).masked_fill(~inside, float("inf"))
    assert torch.equal(idx, torch.where(inside.any(-1), d2.argmin(-1), -1))


def test_augmentation_keeps_points_in_their_boxes(tmp_path):
    # the synthetic tetrapods are plain boxes (not 3-fold symmetric): give them symmetry order 1 here
    p = resolve_params({**TINY, "aug_object_prob": 1.0,
                        "symmetry_orders": {"reef_ring": 0, "reef_cone": 0, "tetrapod_b": 1, "tetrapod_s": 1}})
    npz = make_scene(tmp_path, "aug", 5, ["reef_ring", "tetrapod_b", "tetrapod_s"])
    s = prepare_scene(npz, p)
    idx = sample_points(len(s.xyz), 1024, np.random.default_rng(0))
    for seed in range(5):
        xyz, h, boxes = augment(s.xyz[idx], s.height[idx], s.label[idx], s.boxes, s.cls, s.obj_id, p,
                                np.random.default_rng(seed), s.axis)
        for k, oid in enumerate(s.obj_id):
            m = s.label[idx] == oid
            if s.cls[k] >= 2:  # tetrapods: the box turns with the points
                inside = points_in_box(xyz[m], boxes[k], margin_m=0.05)
                assert inside.mean() > 0.97, (seed, k, inside.mean())
            else:  # yaw-free class (a real ring is round; the synthetic one is square): centre moves along
                assert np.linalg.norm(xyz[m, :2].mean(0) - boxes[k, :2]) < 0.3
        assert np.all(boxes[s.cls == 0][:, 6] == 0)  # reef_ring: yaw-free
        assert 0.97 * 2.7 - 1e-3 <= boxes[s.cls == 0][0, 3] <= 1.03 * 2.7 + 1e-3  # narrow scaling


def test_augmented_box_of_threefold_object_is_canonical():
    """Hard case: a 3-fold symmetric object (tetrapod-like) whose box centre is off its axis. After any
    augmentation the label must equal the box the simulator would give: the box of the turned points
    at the canonical yaw in [-pi/3, pi/3)."""
    from sonardet.geometry import box_from_points

    axis = np.array([3.0, -2.0, 0.0])
    legs = []
    for j in range(3):  # three legs at 120 deg, plus a vertical one
        phi = 0.3 + 2 * math.pi * j / 3
        t = np.linspace(0, 1.2, 200)  # identical legs: exactly 3-fold symmetric
        legs.append(np.c_[axis[0] + t * math.cos(phi), axis[1] + t * math.sin(phi), 0.3 * t])
    t = np.linspace(0, 1.5, 200)
    legs.append(np.c_[np.full(200, axis[0]), np.full(200, axis[1]), t])
    pts = np.vstack(legs).astype(np.float32)
    yaw0 = 0.1
    box0 = box_from_points(pts, yaw0)
    assert np.hypot(*(box0[:2] - axis[:2])) > 0.1  # the box centre is off the axis
    params = resolve_params({"aug_object_prob": 1.0, "aug_scale": [1.0, 1.0]})
    label = np.zeros(len(pts), np.int64)
    for seed in range(20):
        xyz, _, boxes = augment(pts, np.zeros(len(pts)), label, box0[None].astype(np.float32), np.array([2]),
                                np.array([0]), params, np.random.default_rng(seed), axis[None])
        b = boxes[0].astype(np.float64)
        assert -math.pi / 3 - 1e-6 <= b[6] < math.pi / 3 + 1e-6
        ref = box_from_points(xyz.astype(np.float64), b[6])
        assert np.allclose(b[:6], ref[:6], atol=2e-3), (seed, b, ref)


def test_training_step_is_deterministic(tmp_path):
    p = resolve_params(TINY)

    def one_step():
        batch, _ = _batch(tmp_path, p, aug=True)
        torch.manual_seed(p["seed"])
        model = SASADetector(p)
        opt = torch.optim.AdamW(model.parameters(), lr=0.01)
        loss, _ = model.loss(model(batch), batch)
        opt.zero_grad()
        loss.backward()
        opt.step()
        return float(loss.detach()), {k: v.detach().clone() for k, v in model.state_dict().items()}

    l1, s1 = one_step()
    l2, s2 = one_step()
    assert l1 == l2
    assert all(torch.equal(s1[k], s2[k]) for k in s1)


def test_collate_pads_boxes():
    items = [(np.zeros((8, 3), np.float32), np.zeros(8, np.float32), np.ones((2, 7), np.float32), np.array([0, 1])),
             (np.zeros((8, 3), np.float32), np.zeros(8, np.float32), np.zeros((0, 7), np.float32),
              np.zeros(0, np.int64))]
    b = collate(items, "cpu")
    assert b["gt_boxes"].shape == (2, 2, 7) and b["features"].shape == (2, 8, 1)
    assert b["gt_cls"].tolist() == [[0, 1], [-1, -1]]


def test_unknown_parameter_is_named():
    with pytest.raises(ValueError, match="unknown SASA parameter 'n_point'"):
        resolve_params({"n_point": 10})


def test_epochs_are_chosen_on_the_dev_scenes(tmp_path):
    """The dev mAP is measured every val_every_epochs, the best model is kept and training stops after
    early_stop_patience evaluations without improvement (the cap is `epochs`)."""
    train_set = [make_scene(tmp_path, f"s{i:04d}", i, CLASSES[:2]) for i in range(2)]
    dev = [make_scene(tmp_path, f"d{i:04d}", 10 + i, CLASSES[:2]) for i in range(2)]
    params = {**TINY, "classes": CLASSES, "epochs": 8, "lr": 0.002, "val_every_epochs": 1,
              "early_stop_patience": 2, "early_stop_min_delta": 0.5,  # an impossible gain: stops after 3 evals
              "early_stop_min_epoch_frac": 0.0}
    out = tmp_path / "run"
    summary = train(train_set, dev, params, out)
    rows = (out / "loss.csv").read_text().splitlines()
    header = rows[0].split(",")
    assert "val_mAP" in header and len(rows) - 1 == summary["epochs"] == 3 and summary["stopped_early"]
    assert summary["epochs_cap"] == 8 and summary["best_epoch"] == 1
    assert summary["n_parameters"] > 1000 and summary["n_points"] == TINY["n_points"]
    # model.pt is the best epoch's model: its dev mAP is the one recorded for that epoch.
    first = dict(zip(header, rows[1].split(",")))
    assert summary["val"]["mAP_headline"] == pytest.approx(float(first["val_mAP"]), abs=1e-9)
    # Resuming a finished, early-stopped run trains nothing more.
    again = train(train_set, dev, params, out)
    assert again["epochs"] == 3 and again["steps"] == summary["steps"]
    # No stop while the one-cycle LR is high: not before early_stop_min_epoch_frac of the cap.
    late = train(train_set, dev, {**params, "early_stop_min_epoch_frac": 0.5}, tmp_path / "late")
    assert late["epochs"] == 4 and late["stopped_early"] and late["best_epoch"] == 1
    # The default: to the cap (the one-cycle schedule anneals only at its end), the best dev checkpoint kept.
    full = train(train_set, dev, {k: v for k, v in params.items() if k != "early_stop_min_epoch_frac"},
                 tmp_path / "full")
    assert full["epochs"] == 8 and not full["stopped_early"] and full["best_epoch"] == 1


@pytest.mark.slow
def test_study_preset_runs_on_cpu(tmp_path):
    """The study's SASA (reference network, 16384 raw points, no ground filter) takes a training step
    and detects on CPU (slowly; the full budget is meant for a GPU)."""
    from sonardet.detect.sasa import STUDY

    scenes = [make_scene(tmp_path, f"s{i:04d}", i, CLASSES, density=90.0) for i in range(2)]
    params = resolve_params({"classes": CLASSES, "batch_size": 2, "epochs": 1, "val_every_epochs": 0,
                             "progress": False}, STUDY)
    assert params["ground_filter"] is False and params["n_points"] == 16384 and params["nms_iou"] == 0.01
    summary = train(scenes, [], params, tmp_path / "study")
    assert summary["steps"] == 1 and summary["n_parameters"] > 2_000_000
    assert summary["kept_points_per_scene"]["min"] > 16384  # every sounding kept: seabed included
    dets, _ = infer(tmp_path / "study" / "model.pt", scenes[:1], params={"num_threads": 1, "progress": False})
    assert set(dets) == {"s0000"}
