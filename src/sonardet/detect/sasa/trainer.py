"""Training and inference of the SASA detector (function API used by the workflow and the CLI).

* :func:`train` -- fits a model on prepared training scenes and writes ``model.pt``, ``loss.csv``
  (one row per epoch) and ``train.json`` (time, steps, seconds per step, peak memory, validation mAP)
  into ``out_dir``, the three together at the end (all or none); ``checkpoint.pt`` and the loss curve
  so far, ``checkpoint_loss.csv``, are written after every epoch and resumed from (a checkpoint of
  another config or another training set is refused with a message naming the setting).
* :class:`TrainedSASA` -- a saved model loaded once (``TrainedSASA.load(model.pt)``) and called per
  point cloud: ``sasa(xyz, scene_id) -> (detections, stats)``; detections in the frame of ``xyz``
  (``[{cls, box, score, extras}]``, the format of ``sonardet.io.annotations``).
* :func:`infer` -- runs a saved model on scene files and returns ``({scene_id: detections}, timing)``
  in the scene frame.
* :func:`detect_points` -- one in-memory cloud (N, 3) float64 (e.g. a user's survey) with a saved model.

Determinism: the model is initialised from ``seed``; the order of the scenes in every epoch, the
point samples and the augmentation of every step come from seeds derived from (``seed``, epoch,
step), so a resumed run continues exactly as an uninterrupted one; inference samples points with a
seed derived from (``seed``, scene id). With ``dr_enabled`` the domain randomisation of every step
(:func:`~.data.domain_randomise`, training only) draws from its own seed derived from (``seed``, "dr",
epoch, step); with it off nothing of it runs and nothing is drawn for it.
"""

from __future__ import annotations

import csv
import io
import json
import logging
import math
import resource
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from ... import SCHEMA_VERSION
from ...allocator import retain_freed_memory
from ...seeds import derive_seed
from ...io.artifacts import FileReadError, reading, rebuild_hint
from ...io.atomic import atomic_outputs, atomic_path, atomic_write_text
from .config import (
    ARCHITECTURE_KEYS,
    INFERENCE_KEYS,
    RUNTIME_KEYS,
    architecture_settings,
    describe_difference,
    model_settings,
    resolve_params,
)
from .data import (
    PreparedScene,
    augment,
    collate,
    domain_randomise,
    prepare_points,
    prepare_scene,
    sample_points,
    wrap_yaw,
)
from .model import SASADetector

log = logging.getLogger(__name__)

__all__ = ["train", "infer", "infer_models", "detect_points", "read_model", "resolve_device", "ConfigMismatchError",
           "TrainedSASA", "evaluate_scenes", "peak_memory_mb"]

CHECKPOINT_FORMAT = "sonardet-sasa"
CHECKPOINT_VERSION = 1


class ConfigMismatchError(ValueError):
    """A checkpoint or model was made with different settings (the message names them)."""


def resolve_device(device=None) -> torch.device:
    """``device`` if given (str or torch.device), else cuda when available, else cpu."""
    if device is None or device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(device)


def peak_memory_mb(device: torch.device | None = None) -> dict:
    """Peak resident memory of this process (MB, ``ru_maxrss``) and, on CUDA, peak allocated GPU memory."""
    out = {"peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}
    if device is not None and device.type == "cuda":
        out["peak_cuda_mb"] = torch.cuda.max_memory_allocated(device) / 2**20
    return out


def _configure_process(params: dict) -> None:
    """Torch's CPU threads (``num_threads``) and the allocator (``retain_freed_memory``) of this process."""
    if params.get("num_threads"):
        torch.set_num_threads(int(params["num_threads"]))
    if params.get("retain_freed_memory", True):
        retain_freed_memory()


def _rng(seed: int, *keys) -> np.random.Generator:
    return np.random.default_rng(derive_seed(seed, "sasa", *keys))


def _make_batch(scenes: list[PreparedScene], params: dict, rng: np.random.Generator, device, train_aug: bool,
                dr_rng: np.random.Generator | None = None):
    """Sample (and with ``train_aug`` augment) the scenes into a batch. With ``dr_rng`` (training with
    ``dr_enabled``) each scene first goes through :func:`domain_randomise` (drawing from ``dr_rng``),
    which also draws its point sample; without it the code path and the draws from ``rng`` are those of
    training without domain randomisation."""
    items = []
    for s in scenes:
        if dr_rng is None:
            idx = sample_points(len(s.xyz), int(params["n_points"]), rng, s.scene_id)
            xyz, h, lab = s.xyz[idx], s.height[idx], s.label[idx]
            boxes, axis = s.boxes, s.axis
        else:
            d = domain_randomise(s, params, dr_rng)
            xyz, h, lab, boxes, axis = d.xyz, d.height, d.label, d.boxes, d.axis
        if train_aug:
            xyz, h, boxes = augment(xyz, h, lab, boxes, s.cls, s.obj_id, params, rng, axis)
        if params["point_feature"] == "none":  # the study's input: coordinates only (no intensity simulated)
            h = np.zeros_like(h)
        items.append((xyz, h, boxes, s.cls))
    return collate(items, device)


def _checkpoint_settings(params: dict, train_ids: list[str]) -> dict:
    s = model_settings(params)
    if not params.get("dr_enabled"):  # off: the settings of a run without domain randomisation (old checkpoints resume)
        s = {k: v for k, v in s.items() if not k.startswith("dr_")}
    s["train_scenes"] = list(train_ids)
    return s


#: The loss curve of an unfinished run (beside checkpoint.pt, rewritten after every epoch); the
#: finished run's `loss.csv` is written with `model.pt` and `train.json`.
PROGRESS_CSV = "checkpoint_loss.csv"


def _save(obj, path: Path) -> None:
    with atomic_path(path) as tmp:
        torch.save(obj, tmp)


def _load(path: Path, device) -> dict:
    with reading(path, "SASA model / checkpoint (torch)"):
        obj = torch.load(path, map_location=device, weights_only=False)
    if not isinstance(obj, dict) or obj.get("format") != CHECKPOINT_FORMAT:
        fmt = obj.get("format") if isinstance(obj, dict) else type(obj).__name__
        raise FileReadError(f"{path}: not a sonardet SASA checkpoint/model (format {fmt!r}); {rebuild_hint(path)}")
    if obj.get("version") != CHECKPOINT_VERSION:
        raise ValueError(f"{path}: checkpoint version {obj.get('version')!r}; this sonardet reads version "
                         f"{CHECKPOINT_VERSION}. Retrain the model.")
    return obj


def _csv_text(rows: list[dict]) -> str:
    if not rows:
        return ""
    keys = list(rows[0])
    for r in rows[1:]:
        keys += [k for k in r if k not in keys]
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=keys, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in keys})
    return buf.getvalue()


def _symmetry(params: dict):
    orders = params["symmetry_orders"]
    sym = [c for c in params["classes"] if int(orders[c]) == 0]
    periods = {c: 2 * math.pi / int(orders[c]) for c in params["classes"] if int(orders[c]) > 0}
    return sym, periods


def ground_truth(scene_paths, classes) -> dict:
    """The scenes' labelled objects of `classes` (scene JSON), scene id -> list (`sonardet.eval.evaluate`'s
    `gt`): read once per training, not once per development evaluation."""
    from ...io.annotations import read_scene
    from .data import scene_paths as _paths

    gt = {}
    for p in scene_paths:
        doc = read_scene(_paths(p)[1], classes=None)
        gt[doc["scene"]] = [o for o in doc["objects"] if o["cls"] in classes]
    return gt


def evaluate_scenes(dets: dict, scene_paths, params: dict, dist_thresholds_m=(0.5, 1.0, 2.0, 4.0),
                    headline_m: float = 0.5, gt: dict | None = None) -> dict:
    """nuScenes-style metrics (sonardet.eval.evaluate) of ``dets`` against the scenes' JSON labels
    (``gt``: those labels already read by :func:`ground_truth`; ``scene_paths`` is then not read)."""
    from ...eval.evaluate import evaluate, metrics_for_json

    gt = ground_truth(scene_paths, params["classes"]) if gt is None else gt
    sym, periods = _symmetry(params)
    res = evaluate(gt, {k: v for k, v in dets.items() if k in gt}, params["classes"], list(dist_thresholds_m),
                   headline_m, symmetric_classes=sym, yaw_periods_rad=periods)
    return metrics_for_json(res)


def _to_detections(pred: dict, origin: np.ndarray, classes: list[str]) -> list[dict]:
    boxes = pred["boxes"].detach().cpu().double().numpy()
    scores = pred["scores"].detach().cpu().double().numpy()
    labels = pred["labels"].detach().cpu().numpy()
    cs = pred["class_scores"].detach().cpu().double().numpy()
    out = []
    for b, s, lab, c in zip(boxes, scores, labels, cs):
        box = b.copy()
        box[:3] += origin
        box[6] = float(wrap_yaw(box[6]))
        out.append({"cls": classes[int(lab)], "box": [float(v) for v in box], "score": float(s),
                    "extras": {"class_scores": {k: float(v) for k, v in zip(classes, c)}}})
    return out


@torch.no_grad()
def _detect_prepared(model: SASADetector, scene: PreparedScene, params: dict, device) -> list[dict]:
    model.eval()
    rng = _rng(int(params["seed"]), "infer", scene.scene_id)
    batch = _make_batch([scene], params, rng, device, train_aug=False)
    out = model(batch)
    pred = model.predict(out, params["score_thresh"], params["nms_mode"], params["nms_iou"], params["nms_pre_max"],
                         params["nms_post_max"])[0]
    return _to_detections(pred, scene.origin, list(params["classes"]))


def read_model(model_path, params: dict | None = None, device=None) -> tuple[SASADetector, dict]:
    """Load ``model.pt``. ``params`` (partial or complete) may set inference and runtime keys (score
    threshold, NMS, threads); training-only keys (epochs, LR, augmentation, ...) are ignored; a
    network or input key that it sets to another value than the model's raises
    :class:`ConfigMismatchError` naming it. Returns (model in eval mode, effective params)."""
    device = resolve_device(device)
    obj = _load(Path(model_path), device)
    stored = obj["params"]
    eff = resolve_params(stored)
    if params:
        given = dict(params)
        cur = resolve_params(given)
        asked = {k for k in given if k in ARCHITECTURE_KEYS}  # only keys the caller set are compared
        diff = describe_difference({k: v for k, v in architecture_settings(stored).items() if k in asked},
                                   {k: v for k, v in architecture_settings(cur).items() if k in asked})
        if diff:
            raise ConfigMismatchError(f"{model_path}: the model was trained with other settings ({diff}); "
                                      "retrain it with this config or use the config it was trained with")
        for k in INFERENCE_KEYS | RUNTIME_KEYS:
            if k in given:
                eff[k] = cur[k]
    model = SASADetector(eff).to(device)
    model.load_state_dict(obj["state_dict"])
    model.eval()
    return model, eff


class TrainedSASA:
    """A trained SASA model ready for inference, called per point cloud.

    model: a :class:`SASADetector` (put in eval mode when it detects); params: its effective
    parameters (resolved; inference keys such as score_thresh and NMS apply); device: where it runs.
    Usually made with :meth:`load` from a ``model.pt`` written by :func:`train`, once, then called on
    each scene or survey tile. Each cloud's point sample is drawn from a seed derived from (``seed``,
    scene id), so the same cloud and scene id give the same detections on every call.
    """

    def __init__(self, model: SASADetector, params: dict, device=None):
        self.model = model
        self.params = params
        self.device = resolve_device(device)

    @classmethod
    def load(cls, model_path, params: dict | None = None, device=None) -> TrainedSASA:
        """Load ``model.pt`` (see :func:`read_model` for which keys of ``params`` may differ from the
        model's) and set torch's CPU threads when ``params`` sets ``num_threads``."""
        device = resolve_device(device)
        model, eff = read_model(model_path, params, device)
        _configure_process(eff)
        return cls(model, eff, device)

    @property
    def classes(self) -> list[str]:
        """Class names, in the order of the model's logits."""
        return list(self.params["classes"])

    def detect_scene(self, scene: PreparedScene) -> list[dict]:
        """Detections of a prepared scene (`data.prepare_scene` / `data.prepare_points`), in the frame
        of the points it was prepared from: [{cls, box [x,y,z,l,w,h,yaw] (m, rad), score, extras
        {class_scores}}], sorted by descending score."""
        return _detect_prepared(self.model, scene, self.params, self.device)

    def detect_file(self, scene_npz_path) -> tuple[str, list[dict]]:
        """(scene id, detections in the scene frame) of a scene ``.npz`` file (labels not needed)."""
        scene = prepare_scene(scene_npz_path, self.params, with_labels=False)
        return scene.scene_id, self.detect_scene(scene)

    def __call__(self, xyz: np.ndarray, scene_id: str = "points") -> tuple[list[dict], dict]:
        """Detect objects in a cloud ``xyz`` (N, 3) float64 (any frame incl. UTM, m, z up).

        Returns (detections in the frame of ``xyz``, see :meth:`detect_scene`; stats {n_points,
        n_detections, device, seconds {total}}). ``scene_id`` seeds the point sample.
        """
        t0 = time.perf_counter()
        if np.shape(xyz) == (0, 3):
            # As the model-based detectors: an empty cloud (an empty tile) holds nothing, not an error.
            warnings.warn(f"SASA detection on an empty cloud ({scene_id}): nothing to detect", stacklevel=2)
            return [], {"n_points": 0, "n_detections": 0, "device": str(self.device),
                        "seconds": {"total": time.perf_counter() - t0}}
        keep, local, height, origin = prepare_points(xyz, self.params)
        scene = PreparedScene(scene_id, local, height, np.full(len(local), -1, np.int64),
                              np.zeros((0, 7), np.float32), np.zeros(0, np.int64), np.zeros(0, np.int64), origin,
                              len(xyz))
        dets = self.detect_scene(scene)
        stats = {"n_points": int(len(xyz)), "n_detections": len(dets), "device": str(self.device),
                 "seconds": {"total": time.perf_counter() - t0}}
        return dets, stats


def infer(model_path, scene_npz_paths, params: dict | None = None, device=None,
          progress: bool | None = None) -> tuple[dict, dict]:
    """Detect objects in scene files with a trained model (loaded once, see :class:`TrainedSASA`).

    Args:
        model_path: ``model.pt`` written by :func:`train`.
        scene_npz_paths: scene ``.npz`` files (labels are not needed).
        params: optional parameters; only inference/runtime keys may differ from the model's.
        device: None = cuda if available else cpu.
        progress: show a progress bar (None: the model's ``progress`` setting).
    Returns:
        (detections, timing): detections {scene_id: [{"cls", "box" [x, y, z, l, w, h, yaw] (scene
        frame, m, rad), "score", "extras"}]}, each list sorted by descending score; timing {n_scenes,
        s_per_scene (mean seconds per scene: reading, preparing and detecting; None without scenes),
        device, peak_rss_mb (and peak_cuda_mb on CUDA)}.
    """
    return infer_models([TrainedSASA.load(model_path, params, device)], scene_npz_paths, progress)[0]


def _preparation_key(params: dict) -> tuple:
    """The parameters :func:`data.prepare_scene` reads (without labels): models that agree on them
    can share a scene's preparation."""
    return float(params["ground_cell_m"]), bool(params["ground_filter"]), float(params["ground_height_m"])


def infer_models(models: list[TrainedSASA], scene_npz_paths, progress: bool | None = None) -> list[tuple[dict, dict]]:
    """:func:`infer` for several loaded models on the same scene files: each scene is read and
    prepared once for all models that prepare alike (`_preparation_key`), then detected by each in
    turn. Each model's detections are those :func:`infer` gives it alone (the same prepared points,
    the same seeded sample); its ``s_per_scene`` counts the scene's reading and preparation as its own
    (what a run of it alone would take), so the models' seconds do not add up to the call's.

    Returns one (detections, timing) per model, in order (see :func:`infer`).
    """
    if not models:
        return []
    show = models[0].params["progress"] if progress is None else progress
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover - tqdm is a dependency
        tqdm = None
    it = list(scene_npz_paths)
    bar = tqdm(it, desc="sasa infer", disable=not show) if tqdm else it
    outs = [{} for _ in models]
    times = [[] for _ in models]
    for p in bar:
        prepared = {}  # preparation key -> (prepared scene, seconds)
        for k, sasa in enumerate(models):
            key = _preparation_key(sasa.params)
            if key not in prepared:
                t0 = time.perf_counter()
                prepared[key] = (prepare_scene(p, sasa.params, with_labels=False), time.perf_counter() - t0)
            scene, prep_s = prepared[key]
            t0 = time.perf_counter()
            outs[k][scene.scene_id] = sasa.detect_scene(scene)
            times[k].append(prep_s + time.perf_counter() - t0)
    return [(out, {"n_scenes": len(ts), "s_per_scene": float(np.mean(ts)) if ts else None,
                   "device": str(sasa.device), **peak_memory_mb(sasa.device)})
            for sasa, out, ts in zip(models, outs, times)]


def detect_points(model_path, xyz: np.ndarray, params: dict | None = None, device=None, scene_id: str = "points"):
    """Detect objects in an in-memory cloud ``xyz`` (N, 3) float64 (any frame, m, z up) with the model
    ``model_path``. Returns the detections in the frame of ``xyz`` (see :meth:`TrainedSASA.detect_scene`);
    to run one model on many clouds, load a :class:`TrainedSASA` once instead.
    """
    return TrainedSASA.load(model_path, params, device)(xyz, scene_id)[0]


@dataclass
class _Progress:
    """Where a training run stands: next epoch, per-epoch rows, training seconds and steps so far; the
    best development evaluation so far (epoch, mAP, weights) and evaluations since it improved; the
    epoch training stopped at when early stopping ended it."""

    epoch: int = 0
    history: list = field(default_factory=list)
    train_s: float = 0.0
    steps: int = 0
    best_epoch: int | None = None
    best_map: float | None = None
    best_state: dict | None = None
    bad_evals: int = 0
    stopped_epoch: int | None = None


def _checkpoint_to_resume(ckpt_path: Path, settings: dict, resume: bool) -> dict | None:
    """The checkpoint to resume from (None: start afresh); refused when made with other settings."""
    if not (resume and ckpt_path.exists()):
        return None
    ckpt = _load(ckpt_path, "cpu")
    diff = describe_difference(ckpt["settings"], settings)
    if diff:
        raise ConfigMismatchError(f"{ckpt_path}: refusing to resume, the checkpoint was made with other "
                                  f"settings ({diff}); delete it (or pass resume=False) to start afresh")
    return ckpt


def _prepare_training_scenes(train_paths: list[str], val_paths: list[str], params: dict):
    """Prepared training and validation scenes and the preparation time (s); warns when a training
    scene keeps fewer points than n_points (it will be padded)."""
    t_prep = time.perf_counter()
    scenes = [prepare_scene(p, params) for p in train_paths]
    val_scenes = [prepare_scene(p, params) for p in val_paths]
    prep_s = time.perf_counter() - t_prep
    short = [s.scene_id for s in scenes if len(s.xyz) < int(params["n_points"])]
    if short:
        warnings.warn(f"{len(short)} training scene(s) have fewer kept points than n_points="
                      f"{params['n_points']} and will be padded: {', '.join(short[:5])}", stacklevel=3)
    return scenes, val_scenes, prep_s


def _optimiser(model: SASADetector, params: dict, total_steps: int):
    """AdamW with a one-cycle schedule (cosine annealing, cycled momentum) over `total_steps` steps."""
    opt = torch.optim.AdamW(model.parameters(), lr=float(params["lr"]) / float(params["div_factor"]),
                            betas=(float(params["moms"][0]), 0.99), weight_decay=float(params["weight_decay"]))
    sched = torch.optim.lr_scheduler.OneCycleLR(
        opt, max_lr=float(params["lr"]), total_steps=total_steps, pct_start=float(params["pct_start"]),
        anneal_strategy="cos", cycle_momentum=True, base_momentum=float(params["moms"][1]),
        max_momentum=float(params["moms"][0]), div_factor=float(params["div_factor"]),
        final_div_factor=float(params["final_div_factor"]))
    return opt, sched


def _restore(ckpt: dict | None, model, opt, sched) -> _Progress:
    """Load a checkpoint's weights, optimiser and schedule; its progress (a fresh one without checkpoint)."""
    if ckpt is None:
        return _Progress()
    model.load_state_dict(ckpt["state_dict"])
    opt.load_state_dict(ckpt["optimizer"])
    sched.load_state_dict(ckpt["scheduler"])
    best = ckpt.get("best") or {}
    return _Progress(int(ckpt["epoch"]), list(ckpt["history"]), float(ckpt["train_s"]), int(ckpt["steps"]),
                     best.get("epoch"), best.get("mAP"), best.get("state_dict"), int(best.get("bad_evals", 0)),
                     ckpt.get("stopped_epoch"))


def _train_epoch(model, opt, sched, scenes: list, params: dict, epoch: int, device, bar) -> dict:
    """One pass over the training scenes (order, point samples, augmentation and domain randomisation
    seeded from (seed, epoch, step)); returns the sums of the loss parts over its steps."""
    seed, bs = int(params["seed"]), int(params["batch_size"])
    model.train()
    order = _rng(seed, "order", epoch).permutation(len(scenes))
    sums: dict[str, float] = {}
    for step in range(math.ceil(len(scenes) / bs)):
        sel = [scenes[i] for i in order[step * bs:(step + 1) * bs]]
        rng = _rng(seed, "step", epoch, step)
        dr_rng = _rng(seed, "dr", epoch, step) if params["dr_enabled"] else None
        batch = _make_batch(sel, params, rng, device, train_aug=True, dr_rng=dr_rng)
        out = model(batch)
        loss, parts = model.loss(out, batch)
        if not torch.isfinite(loss):
            raise FloatingPointError(f"non-finite training loss at epoch {epoch}, step {step}: {parts}")
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), float(params["grad_clip"]))
        opt.step()
        sched.step()
        for k, v in parts.items():
            sums[k] = sums.get(k, 0.0) + float(v)
        if bar is not None:
            bar.update(1)
            bar.set_postfix(epoch=epoch + 1, loss=f"{parts['loss']:.3f}")
    return sums


def _validate(model, val_scenes: list, val_gt: dict, params: dict, device, headline_only: bool = False) -> dict:
    """Validation metrics (`evaluate_scenes`) of the model on the validation scenes (labels `val_gt`);
    ``headline_only``: at the headline distance alone (the same `mAP_headline`: each distance is
    matched on its own), what a development evaluation during training needs."""
    dets = {s.scene_id: _detect_prepared(model, s, params, device) for s in val_scenes}
    if headline_only:
        return evaluate_scenes(dets, [], params, dist_thresholds_m=(0.5,), headline_m=0.5, gt=val_gt)
    return evaluate_scenes(dets, [], params, gt=val_gt)


def _training_summary(params: dict, device, scenes: list, val_scenes: list, train_ids: list[str],
                      run: _Progress, prep_s: float, val_s: float | None, val: dict | None, n_parameters: int) -> dict:
    """The summary written to train.json (times in s, memory in MB)."""
    n_kept = [len(s.xyz) for s in scenes]
    return {
        "schema_version": SCHEMA_VERSION,
        "method": "sasa",
        "device": str(device),
        "torch_threads": torch.get_num_threads(),
        # whether glibc kept freed memory in the process (sonardet.allocator): False where it is off or not glibc
        "freed_memory_kept": bool(params.get("retain_freed_memory", True)) and retain_freed_memory(),
        "n_train_scenes": len(scenes),
        "n_val_scenes": len(val_scenes),
        "train_scenes": train_ids,
        "epochs": len(run.history),
        "epochs_cap": int(params["epochs"]),
        "best_epoch": run.best_epoch,
        "stopped_early": run.stopped_epoch is not None,
        "batch_size": int(params["batch_size"]),
        "n_points": int(params["n_points"]),
        "n_parameters": int(n_parameters),
        "steps": run.steps,
        "train_time_s": run.train_s,
        "train_s": run.train_s,  # the comparison table's column name for the same seconds
        "s_per_step": run.train_s / max(run.steps, 1),
        "prepare_time_s": prep_s,
        "kept_points_per_scene": {"min": int(min(n_kept)), "median": float(np.median(n_kept)), "max": int(max(n_kept))},
        "val_infer_s_per_scene": val_s,
        "val": val,
        "final_loss": run.history[-1] if run.history else None,
        **peak_memory_mb(device),
        "params": params,
    }


def _progress_bar(params: dict, total_steps: int, done_steps: int, n_scenes: int):
    """A tqdm bar over the training steps (None without tqdm)."""
    try:
        from tqdm import tqdm
    except ImportError:  # pragma: no cover
        return None
    return tqdm(total=total_steps, initial=done_steps, desc=f"sasa train ({n_scenes} scenes)",
                disable=not params["progress"])


def _evaluate_epoch(model, val_scenes, val_gt: dict, params: dict, device, run: _Progress, row: dict,
                    epochs: int) -> None:
    """Every `val_every_epochs` epochs (and after the last): the dev mAP into `row`, the best model
    kept, and early stopping decided (`early_stop_patience` evaluations without a dev mAP better by
    `early_stop_min_delta`, from epoch `early_stop_min_epoch_frac` x the cap on)."""
    every = int(params.get("val_every_epochs") or 0)
    epoch = int(row["epoch"])
    if not (val_scenes and every and (epoch % every == 0 or epoch == epochs)):
        return
    m = _validate(model, val_scenes, val_gt, params, device, headline_only=True)["mAP_headline"]
    row["val_mAP"] = m
    if run.best_map is None or m > run.best_map + float(params["early_stop_min_delta"]):
        run.best_epoch, run.best_map, run.bad_evals = epoch, float(m), 0
        run.best_state = {k: v.detach().clone() for k, v in model.state_dict().items()}
    else:
        run.bad_evals += 1
        patience = int(params.get("early_stop_patience") or 0)
        # Not while the one-cycle LR is still high: the dev mAP then swings by ~0.1 between
        # evaluations and a stop keeps a model the annealing would have improved.
        settled = epoch >= float(params.get("early_stop_min_epoch_frac", 0.0)) * epochs
        if patience and settled and run.bad_evals >= patience and epoch < epochs:
            run.stopped_epoch = epoch


def _checkpoint(settings: dict, params: dict, model, opt, sched, epoch: int, run: _Progress) -> dict:
    """The resumable checkpoint after `epoch` (weights, optimiser, schedule, history, best so far)."""
    return {"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, "settings": settings, "params": params,
            "state_dict": model.state_dict(), "optimizer": opt.state_dict(), "scheduler": sched.state_dict(),
            "epoch": epoch, "history": run.history, "train_s": run.train_s, "steps": run.steps,
            "best": {"epoch": run.best_epoch, "mAP": run.best_map, "state_dict": run.best_state,
                     "bad_evals": run.bad_evals},
            "stopped_epoch": run.stopped_epoch}


def _final_validation(model, val_scenes: list, val_gt: dict, params: dict, device, run: _Progress,
                      out_dir: Path):
    """Validation of the kept model (the best on the dev scenes, else the last epoch's): (metrics for
    train.json, inference seconds per scene), both None without validation scenes. Without periodic
    evaluations the last loss.csv row gets the validation mAP."""
    if not val_scenes:
        return None, None
    t0 = time.perf_counter()
    m = _validate(model, val_scenes, val_gt, params, device)
    val_s = (time.perf_counter() - t0) / len(val_scenes)
    val = {"mAP_headline": m["mAP_headline"], "mAP": m["mAP"],
           "AP_headline": {c: m["per_class"][c]["AP"][repr(0.5)] for c in params["classes"]}}
    if run.history and "val_mAP" not in run.history[-1] and run.best_epoch is None:
        run.history[-1]["val_mAP"] = m["mAP_headline"]
        atomic_write_text(out_dir / PROGRESS_CSV, _csv_text(run.history))
    return val, val_s


def train(train_scene_paths, val_scene_paths, params: dict | None, out_dir, device=None, resume: bool = True) -> dict:
    """Train a SASA detector.

    Args:
        train_scene_paths: scene files (``.npz``; the ``.json`` labels beside them are read).
        val_scene_paths: scenes for the validation mAP (may be empty).
        params: parameters (see config.py ``DEFAULTS``; missing keys take the defaults).
        out_dir: output folder; gets ``model.pt``, ``loss.csv``, ``train.json`` and ``checkpoint.pt``.
        device: None = cuda if available else cpu.
        resume: continue from ``out_dir/checkpoint.pt`` if present (refused, with the differing setting
            named, if it was made with other settings or another training set); False starts afresh.
    Returns:
        the summary written to ``train.json`` (times in s, memory in MB, validation metrics).
    """
    params = resolve_params(params)
    device = resolve_device(device)
    _configure_process(params)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    train_paths = sorted(str(p) for p in train_scene_paths)
    val_paths = sorted(str(p) for p in val_scene_paths or [])
    if not train_paths:
        raise ValueError("train: no training scenes given")
    train_ids = [Path(p).stem for p in train_paths]
    settings = _checkpoint_settings(params, train_ids)
    ckpt_path = out_dir / "checkpoint.pt"
    ckpt = _checkpoint_to_resume(ckpt_path, settings, resume)
    scenes, val_scenes, prep_s = _prepare_training_scenes(train_paths, val_paths, params)
    val_gt = ground_truth(val_paths, params["classes"])

    torch.manual_seed(int(params["seed"]))
    model = SASADetector(params).to(device)
    steps_per_epoch = math.ceil(len(scenes) / int(params["batch_size"]))
    epochs = int(params["epochs"])
    opt, sched = _optimiser(model, params, steps_per_epoch * epochs)
    run = _restore(ckpt, model, opt, sched)
    if ckpt is not None:
        log.info("resuming %s at epoch %d/%d", ckpt_path, run.epoch, epochs)
    bar = _progress_bar(params, steps_per_epoch * epochs, run.epoch * steps_per_epoch, len(scenes))
    for epoch in range(run.epoch, epochs):
        if run.stopped_epoch is not None:  # resumed after early stopping
            break
        t_ep = time.perf_counter()
        sums = _train_epoch(model, opt, sched, scenes, params, epoch, device, bar)
        run.steps += steps_per_epoch
        ep_s = time.perf_counter() - t_ep
        run.train_s += ep_s
        row = {"epoch": epoch + 1, **{k: v / steps_per_epoch for k, v in sums.items()},
               "lr": sched.get_last_lr()[0], "epoch_s": ep_s}
        _evaluate_epoch(model, val_scenes, val_gt, params, device, run, row, epochs)
        run.history.append(row)
        log.info("epoch %d/%d: loss %.4f, %.1f s (%.2f s/step)%s", epoch + 1, epochs, row.get("loss", float("nan")),
                 ep_s, ep_s / steps_per_epoch, f", dev mAP {row['val_mAP']:.3f}" if "val_mAP" in row else "")
        atomic_write_text(out_dir / PROGRESS_CSV, _csv_text(run.history))
        _save(_checkpoint(settings, params, model, opt, sched, epoch + 1, run), ckpt_path)
        if run.stopped_epoch is not None:
            log.info("early stop after epoch %d: no dev mAP better than %.4f (epoch %d) in %d evaluations",
                     epoch + 1, run.best_map, run.best_epoch, run.bad_evals)
            break
    if run.best_state is not None:  # the model chosen on the development scenes
        model.load_state_dict(run.best_state)
    if bar is not None:
        bar.close()
    val, val_s = _final_validation(model, val_scenes, val_gt, params, device, run, out_dir)
    summary = _training_summary(params, device, scenes, val_scenes, train_ids, run, prep_s, val_s, val,
                                sum(p.numel() for p in model.parameters()))
    with atomic_outputs([out_dir / "model.pt", out_dir / "loss.csv", out_dir / "train.json"]) as (pt, loss, js):
        _save({"format": CHECKPOINT_FORMAT, "version": CHECKPOINT_VERSION, "settings": settings, "params": params,
               "state_dict": model.state_dict(), "classes": list(params["classes"]), "summary": summary}, pt)
        atomic_write_text(loss, _csv_text(run.history))
        atomic_write_text(js, json.dumps(summary, indent=1, default=float) + "\n")
    return summary
